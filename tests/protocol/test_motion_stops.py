"""The per-axis stop epoch of :class:`tango_aio.controller._motion.Motion` (#26 item 3): a stop of
some axes counts against the moves of those axes only."""

from __future__ import annotations

from typing import cast

from tango_aio.controller._motion import Motion, MotionPort


def test_a_one_axis_stop_counts_for_that_axis_only() -> None:
    motion = Motion(cast(MotionPort, object()))  # stopped()/epoch() never use the port
    x, y, xy, z = (motion.epoch(axes) for axes in (("x",), ("y",), ("x", "y"), ("z",)))
    motion.stopped(["x"])
    assert motion.epoch(("x",)) != x
    assert motion.epoch(("x", "y")) != xy  # a merged line moving X is stopped too
    assert motion.epoch(("y",)) == y
    assert motion.epoch(("z",)) == z
    y = motion.epoch(("y",))
    z = motion.epoch(("z",))
    motion.stopped()  # `a` or Ctrl+C: every axis
    assert motion.epoch(("y",)) != y
    assert motion.epoch(("z",)) != z


def test_every_stop_wakes_the_moves_being_followed() -> None:
    motion = Motion(cast(MotionPort, object()))
    hints = motion._hints
    motion.stopped(["y"])  # a move of X re-reads the state too (and goes on)
    assert motion._hints == hints + 1
