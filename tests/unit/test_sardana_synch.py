"""What a position-domain synchronisation asks of the trigger output, and the trigger/gate
state from the counter (tango_aio.sardana's pure part; no Sardana needed)."""

from __future__ import annotations

import math

import pytest

from tango_aio.sardana._state import State
from tango_aio.sardana._synch import Group, plan, trigger_state


def test_one_group_is_one_range_both_ends_included() -> None:
    found = plan([Group(0.5, 0.25, 5, active_time=0.0002)])
    assert found.range == (0.5, 1.5, 5)
    assert found.positions == (0.5, 0.75, 1.0, 1.25, 1.5)
    assert found.width_us == 200


@pytest.mark.parametrize("groups", [[Group(1.0, 1.0, 1)],
                                    [Group(3.0, -1.0, 2), Group(0.5, -0.25, 2)]])
def test_a_single_pulse_or_several_groups_are_a_list(groups: list[Group]) -> None:
    found = plan(groups)
    assert found.range is None and found.width_us is None
    assert list(found.positions) == [p for g in groups
                                     for p in (g.initial + i * g.total
                                               for i in range(g.repeats))]


@pytest.mark.parametrize("groups", [
    [], [Group(0.0, 0.0, 3)], [Group(0.0, 1.0, 0)], [Group(math.nan, 1.0, 2)],
    [Group(0.0, 1.0, 3), Group(1.0, 1.0, 2)],  # 2.0 repeated: not strictly monotonic
    [Group(0.0, 1.0, 2), Group(5.0, -1.0, 2)],  # turns back
    [Group(0.0, 1.0, 2, 0.001), Group(5.0, 1.0, 2, 0.002)],  # two pulse widths
])
def test_what_the_output_cannot_do_is_refused(groups: list[Group]) -> None:
    with pytest.raises(ValueError):
        plan(groups)


@pytest.mark.parametrize(("started", "stopped", "enabled", "count", "state"), [
    (False, False, False, 0, State.ON),
    (True, False, True, 2, State.MOVING),
    (True, False, True, 3, State.ON),
    (True, False, True, 4, State.ALARM),
    (True, True, False, 1, State.ON),
    (True, False, False, 1, State.ALARM),
])
def test_the_state_follows_the_counter(started: bool, stopped: bool, enabled: bool,
                                       count: int, state: State) -> None:
    found, status = trigger_state(loaded=True, started=started, stopped=stopped,
                                  enabled=enabled, count=count, expected=3)
    assert found is state and status
