"""The sans-IO rules of a move: its timing, budget and verdict.

``_timing.py`` computes how long a motion line may take (``move_budget``), which axes it
moves, and judges what a state read shows afterwards (``verdict``; a refused or garbled
verdict contested by ``?statusaxis``; the proofs that a ``speed`` or ``go`` line arrived).
Pure functions of the line, the cached settings and the replies, tested synchronously.
"""

from __future__ import annotations

from ._timing import (
    POLL_GRACE,
    Acceptance,
    Budget,
    MoveTiming,
    Verdict,
    acceptance,
    ack_verdict,
    contest,
    cut_short,
    describe_stop,
    err_verdict,
    move_budget,
    moved_axes,
    polled_during,
    position_tolerance,
    report_shows_run,
    rest_budget,
    shifted_axes,
    speed_shown,
    stop_time,
    too_early,
    verdict,
)

__all__ = [
    "POLL_GRACE",
    "Acceptance",
    "Budget",
    "MoveTiming",
    "Verdict",
    "acceptance",
    "ack_verdict",
    "contest",
    "cut_short",
    "describe_stop",
    "err_verdict",
    "move_budget",
    "moved_axes",
    "polled_during",
    "position_tolerance",
    "report_shows_run",
    "rest_budget",
    "shifted_axes",
    "speed_shown",
    "stop_time",
    "too_early",
    "verdict",
]
