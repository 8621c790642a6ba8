"""Snapshot events (manual chapter 23, L14499-14861): what the key F2 (``snse 2``) or an
edge at the snapshot input does in the snapshot modes the emulator models.

* Modes 0 and 4 capture the axes' positions into the array, 1 and 5 step to the next
  entry of the array (L14752-14790); 0 and 1 take the key F2, 4 and 5 the snapshot
  input instead (L14786-14790). ``snse 2`` is "the function normally executed by
  pressing Joystick F2 key or using the AUX I/O SnapShot input" (L15409-15410), so it
  steps in mode 5 too. Nothing happens while snapshots are off (``sns 0``, L14644-14648).
* A step moves every axis the entry holds a position for (L14833-14836, L15389-15390)
  like a ``moa`` of them (speeds, limits, ``delay``); the entry comes from the pointer
  ``snsi`` (switch ``snapshot_pointer``), the pointer wraps at the end (L14522-14524).
  Whether a step reports (``snapshot_step_report``) and what an event does while the
  axes still move (``snapshot_while_moving``) are switches: the manual is silent.
  Choice: a step the motion model refuses (a target beyond a limit) shows ``E`` on its
  axes, as a refused ``moa`` does (L2705), and sets no error number (no line ran).
* The snapshot input is an AUX input whose function is 2 (``adiginfunc``, input 3 by
  default, L9203-9218); its active edge is falling for ``snsl 0`` and rising for
  ``snsl 1`` (L14681-14687). The filter ``snsf`` "does not delay the reaction to the
  signal, it only delays the next detection of a signal change" (L14710-14717). Choice:
  an active edge inside the filter time after a detected one is not detected (a bounce),
  nor later; the inactive edge starts nothing.
* Choice where the mode has keys the table leaves empty (mode 1's F1, F3, F4:
  L14864-14880): nothing happens; in the other modes every key captures, as before
  (their own functions are not modelled, nor is mode 6's triggered start).
"""

from __future__ import annotations

from .motion import MotionRefused
from .port import ModelPort

__all__ = ["SNAPSHOT_FUNCTION", "active_level", "input_changed", "key_event"]

#: ``adiginfunc``'s function of a snapshot input (L9203).
SNAPSHOT_FUNCTION = 2
#: Modes that step through the array: on the key F2, on the snapshot input (L14759, L14789).
_STEP_KEY, _STEP_INPUT = 1, 5
#: Modes that capture on the snapshot input (L14786).
_CAPTURE_INPUT = 4


def _enabled(m: ModelPort) -> bool:
    return int(m.params.first("sns")) == 1


def _mode(m: ModelPort) -> int:
    return int(m.params.first("snsm"))


def key_event(m: ModelPort, key: int) -> None:
    """``snse key`` (1..4): latch the key (``keyl``) and do what the mode does with it."""
    m.session.keys_latched[key - 1] = 1
    if not _enabled(m):
        return
    if _mode(m) in (_STEP_KEY, _STEP_INPUT):
        if key == 2:
            step(m)
        return
    capture(m)


def input_changed(m: ModelPort, index: int, level: bool, now: float) -> None:
    """AUX input ``index`` (``adigin``) changed to ``level`` at ``now``: a snapshot event
    if it is a snapshot input and the change is its active edge, outside the filter time."""
    functions = m.params.global_values["adiginfunc"]
    if int(functions[index]) != SNAPSHOT_FUNCTION:
        return
    session = m.session
    if level != active_level(m) or now < session.snapshot_quiet_until:
        return
    session.snapshot_quiet_until = now + float(m.params.first("snsf")) / 1000.0
    if not _enabled(m):
        return
    mode = _mode(m)
    if mode == _STEP_INPUT:
        step(m)
    elif mode == _CAPTURE_INPUT:
        capture(m)


def active_level(m: ModelPort) -> bool:
    """The snapshot input's active level: high for ``snsl 1`` (L14681-14687)."""
    return int(m.params.first("snsl")) == 1


def capture(m: ModelPort) -> None:
    """Append the axes' positions to the array."""
    motion = m.motion
    m.snapshots.capture(tuple(motion.to_user(i, motion.position(i)) for i in range(m.axes)))


def step(m: ModelPort) -> None:
    """Move to the next entry of the array."""
    snapshots, motion = m.snapshots, m.motion
    if not snapshots.entries:
        return
    if m.firmware.snapshot_while_moving == "ignore" and any(
            motion.is_moving(i) for i in range(m.axes)):
        return
    row = snapshots.step(advance_first=m.firmware.snapshot_pointer == "advance")
    assert row is not None
    targets: dict[int | str, float] = {
        i: motion.from_user(i, value) for i, value in enumerate(row[: m.axes])
        if value is not None}
    if not targets:
        return
    try:
        job = motion.move_absolute(targets)
    except MotionRefused:
        motion.mark_not_executed(targets)
        return
    m.session.snapshot_jobs.add(job)
