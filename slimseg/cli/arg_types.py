"""argparse ``type=`` helpers that check an option's range while parsing, so that a value out of
range ends in argparse's one line (``slimseg bench: error: argument --runs: 0 is not a whole
number >= 1``) instead of a traceback or a silent, meaningless result.

Every numeric option of the CLI uses one of these: :func:`count` (whole number from a lower
bound), :func:`number` (finite float within bounds), :func:`multiple_of` (image sizes: a
multiple of the network stride).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from slimseg.deploy.preprocess import MAX_STRIDE as STRIDE  # image sides are multiples of it
from slimseg.utils.threads import available_cpus


def count(low: int = 1, high: int | None = None) -> Callable[[str], int]:
    """A whole number ``low <= n`` (``<= high`` when given)."""
    span = f">= {low}" if high is None else f"in {low}..{high}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number {span}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{value} is not a whole number {span}")
        return value

    parse.__name__ = "count"
    return parse


def threads() -> Callable[[str], int]:
    """A thread count: 0 (the default) up to the CPU cores this process may use
    (:func:`slimseg.utils.threads.available_cpus`); more is refused, never capped silently."""
    cpus = available_cpus()

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = -1
        if not 0 <= value <= cpus:
            raise argparse.ArgumentTypeError(
                f"{text!r} is not a thread count in 0..{cpus} (the CPU cores this process may "
                "use; 0: the default)"
            )
        return value

    parse.__name__ = "threads"
    return parse


def number(
    low: float = -math.inf, high: float = math.inf, open_low: bool = False, open_high: bool = False
) -> Callable[[str], float]:
    """A finite number within ``[low, high]`` (``open_low``/``open_high``: that end excluded);
    ``nan`` and ``inf`` are always refused."""
    left, right = "(" if open_low else "[", ")" if open_high else "]"
    span = f"in {left}{low:g}, {high:g}{right}"
    if math.isinf(low) and math.isinf(high):
        span = ""
    elif math.isinf(high):
        span = f"{'>' if open_low else '>='} {low:g}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number {span}".rstrip()) from None
        ok = math.isfinite(value) and low <= value <= high
        ok = ok and not (open_low and value == low) and not (open_high and value == high)
        if not ok:
            raise argparse.ArgumentTypeError(f"{text} is not a finite number {span}".rstrip())
        return value

    parse.__name__ = "number"
    return parse


def multiple_of(stride: int = STRIDE, low: int | None = None) -> Callable[[str], int]:
    """A whole multiple of ``stride`` and at least ``low`` (default: ``stride``)."""
    low = stride if low is None else low
    base = count(low)

    def parse(text: str) -> int:
        value = base(text)
        if value % stride:
            down, up = value // stride * stride, (value // stride + 1) * stride
            near = f"{down} or {up}" if down >= low else str(up)
            raise argparse.ArgumentTypeError(f"{value} is not a multiple of {stride} (try {near})")
        return value

    parse.__name__ = "multiple_of"
    return parse


def image_side(high: int, stride: int = STRIDE) -> Callable[[str], int]:
    """An image side: a multiple of ``stride`` from ``stride`` to ``high``."""
    base = multiple_of(stride)

    def parse(text: str) -> int:
        value = base(text)
        if value > high:
            raise argparse.ArgumentTypeError(f"{value} is over {high} (the largest side allowed)")
        return value

    parse.__name__ = "image_side"
    return parse


FRACTION = number(0.0, 1.0)
"""scores, IoU thresholds, rates: a finite number in [0, 1]"""
