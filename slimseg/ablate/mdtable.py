"""Markdown table cells of the sweep reports: percent, points, relative change, mean ± spread."""

from __future__ import annotations

import math


def table(headers: list[str], rows: list[list[str]]) -> str:
    """A GitHub markdown table."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def pct(v: float) -> str:
    """A fraction in percent, one decimal (``–`` for NaN)."""
    return "–" if math.isnan(v) else f"{100 * v:.1f}"


def pts(v: float, base: float) -> str:
    """Signed change in percentage points of two fractions."""
    return "–" if math.isnan(v) or math.isnan(base) else f"{100 * (v - base):+.1f}"


def rel(v: float, base: float) -> str:
    """Signed relative change in percent."""
    return f"{100 * (v / base - 1):+.1f} %"


def pm(mean: str, spread: str | None) -> str:
    """``mean ± spread`` (``mean`` alone when ``spread`` is None: a single run)."""
    return mean if spread is None else f"{mean} ± {spread}"
