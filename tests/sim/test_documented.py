"""Documented behaviours that third-party TANGO client code met (issue #12, item 3), under
both profiles: the joystick at power-on and ``!joy 0``, ``pause``/``delay`` and closed-loop
settling, internal errors in ``?err``, the reboot after ``reset``, ``?statusaxis`` of an
absent axis and a refused move in mode 1. Sans-IO, virtual time."""

from __future__ import annotations

import pytest

from tango_aio.sim.profiles import PROFILES

from .test_model import Sim, trapezoid_time

pytestmark = pytest.mark.timeout(30)

PROFILE_NAMES = list(PROFILES)


def sim(profile: str, axes: int = 3) -> Sim:
    return Sim(axes=axes, firmware=PROFILES[profile])


@pytest.mark.parametrize("profile", PROFILE_NAMES)
def test_the_joystick_is_on_at_power_on_and_joy_0_reports(profile: str) -> None:
    """L7142: ``?joy ==> 2 (HDI is enabled)``; switching it off sends ``@@@-.`` (L2093,
    L7154), not when it already is off (L7156)."""
    s = sim(profile)
    assert s.ask("?joy") == "2"
    assert s.send("!joy 0") == ["@@@-."]
    assert s.send("!joy 0") == []
    assert s.send("!joy 2") == []


@pytest.mark.parametrize("profile", PROFILE_NAMES)
def test_joy_0_reports_during_a_move_and_the_move_goes_on(profile: str) -> None:
    s = sim(profile)
    s.send("!moa 4")
    s.now += 0.1
    assert s.send("!joy 0") == ["@@@-."]  # looks like a completion: the axis still moves
    assert s.ask("sa") == "M@@-.-"
    events = s.events()
    assert [line for _, line in events] == ["@@@-."]
    assert events[0][0] == pytest.approx(trapezoid_time(4.0, 10.0, 1000.0), abs=0.02)
    assert s.ask("?pos x") == "4.0000"


def test_joy_0_in_mode_2_reports_then_acknowledges() -> None:
    s = sim("manual")
    s.send("!autostatus 2")
    assert s.send("!joy 0") == ["@@@-.", "OK..."]


@pytest.mark.parametrize("profile", PROFILE_NAMES)
def test_delay_holds_the_start_and_pause_the_report(profile: str) -> None:
    """``delay`` delays the start of moa/mor/moc/m, ``pause`` the report (L6845-6899)."""
    s = sim(profile)
    s.send("!delay 300", "!pause 200")
    s.send("!moa 1")
    s.now += 0.29
    assert s.ask("?pos x") == "0.0000"
    assert s.ask("sa") == "M@@-.-"  # reserved by the delayed move
    events = s.events()
    travel = 0.3 + trapezoid_time(1.0, 10.0, 1000.0)
    assert [line for _, line in events] == ["@@@-."]
    assert events[0][0] == pytest.approx(0.29 + (travel - 0.29) + 0.2, abs=0.02)


@pytest.mark.parametrize("profile", PROFILE_NAMES)
def test_closed_loop_settling_delays_the_report(profile: str) -> None:
    """In closed loop the report waits until the axis held ±twi for ``ctrd`` ms
    (L11616-11631); closed loop needs ``ctr`` and ``encmask`` (L11761-11800)."""
    open_loop, closed = sim(profile), sim(profile)
    closed.send("!encmask 1 0 0", "!ctrd x 400")
    times = []
    for s in (open_loop, closed):
        s.send("!moa 1")
        events = s.events()
        assert [line for _, line in events] == ["@@@-."]
        times.append(events[0][0])
    # The older edition has no 'ctrd' instruction (error 4): its default 10 ms applies.
    settle = 0.4 if profile == "manual" else 0.01
    assert times[1] - times[0] == pytest.approx(settle, abs=1e-6)
    closed.send("!ctr x 0")  # closed loop off: no settling
    start = closed.now
    closed.send("!moa 0")
    assert closed.events()[0][0] - start == pytest.approx(times[0], abs=1e-6)


@pytest.mark.parametrize("profile", PROFILE_NAMES)
def test_an_internal_error_shows_while_the_last_instruction_was_fine(profile: str) -> None:
    """L2853-2867: "If the previously executed instruction returned no error, the 'err'
    response is either 0 or if an internal error state is active, the internal error is
    returned"."""
    s = sim(profile)
    s.model.inject_internal_error(29, permanent=True)
    assert s.send("!vel 3", "?err", "?status") == ["29", "ERR 29"]
    assert s.send("!vel -3", "?err") == ["5"]  # an instruction error hides it
    assert s.send("!err", "?err") == ["29"]  # permanent: '!err' cannot clear it
    s.model.inject_internal_error(21)
    assert s.send("?err", "!err", "?err") == ["21", "0"]
    with pytest.raises(ValueError, match="20 and above"):
        s.model.inject_internal_error(5)


def test_a_reset_clears_an_internal_error() -> None:
    s = sim("manual")
    s.model.inject_internal_error(27)
    s.send("reset")
    s.now += 1.5
    assert s.send("?err") == ["0"]


@pytest.mark.parametrize("profile", PROFILE_NAMES)
def test_input_during_the_reboot_is_lost(profile: str) -> None:
    """L1837-1857: no reply to a reset, >1 s not responding; the host polls ``?err`` every
    0.5 s until it answers. Polls sent while it reboots are lost, so exactly one of them
    (the first after the reboot) answers."""
    s = sim(profile)
    s.send("!autostatus 2")
    s.write(b"reset\r")
    answers = []
    for _ in range(5):
        s.write(b"?err\r")
        s.now += 0.5
        answers.append(s.take())
    assert answers == [[], [], ["0"], ["0"], ["0"]]
    assert s.wire.lost_bytes == 10
    assert s.ask("?autostatus") == "1"


@pytest.mark.parametrize("profile", PROFILE_NAMES)
def test_statusaxis_of_an_absent_axis_answers_a_dash(profile: str) -> None:
    """``?statusaxis z`` on a 2-axis unit: ``-`` like the all-axes form (L2711, L2721)."""
    s = sim(profile, axes=2)
    assert s.send("?statusaxis z", "?err", "sa a") == ["-", "0", "-"]


@pytest.mark.parametrize("profile", PROFILE_NAMES)
def test_a_refused_move_in_mode_1_sends_nothing_and_shows_e(profile: str) -> None:
    """The choice from L2705 (statusaxis "E => error response, move aborted or not
    executed"): a refused move sets the error, reports nothing, and the axes it named show
    ``E`` until the next move (switch ``refused_move_report`` adds a report)."""
    s = sim(profile)
    s.send("!lim x -1 1")
    assert s.send("!moa 5") + s.settle() == []
    assert s.send("?err", "sa") == ["5", "E@@-.-"]
    assert s.send("!moa 0.5 0.5 0.5") + s.settle() == ["@@@-."]
    assert s.ask("sa") == "@@@-.-"
    assert s.send("!moa y 0.5 5") + s.settle() == []  # wrong count of values: parser error
    assert s.send("!cal", "?err") == ["0"]


def test_the_older_edition_names_error_4_unknown_keyword() -> None:
    """old L819: ``help => ERROR 4,unknown keyword``; 1.71 calls it "invalid instruction"."""
    older, newer = sim("legacy"), sim("manual")
    assert older.send("!nosuchthing", "?help") == ["ERROR 4,unknown keyword"]
    assert newer.send("!nosuchthing", "?help") == ["ERROR 4,invalid instruction"]
