"""Numeric settings checked against a declared range, and their one-line description: one
rule for every family of settings (masking, track stage)."""

from __future__ import annotations

Range = tuple[float, float, bool, str]
"""lowest, highest (inclusive), whole numbers only, what the setting is (for the error)"""


def in_range(value: object, spec: Range, open_low: bool = False, open_high: bool = False) -> bool:
    """Is ``value`` a number of the right kind (``bool`` never counts) within ``spec``?
    ``open_low`` / ``open_high``: that bound itself is not allowed."""
    lo, hi, integer, _ = spec
    typed = isinstance(value, int) if integer else isinstance(value, int | float)
    ok = typed and not isinstance(value, bool) and lo <= value <= hi
    return ok and not (open_low and value == lo) and not (open_high and value == hi)


def describe_values(preset: str | None, values: dict[str, float | int | str]) -> str:
    """``slimseg preset (conf 0.1, dilation_px 5, ...)``, or ``custom (...)`` without a name."""
    text = ", ".join(f"{k} {v}" if isinstance(v, str) else f"{k} {v:g}" for k, v in values.items())
    return f"{preset + ' preset' if preset else 'custom'} ({text})"
