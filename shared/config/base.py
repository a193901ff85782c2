"""The base class every configuration section derives from.

Sections are frozen pydantic models: unknown keys and out-of-range values are errors at load
time, and nothing down the line can change a setting after it was validated.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Section(BaseModel):
    """A frozen, validated configuration section (unknown keys are rejected)."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class ConfigError(ValueError):
    """A configuration file or value is invalid; the message names the file and the key."""
