"""The secure profile: identities and their certificates, the hub's access rules.

``identities`` (who exists and which files are whose), ``certs`` (``racestack certs``: a
local CA and one certificate per identity, with the ``cryptography`` package), ``acl`` (the
Zenoh ``access_control`` of the hub, pure data: the stack's keys and those of the ``[ros2]``
topics), ``denials`` (reading Zenoh's access-control trace into counts of denied messages).
"""

from shared.security.acl import PUT_RIGHTS, ROS2_WRITERS, access_control, may_put, ros2_keys
from shared.security.identities import (
    CA_CERT,
    CA_KEY,
    CERTS_DIR_ENV,
    HUB_IDENTITY,
    IDENTITIES,
    ROS2_IDENTITY,
    IdentityFiles,
    identity_files,
)

__all__ = [
    "CA_CERT",
    "CA_KEY",
    "CERTS_DIR_ENV",
    "HUB_IDENTITY",
    "IDENTITIES",
    "PUT_RIGHTS",
    "ROS2_IDENTITY",
    "ROS2_WRITERS",
    "IdentityFiles",
    "access_control",
    "identity_files",
    "may_put",
    "ros2_keys",
]
