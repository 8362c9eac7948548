"""The base of every configuration record (one scenario section = one model).

The records are pydantic v2 models: a field's type, default, constraint (``gt``, ``ge``,
``lt``, ``Literal`` choices) and ``description`` (meaning, units) are written once, on the
field, and give the validation, the JSON Schema (``tdacm schema``) and the generated scenario
reference (docs/scenario-reference.md). pydantic is used instead of hand-written dataclass
validators because it produces the JSON Schema and located errors (the dotted key) from the
same declaration.

The records are strict (TOML gives typed values: ``1`` is not ``true``, ``"2"`` is not a
number; an integer is accepted for a float), reject unknown keys, reject NaN and infinities,
and are frozen. This module sits below every layer (it imports only pydantic), so each block
can declare its parameter record next to its code.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["ConfigModel", "Field"]


class ConfigModel(BaseModel):
    """A validated, immutable parameter record (see the module docstring)."""

    model_config = ConfigDict(
        extra="forbid",
        strict=True,
        frozen=True,
        allow_inf_nan=False,
        populate_by_name=True,
        validate_default=False,
    )
