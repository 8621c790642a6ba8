"""Checks of the caller's numeric options (timeouts, sizes, limits) at the public boundary."""

from __future__ import annotations

import math
import numbers

__all__ = ["check_count", "check_timeout"]


def check_timeout(value: float | None, name: str = "timeout", *,
                  zero: bool = False) -> float | None:
    """``value`` as seconds (``None`` stays ``None``: no limit, or the default)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a number of seconds or None, got {value!r}")
    seconds = float(value)
    if not math.isfinite(seconds) or seconds < 0.0 or (seconds == 0.0 and not zero):
        raise ValueError(f"{name} must be a finite number of seconds > 0 (or None), got {value!r}")
    return seconds


def check_count(value: int, name: str, minimum: int = 1) -> int:
    """``value`` as an integer of at least ``minimum`` (NaN, floats and bools refused)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be at least {minimum}, got {value!r}")
    return int(value)
