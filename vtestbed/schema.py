"""Validation of the tables read from scenario, campaign and lab files.

One set of checks for every file kind, each raising :class:`~vtestbed.errors.ScenarioError` with
the file, the dotted field name and the valid values or range, so that a researcher can fix a
file without reading a traceback. :class:`Fields` binds the source file once.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .errors import ScenarioError


@dataclass(frozen=True)
class Fields:
    """Validators bound to one source file (``None`` for a mapping built in code)."""

    source: Path | str | None = None

    def error(self, field_name: str, message: str) -> ScenarioError:
        where = f"{self.source}: " if self.source else ""
        return ScenarioError(f"{where}{field_name}: {message}")

    def table(self, value, field_name: str, allowed=None) -> dict:
        """``value`` if it is a table whose keys are all in ``allowed`` (any keys if None)."""
        if not isinstance(value, dict):
            raise self.error(field_name, f"must be a table, got {type(value).__name__} {value!r}")
        if allowed is not None:
            unknown = sorted(set(value) - set(allowed))
            if unknown:
                prefix = f"{field_name}." if field_name else ""
                raise self.error(f"{prefix}{unknown[0]}", f"unknown key; valid keys: {', '.join(allowed)}")
        return value

    def number(self, value, field_name: str, low: float, high: float, unit: str = "") -> float:
        """A finite number in ``[low, high]`` (``unit``, if given, follows the range in errors)."""
        u = f" {unit}" if unit else ""
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(field_name, f"must be a number in [{low:g}, {high:g}]{u}, got {value!r}")
        if not low <= value <= high:  # also refuses NaN
            raise self.error(field_name, f"= {value:g}{u} is outside the valid range [{low:g}, {high:g}]{u}")
        return float(value)

    def integer(self, value, field_name: str, low: int, high: int) -> int:
        """An integer in ``[low, high]``."""
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise self.error(field_name, f"must be an integer in [{low}, {high}], got {value!r}")
        return value

    def vector(self, value, field_name: str, length: int, low: float, high: float) -> tuple[float, ...]:
        """A list of ``length`` numbers, each in ``[low, high]``."""
        if not isinstance(value, list) or len(value) != length:
            raise self.error(field_name, f"must be a list of {length} numbers, got {value!r}")
        return tuple(self.number(v, f"{field_name}[{i}]", low, high) for i, v in enumerate(value))

    def choice(self, value, field_name: str, valid) -> str:
        """One of the names in ``valid``."""
        if not isinstance(value, str) or value not in valid:
            raise self.error(field_name, f"{value!r} is not one of {', '.join(valid)}")
        return value

    def boolean(self, value, field_name: str) -> bool:
        if not isinstance(value, bool):
            raise self.error(field_name, f"must be true or false, got {value!r}")
        return value

    def string(self, value, field_name: str, allow_empty: bool = True) -> str:
        if not isinstance(value, str) or (not allow_empty and not value):
            raise self.error(field_name, "must be a " + ("string" if allow_empty else "non-empty string"))
        return value

    def seed(self, value, field_name: str) -> int:
        """A non-negative integer seed."""
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise self.error(field_name, f"must be a non-negative integer, got {value!r}")
        return value
