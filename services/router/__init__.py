"""A Zenoh router on the well-known hub endpoint that every other service connects to.

In the secure profile it carries the access rules and counts their denials (``Router``).
"""

from services.router.denials import Denial, DenialCounter, DenialParser

__all__ = ["Denial", "DenialCounter", "DenialParser"]
