"""The base class every configuration section derives from.

Sections are frozen pydantic models: unknown keys and out-of-range values are errors at load
time, and nothing down the line can change a setting after it was validated.
"""

from __future__ import annotations

from collections.abc import Callable

from pydantic import BaseModel, ConfigDict


class Section(BaseModel):
    """A frozen, validated configuration section (unknown keys are rejected)."""

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


class ConfigError(ValueError):
    """A configuration file or value is invalid; the message names the file and the key."""


class Choices:
    """Field metadata naming a string field's allowed values when they come from a registry
    (validated by the field's own validator; the configuration reference lists them).

    ``Annotated[str, Choices(planner_methods)]``: `names` is called when the values are needed.
    """

    def __init__(self, names: Callable[[], tuple[str, ...]]) -> None:
        self.names = names
