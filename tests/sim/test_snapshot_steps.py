"""The emulator's snapshot events (manual chapter 23): the step modes 1 and 5 through the
snapshot array, the snapshot input's edges, polarity and filter, and the switches where
the manual is silent. Sans-IO, in virtual time (the ``Sim`` harness of ``test_model``)."""

from __future__ import annotations

import pytest

from tango_aio.sim.profiles import Firmware

from .test_model import Sim

pytestmark = pytest.mark.timeout(30)


def sim(**switches: str) -> Sim:
    return Sim(firmware=Firmware().with_(**switches))


def loaded(*z_mm: float, mode: int = 5, **switches: str) -> Sim:
    """Entries holding Z only, the given snapshot mode, no filter."""
    s = sim(**switches)
    s.send("!snsa 0", *(f"!snsa z {i} {z}" for i, z in enumerate(z_mm, 1)),
           f"!snsm {mode}", "!snsf 0")
    assert s.err == 0
    return s


def drive(s: Sim, index: int = 3) -> None:
    """One pulse on the AUX input now, the wire told (as ``testing.Faults`` does)."""
    s.model.pulse_snapshot_input(index, now=s.now)
    s.wire.handler_changed()


def level(s: Sim, value: bool) -> None:
    s.model.set_input("adigin", 3, value, now=s.now)
    s.wire.handler_changed()


def pulse(s: Sim, index: int = 3) -> list[str]:
    """One pulse on the AUX input, then everything that follows; the replies."""
    drive(s, index)
    replies = s.settle()
    s.now += 0.5
    return replies


def z(s: Sim) -> float:
    return float(s.ask("?pos z"))


def test_each_pulse_steps_to_the_next_entry_and_wraps() -> None:
    s = loaded(0.01, 0.02, 0.03)
    seen = []
    for _ in range(4):
        pulse(s)
        seen.append((z(s), s.ask("?snsi")))
    assert seen == [(0.01, "1"), (0.02, "2"), (0.03, "0"), (0.01, "1")]  # L14522-14524
    assert s.send("?pos x", "?pos y") == ["0.0000", "0.0000"]  # axes the entries lack


def test_a_step_is_a_move_the_status_shows() -> None:
    s = loaded(5.0)  # 5 mm at 10 mm/s: a while
    drive(s)
    assert s.ask("sa").startswith("@@M")
    s.settle()
    assert s.ask("sa").startswith("@@@") and z(s) == 5.0


@pytest.mark.parametrize(("pointer", "first"), [("next", 0.01), ("advance", 0.02)])
def test_snapshot_pointer(pointer: str, first: float) -> None:
    s = loaded(0.01, 0.02, 0.03, snapshot_pointer=pointer)
    pulse(s)
    assert z(s) == first
    s.send("!snsi 2")
    pulse(s)
    assert z(s) == (0.03 if pointer == "next" else 0.01)


@pytest.mark.parametrize("report", ["no", "yes"])
def test_snapshot_step_report(report: str) -> None:
    s = loaded(0.01, snapshot_step_report=report)
    assert pulse(s) == (["@@@-."] if report == "yes" else [])
    assert s.send("!moa z 0") == [] and s.settle() == ["@@@-."]  # a line's move reports


@pytest.mark.parametrize("policy", ["move", "ignore"])
def test_snapshot_while_moving(policy: str) -> None:
    s = loaded(5.0, 0.01, snapshot_while_moving=policy)
    drive(s)
    s.now += 0.1
    s.take()
    drive(s)  # while Z travels to 5 mm
    s.settle()
    assert z(s) == 5.0
    if policy == "move":  # a move for a moving axis: refused (move_during_move=refuse)
        assert s.ask("?snsi") == "0" and s.ask("?err") == "0"
    else:
        assert s.ask("?snsi") == "1"


def test_a_step_beyond_a_limit_shows_e_and_moves_nothing() -> None:
    s = loaded(0.01)
    s.send("!lim z -1 0.005")
    pulse(s)
    assert z(s) == 0.0 and s.ask("sa")[2] == "E"


@pytest.mark.parametrize(("snsl", "active"), [(0, False), (1, True)])
def test_only_the_active_edge_counts(snsl: int, active: bool) -> None:
    s = loaded(0.01, 0.02)
    s.send(f"!snsl {snsl}")
    model = s.model
    level(s, not active)
    s.settle()
    assert z(s) == 0.0 and model.devices.inputs["adigin"][3] == int(not active)
    level(s, active)  # L14681-14687
    s.settle()
    assert z(s) == 0.01
    level(s, active)  # no change, no edge
    s.settle()
    assert z(s) == 0.01


def test_the_filter_drops_a_second_edge_inside_its_time() -> None:
    s = loaded(0.01, 0.02, 0.03)
    s.send("!snsf 10")
    drive(s)
    s.now += 0.005
    drive(s)  # a bounce 5 ms later (L14710-14717)
    s.settle()
    assert z(s) == 0.01 and s.ask("?snsi") == "1"
    s.now += 0.011
    pulse(s)
    assert z(s) == 0.02


@pytest.mark.parametrize(("mode", "stepped", "captured"),
                         [(0, False, False), (1, False, False), (4, False, True),
                          (5, True, False)])
def test_the_input_acts_in_modes_4_and_5_only(mode: int, stepped: bool,
                                              captured: bool) -> None:
    s = loaded(0.01, mode=mode)
    pulse(s)
    assert (z(s) == 0.01) is stepped
    assert s.ask("?snsc") == ("2" if captured else "1")  # L14786-14790


@pytest.mark.parametrize("mode", [1, 5])
def test_the_key_f2_steps_in_modes_1_and_5(mode: int) -> None:
    s = loaded(0.01, 0.02, mode=mode)
    s.send("snse 1", "snse 3")  # no function in mode 1 (L14864-14880)
    s.settle()
    assert z(s) == 0.0 and s.ask("?snsc") == "2"
    s.send("snse 2")  # L15409-15410
    s.settle()
    assert z(s) == 0.01 and s.ask("?snsc") == "2"


def test_nothing_while_snapshots_are_off() -> None:
    s = loaded(0.01)
    s.send("!sns 0")
    pulse(s)
    s.send("snse 2")
    s.settle()
    assert z(s) == 0.0


def test_any_input_with_the_snapshot_function_is_a_snapshot_input() -> None:
    s = loaded(0.01, 0.02)
    s.send("!adiginfunc 3 0", "!adiginfunc 1 2")  # L9249-9257
    pulse(s, 3)
    assert z(s) == 0.0
    pulse(s, 1)
    assert z(s) == 0.01


def test_an_entry_written_axis_by_axis_and_one_without_z() -> None:
    s = sim()
    s.send("!snsa 0", "!snsa y 1 0.5", "!snsa x 1 0.25", "!snsa -1 0.1 0.2",
           "!snsm 5", "!snsf 0")
    assert s.send("?snsa 1", "?snsa 2") == ["0.2500 0.5000 0.0000", "0.1000 0.2000 0.0000"]
    s.send("!moa z 0.05")
    s.settle()
    pulse(s)
    assert s.send("?pos") == ["0.2500 0.5000 0.0500"]  # Z held: no position in entry 1
    pulse(s)
    assert s.send("?pos") == ["0.1000 0.2000 0.0500"]


def test_setting_the_mode_or_the_enable_clears_latched_keys() -> None:
    s = sim()
    for line in ("!snsm 0", "!sns 1"):
        s.send("snse 3")
        s.send(line)  # L14650-14652, L14841-14843
        assert s.ask("?keyl") == "0 0 0 0"
    assert s.send("?snsm", "?sns") == ["0", "1"]


def test_an_input_the_controller_lacks_is_refused() -> None:
    s = sim()
    with pytest.raises(ValueError, match="no input"):
        s.model.set_input("adigin", 4, True)
    with pytest.raises(ValueError, match="no input"):
        s.model.set_input("volts", 0, True)
