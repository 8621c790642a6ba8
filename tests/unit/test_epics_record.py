"""The IOC's pure motor-record logic (tango_aio.epics.record): alarms, limits, metadata."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tango_aio.epics.access import AccessPolicy
from tango_aio.epics.record import (
    LINK_DOWN,
    NO_ALARM,
    Alarm,
    AxisUnits,
    Ending,
    derived_fields,
    fault_after,
    limit_violation,
    nint,
    revolution_speeds,
    shown_alarm,
)
from tango_aio.units import UnitScale

FAULTS = st.sampled_from([NO_ALARM, Alarm("STATE", "MAJOR_ALARM"),
                          Alarm("HIGH", "MAJOR_ALARM"), Alarm("LOW", "MAJOR_ALARM")])


@given(FAULTS)
def test_a_failed_move_raises_the_alarm_whatever_it_was(fault: Alarm) -> None:
    assert fault_after(fault, Ending.FAILED) == Alarm("STATE", "MAJOR_ALARM")


@given(FAULTS)
def test_only_a_move_that_arrived_clears_the_alarm(fault: Alarm) -> None:
    assert fault_after(fault, Ending.ARRIVED) == NO_ALARM
    for ending in Ending:
        if ending is not Ending.ARRIVED and fault != NO_ALARM:
            assert fault_after(fault, ending) != NO_ALARM, ending


@given(FAULTS)
def test_a_stop_neither_raises_nor_clears_the_alarm(fault: Alarm) -> None:
    assert fault_after(fault, Ending.STOPPED) == fault


def test_a_failed_move_then_stop_then_a_good_move() -> None:
    fault = fault_after(NO_ALARM, Ending.FAILED)
    fault = fault_after(fault, Ending.STOPPED)
    assert shown_alarm(fault, link_up=True) == Alarm("STATE", "MAJOR_ALARM")
    assert shown_alarm(fault, link_up=False) == LINK_DOWN
    assert shown_alarm(fault_after(fault, Ending.ARRIVED), link_up=True) == NO_ALARM


def test_a_target_beyond_the_soft_limits_is_a_violation_on_its_side() -> None:
    assert limit_violation(2600.1, -5.0, 2600.0) is Ending.ABOVE_LIMIT
    assert limit_violation(-5.1, -5.0, 2600.0) is Ending.BELOW_LIMIT
    assert limit_violation(2600.0, -5.0, 2600.0) is None
    assert limit_violation(-5.0, -5.0, 2600.0) is None
    assert limit_violation(1e6, 0.0, 0.0) is None  # 0 and 0: no limits (motor record)
    assert fault_after(NO_ALARM, Ending.ABOVE_LIMIT) == Alarm("HIGH", "MAJOR_ALARM")
    assert fault_after(NO_ALARM, Ending.BELOW_LIMIT) == Alarm("LOW", "MAJOR_ALARM")


@pytest.mark.parametrize(("units", "mres", "urev", "srev"), [
    (AxisUnits(), 2.5e-5, 1.0, 40000),  # mm, 1 mm pitch: the 2.5e-5 mm
    (AxisUnits(pitch=4.0, gear=2.0, usteps=200), 0.01, 2.0, 200),
    (AxisUnits(dim=1, pitch=2.0), 0.05, 2000.0, 40000),  # um
    (AxisUnits(dim=0, usteps=25600), 1.0, 25600.0, 25600),  # microsteps
])
def test_the_resolution_fields_are_the_unit_scales(units: AxisUnits, mres: float,
                                                   urev: float, srev: int) -> None:
    assert units.mres == pytest.approx(mres)
    assert units.urev == pytest.approx(urev)
    assert units.srev == srev
    # One home: the same facts the Bluesky device reports.
    scale = UnitScale(units.dim, units.pitch, units.gear, units.usteps)
    assert units.mres == scale.resolution == scale.user_per_rev / scale.usteps


def test_rdbd_is_the_drivers_tolerance_and_at_least_mres() -> None:
    assert AxisUnits().rdbd(4) == pytest.approx(1.5e-4)
    assert AxisUnits().rdbd(0) == pytest.approx(1.5)
    coarse = AxisUnits(pitch=1000.0, usteps=200)  # 5 mm per step
    assert coarse.rdbd(4) == pytest.approx(5.0)


def test_accs_is_accel_in_egu_per_s2() -> None:
    assert AxisUnits().accs_from_accel(0.2) == pytest.approx(200.0)  # 0.2 m/s² in mm/s²
    assert AxisUnits(dim=1).accs_from_accel(0.2) == pytest.approx(2e5)  # um/s²
    units = AxisUnits()
    velo = 20.0
    accl = units.accl_from_accel(velo, 0.2)
    assert velo / accl == pytest.approx(units.accs_from_accel(0.2))


@given(st.floats(-1e9, 1e9))
def test_nint_is_the_nearest_integer_halves_away_from_zero(value: float) -> None:
    rounded = nint(value)
    assert abs(rounded - value) <= 0.5
    assert nint(-value) == -rounded


def test_nint_rounds_halves_as_c_does_not_to_even() -> None:
    assert [nint(v) for v in (0.5, 1.5, 2.5, -0.5, -2.5)] == [1, 2, 3, -1, -3]


def test_the_raw_fields_are_the_dial_values_in_microsteps() -> None:
    fields = derived_fields(val=4.0, dval=3.0, drbv=2.9999, mres=2.5e-5)
    assert fields == {"RVAL": 120000, "RRBV": 119996, "RMP": 119996,
                      "DIFF": pytest.approx(1e-4), "RDIF": 4, "LVAL": 4.0, "LDVL": 3.0,
                      "LRVL": 120000}


def test_speeds_in_revolutions_per_second_are_egu_per_s_over_urev() -> None:
    assert revolution_speeds(velo=5.0, vmax=20.0, urev=2.0) == {
        "S": 2.5, "SMAX": 10.0, "SBAS": 0.0}
    assert revolution_speeds(velo=5.0, vmax=20.0, urev=-2.0)["S"] == 2.5
    assert revolution_speeds(velo=5.0, vmax=20.0, urev=0.0)["S"] == 0.0


def test_allowed_hosts_are_compared_whole_without_trimming_blanks() -> None:
    policy = AccessPolicy.build(hosts=["acq-pc"], users=["alice"])
    assert policy.may_write("acq-pc", "alice") and policy.may_write("ACQ-PC", "alice")
    assert policy.may_write("acq-pc.", "alice")  # DNS's root dot
    for reported in ("acq-pc ", " acq-pc", "acq-pc\t", "acq-pc\n", "acq-pc.lab"):
        assert not policy.may_write(reported, "alice"), reported
    assert not policy.may_write("acq-pc", "alice ")
    for hosts, users in ((["acq-pc "], []), ([" acq-pc"], []), ([], ["alice "]), ([""], [])):
        with pytest.raises(ValueError):
            AccessPolicy.build(hosts=hosts, users=users)
