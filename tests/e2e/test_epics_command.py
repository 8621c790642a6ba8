"""The ``tango-aio ioc`` command line (no caproto needed for these)."""

from __future__ import annotations

import pytest

from tango_aio.cli._main import main
from tango_aio.epics.command import loopback_only, parse_controllers


def test_one_url_or_named_controllers() -> None:
    assert parse_controllers("/dev/ttyUSB0", []) == {"": "/dev/ttyUSB0"}
    assert parse_controllers(None, ["stage=sim://", "focus=socket://h:4001"]) == {
        "stage": "sim://", "focus": "socket://h:4001"}
    for url, named in [(None, []), ("sim://", ["a=sim://"]), (None, ["a"]),
                       (None, ["=sim://"]), (None, ["a:b=sim://"]),
                       (None, ["a=sim://", "a=sim://?axes=2"])]:
        with pytest.raises(ValueError):
            parse_controllers(url, named)


def test_loopback_detection() -> None:
    assert loopback_only(["127.0.0.1"]) and loopback_only(["127.0.0.1", "::1"])
    assert not loopback_only(["0.0.0.0"]) and not loopback_only(["192.168.1.20"])
    assert not loopback_only(["localhost"])  # a name: not known to be loopback


def test_usage_errors_exit_nonzero(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["ioc", "--prefix", "P:"]) == 2  # a usage error
    assert "controller URL" in capsys.readouterr().err
    assert main(["ioc", "sim://", "--prefix", "P:", "--allow-user", ""]) == 2
    with pytest.raises(SystemExit):
        main(["ioc", "sim://"])  # --prefix is required


def test_record_arithmetic() -> None:
    from tango_aio.epics.record import (
        AxisUnits,
        LimitSwitches,
        Msta,
        calibrated,
        limit_switches,
        msta,
    )

    mm = AxisUnits(dim=2, pitch=2.0)  # 2 mm per revolution
    assert mm.velo_from_vel(10.0) == pytest.approx(20.0)  # rev/s -> mm/s
    assert mm.vel_from_velo(20.0) == pytest.approx(10.0)
    assert mm.accel_from_accl(20.0, 0.1) == pytest.approx(0.2)  # 200 mm/s² = 0.2 m/s²
    assert mm.accl_from_accel(20.0, 0.2) == pytest.approx(0.1)
    um = AxisUnits(dim=1, pitch=1.0)
    assert um.egu == "um" and um.velo_from_vel(1.0) == pytest.approx(1000.0)
    assert AxisUnits(dim=9, pitch=2.0).velo_from_vel(5.0) == pytest.approx(5.0)  # mm/s
    with pytest.raises(ValueError):
        mm.accel_from_accl(20.0, 0.0)
    assert limit_switches("000000001000", "x") == LimitSwitches(low=False, high=True)
    assert limit_switches("010000000000", "y") == LimitSwitches(low=True, high=False)
    assert limit_switches("", "x") == LimitSwitches()
    assert calibrated("A---D-----------", "x") and not calibrated("A---", "y")
    word = msta(moving=False, switches=LimitSwitches(high=True), problem=True,
                comm_error=False, homed=True, positive=True)
    assert word == (Msta.DONE | Msta.PLUS_LS | Msta.PROBLEM | Msta.HOMED | Msta.DIRECTION)
