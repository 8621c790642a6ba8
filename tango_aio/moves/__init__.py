"""The sans-IO rules of a move: its timing, budget and verdict, and the move tracker.

``_timing.py`` computes how long a motion line may take (``move_budget``), which axes it
moves, and judges what a state read shows afterwards (``verdict``, ``failed_axes``: the
one rule of a move's end; a refused or garbled verdict contested by ``?statusaxis``; the
proofs that a ``speed`` or ``go`` line arrived). Pure functions of the line, the cached
settings and the replies, tested synchronously. ``_tracker.py`` drives them: a
connection's facts about its moves (``MoveTracker``: where a start comes from) and one
move followed to its end (``Follow``: events in, intents out).
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
    failed_axes,
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
from ._tracker import (
    FOLLOW,
    POLL_MAX,
    POLL_MIN,
    Confirmation,
    Follow,
    FollowStateError,
    Intent,
    MoveTracker,
    Next,
    Phase,
    ProofStep,
    Prove,
    Start,
    StartProof,
    acceptance_shown,
    failed_letters,
    optional_axes,
)

__all__ = [
    "FOLLOW",
    "POLL_GRACE",
    "POLL_MAX",
    "POLL_MIN",
    "Acceptance",
    "Budget",
    "Confirmation",
    "Follow",
    "FollowStateError",
    "Intent",
    "MoveTiming",
    "MoveTracker",
    "Next",
    "Phase",
    "ProofStep",
    "Prove",
    "Start",
    "StartProof",
    "Verdict",
    "acceptance",
    "acceptance_shown",
    "ack_verdict",
    "contest",
    "cut_short",
    "describe_stop",
    "err_verdict",
    "failed_axes",
    "failed_letters",
    "move_budget",
    "moved_axes",
    "optional_axes",
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
