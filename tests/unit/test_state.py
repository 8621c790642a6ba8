"""DriverState: the driver's cached settings, updated without I/O."""

from __future__ import annotations

import pytest

from tango_aio.catalog._encode import build
from tango_aio.catalog._instructions import INSTRUCTIONS, Context, parse
from tango_aio.moves._timing import MoveTiming
from tango_aio.sansio._state import CACHED_SETTINGS, DriverState


def test_starts_at_the_power_on_timing_and_context() -> None:
    state = DriverState()
    assert isinstance(state, MoveTiming)
    assert state.dims == [2, 2, 2, 2] and state.vel == [10.0] * 4
    assert (state.delay_ms, state.pause_ms, state.settle_ms, state.extmode) == (0, 0, 0, 0)
    assert state.context == Context((2, 2, 2, 2), 4, 0)


def test_the_cached_settings_are_the_catalogs() -> None:
    assert [e.name for e in CACHED_SETTINGS] == [
        "extmode", "dim", "pitch", "accel", "vel", "secvel", "delay", "pause", "ctrt"]


@pytest.mark.parametrize(("line", "attribute", "expected"), [
    ("!vel y 5", "vel", [10.0, 5.0, 10.0, 10.0]),
    ("!vel 5 6", "vel", [5.0, 6.0, 10.0, 10.0]),
    ("!vel 1 2 3", "vel", [1.0, 2.0, 3.0, 10.0]),
    ("!dim 1 9", "dims", [1, 9, 2, 2]),
    ("!pitch a 4", "pitch", [1.0, 1.0, 1.0, 4.0]),
    ("!accel 0.5", "accel", [0.5, 1.0, 1.0, 1.0]),
    ("!secvel x 3", "secvel", [3.0, 10.0, 10.0, 10.0]),
    ("!extmode 1", "extmode", 1),
    ("!delay 250", "delay_ms", 250.0),
    ("!pause 40", "pause_ms", 40.0),
    ("!ctrt 1500", "settle_ms", 1500.0),
])
def test_observe_takes_in_an_accepted_set(line: str, attribute: str, expected: object) -> None:
    state = DriverState()
    # True only where the setting is part of the validation context (dim, extmode).
    assert state.observe(parse(line)) is (attribute in ("dims", "extmode"))
    assert getattr(state, attribute) == expected
    assert type(getattr(state, attribute)) is type(expected)


def test_dims_and_extmode_change_the_context() -> None:
    state = DriverState()
    state.observe(parse("!dim y 9"))
    state.observe(parse("!extmode 1"))
    state.axes = 3
    assert state.context == Context((2, 9, 2, 2), 3, 1)


@pytest.mark.parametrize("line", ["?vel", "?vel x 4", "!moa 1 2", "!autostatus 4",
                                  "!posclr", "?dim"])
def test_observe_ignores_reads_and_settings_it_does_not_cache(line: str) -> None:
    state = DriverState()
    assert state.observe(parse(line)) is False
    assert state == DriverState()


def test_load_stores_values_read_back() -> None:
    state = DriverState()
    state.load(INSTRUCTIONS["vel"], {"x": 3.5, "z": 7})
    state.load(INSTRUCTIONS["dim"], {"y": "1"})
    state.load(INSTRUCTIONS["ctrt"], 1000)
    state.load(INSTRUCTIONS["extmode"], 1)
    assert state.vel == [3.5, 10.0, 7.0, 10.0] and state.dims == [2, 1, 2, 2]
    assert state.settle_ms == 1000.0 and type(state.settle_ms) is float
    assert state.extmode == 1


def test_load_refuses_what_does_not_fit() -> None:
    state = DriverState()
    with pytest.raises(ValueError, match="not a cached setting"):
        state.load(INSTRUCTIONS["cur"], {"x": 1.0})
    with pytest.raises(TypeError, match="vel"):
        state.load(INSTRUCTIONS["vel"], 3.0)


def test_states_do_not_share_their_lists() -> None:
    first, second = DriverState(), DriverState()
    first.observe(build("vel", x=2.0))
    assert second.vel == [10.0] * 4
