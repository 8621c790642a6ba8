"""What an axis device's ``State`` and ``Status`` say (``tango_aio.tango_controls``'s
pure rule)."""

from __future__ import annotations

from tango_aio.tango_controls import AxisView, Shown, shown


def test_the_link_outranks_everything() -> None:
    view = AxisView(link_up=True, ready=True).started("move to 1").link(False)
    assert shown(view)[0] is Shown.FAULT
    assert shown(view.link(True))[0] is Shown.INIT  # settings read again first
    assert shown(view.link(True).settings_read())[0] is Shown.MOVING


def test_moving_from_acceptance_to_the_verdict() -> None:
    view = AxisView(link_up=True, ready=True)
    assert shown(view) == (Shown.ON, "standing")
    moving = view.started("move to 3")
    assert shown(moving) == (Shown.MOVING, "move to 3: under way")
    assert shown(moving.read(False))[0] is Shown.MOVING  # a read does not end it
    assert shown(moving.ended(None)) == (Shown.ON, "move to 3: arrived")


def test_a_move_ended_short_stays_alarm_until_one_arrives() -> None:
    view = AxisView(link_up=True, ready=True).started("move to 3").ended("limit switch")
    assert shown(view) == (Shown.ALARM, "move to 3 ended short: limit switch")
    assert shown(view.read(False))[0] is Shown.ALARM
    assert shown(view.started("move to 0"))[0] is Shown.MOVING
    assert shown(view.started("move to 0").ended(None))[0] is Shown.ON
    assert "after: limit switch" in shown(view.link(False))[1]


def test_motion_nobody_here_started_shows_moving() -> None:
    view = AxisView(link_up=True, ready=True).read(True)
    assert shown(view) == (Shown.MOVING, "moving (not started by this server)")
    assert shown(view.read(False))[0] is Shown.ON


def test_init_until_the_settings_are_read() -> None:
    assert shown(AxisView(link_up=True))[0] is Shown.INIT
    assert shown(AxisView())[0] is Shown.FAULT
