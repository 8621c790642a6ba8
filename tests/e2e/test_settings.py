"""The settings family against the emulator: snapshot, diff and restore on every firmware
profile, a restore that loses a line, another model's snapshot, save / reload / reset /
factory reset with the emulator's saved store and a power cycle, the controller's
information, and the older firmware's missing instructions."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from helpers import wire_of

import tango_aio
from tango_aio import (
    InvalidCommandError,
    NotSupportedByFirmwareError,
    SettingsRestoreError,
    SnapshotMismatchError,
)
from tango_aio.families import SettingsSnapshot
from tango_aio.sim.profiles import PROFILES
from tango_aio.testing import faults

#: Ten settings changed behind the driver's back, through raw lines, each known to both
#: editions of the manual; with the label each shows in a diff.
CHANGES = {
    "!vel x 3": "vel X", "!accel y 0.5": "accel Y", "!pitch z 2": "pitch Z",
    "!scanvel 2": "scanvel", "!joywindow 20": "joywindow", "!trigd 3": "trigd",
    "!snsf 20": "snsf", "!twi y 0.01": "twi Y", "!lim x -5 5": "lim X",
    "!joyspeed 2 25": "joyspeed 2",
}


def _url(profile: str, state: Path | None = None) -> str:
    return f"sim://?baud=0&profile={profile}" + (f"&state={state}" if state else "")


@pytest.mark.parametrize("profile", sorted(PROFILES))
async def test_snapshot_diff_restore_round_trip(profile: str) -> None:
    async with tango_aio.connect(_url(profile)) as tango:
        snapshot = await tango.settings.snapshot()
        assert snapshot.model == tango.identity.model and snapshot.axes == "xyz"
        assert await tango.settings.diff(snapshot) == []
        for line in CHANGES:
            await tango.command(line)
        found = await tango.settings.diff(snapshot)
        assert sorted(str(d).split(":")[0] for d in found) == sorted(CHANGES.values())
        text = snapshot.to_json()
        written = await tango.settings.restore(SettingsSnapshot.from_json(text))
        assert len(written) == len(CHANGES)
        assert await tango.settings.diff(snapshot) == []
        assert await tango.settings.vel(axis="x") == 10.0


async def test_the_older_firmware_lacks_the_newer_settings_by_name() -> None:
    async with tango_aio.connect(_url("legacy")) as tango:
        snapshot = await tango.settings.snapshot()
        assert "extmode" in snapshot.absent and ("extmode", None, None) not in snapshot.values
        before = wire_of(tango).lines_processed
        with pytest.raises(NotSupportedByFirmwareError, match="'backlash'") as caught:
            await tango.settings.set_backlash(x=5.0)
        assert caught.value.instruction == "backlash"
        assert wire_of(tango).lines_processed == before  # known beforehand: nothing sent
    async with tango_aio.connect("sim://?baud=0&lacks=extmode") as tango:
        with pytest.raises(NotSupportedByFirmwareError, match="'extmode'"):
            await tango.settings.set_extmode(False)  # answered with error 4


async def test_a_line_lost_mid_restore_is_named() -> None:
    async with tango_aio.connect(_url("manual")) as tango:
        snapshot = await tango.settings.snapshot()
        await tango.command("!vel x 3")
        await tango.command("!accel y 0.5")
        faults(tango).lose_line("!vel")
        with pytest.raises(SettingsRestoreError) as caught:
            await tango.settings.restore(snapshot)
        assert list(caught.value.failed) == ["vel X"]
        assert "vel X" in str(caught.value)
        assert await tango.settings.accel(axis="y") == 1.0  # the others were written
        await tango.settings.restore(snapshot)
        assert await tango.settings.diff(snapshot) == []


async def test_another_models_snapshot_is_refused_before_a_byte() -> None:
    async with tango_aio.connect(_url("manual")) as tango:
        snapshot = await tango.settings.snapshot()
        await tango.command("!vel x 3")
        other = dataclasses.replace(snapshot, model="TANGO-PCI")
        wider = dataclasses.replace(snapshot, values={**snapshot.values,
                                                      ("vel", "a", None): 10.0})
        before = wire_of(tango).lines_processed
        with pytest.raises(SnapshotMismatchError, match="TANGO-PCI"):
            await tango.settings.restore(other)
        with pytest.raises(SnapshotMismatchError, match="axes"):
            await tango.settings.restore(wider)
        assert wire_of(tango).lines_processed == before
        assert await tango.settings.vel(axis="x") == 3.0
    async with tango_aio.connect(_url("legacy")) as tango:
        with pytest.raises(SnapshotMismatchError, match=r"lacks settings .*extmode"):
            await tango.settings.restore(snapshot)


async def test_save_reload_reset_and_a_power_cycle(tmp_path: Path) -> None:
    async with tango_aio.connect(_url("manual", tmp_path / "eeprom.json")) as tango:
        model = faults(tango).model  # restarts in 0.1 s (the manual: more than 1 s)
        model.config = dataclasses.replace(model.config, reset_time=0.1)
        await tango.settings.set_vel(x=4.0)
        await tango.settings.save()
        await tango.settings.set_vel(x=5.0)
        await tango.settings.reload()
        assert await tango.settings.vel(axis="x") == 4.0
        await tango.settings.set_vel(x=6.0)
        await tango.settings.reset(confirm=True, quiet=0.2)
        assert tango.autostatus == 1 and await tango.settings.vel(axis="x") == 4.0
        await tango.settings.set_vel(x=7.0)
        faults(tango).power_cycle(0.05)
        await tango.wait_restarted(quiet=0.2)
        assert await tango.settings.vel(axis="x") == 4.0
        await tango.settings.factory_reset(confirm=True, quiet=0.2)
        assert await tango.settings.vel(axis="x") == 10.0
        assert not (tmp_path / "eeprom.json").exists() or \
            "vel" not in (tmp_path / "eeprom.json").read_text()


async def test_restarts_need_an_explicit_confirmation() -> None:
    async with tango_aio.connect(_url("manual")) as tango:
        before = wire_of(tango).lines_processed
        for call in (tango.settings.reset(confirm=False),
                     tango.settings.factory_reset(confirm="yes")):  # type: ignore[arg-type]
            with pytest.raises(InvalidCommandError, match="confirm=True"):
                await call
        assert wire_of(tango).lines_processed == before


async def test_save_is_refused_while_an_axis_moves() -> None:
    async with tango_aio.connect("sim://?baud=0") as tango:
        await tango.settings.set_vel(x=1.0)
        await tango.command("!speed x 1")
        try:
            with pytest.raises(tango_aio.StateError, match="idle"):
                await tango.settings.save()
        finally:
            await tango.stop()


async def test_read_info_reads_the_identity_and_condition() -> None:
    async with tango_aio.connect(_url("manual")) as tango:
        info = await tango.read_info()
        assert info.model == "TANGO-DT" and info.firmware == tango.identity.firmware
        assert info.serial_number == await tango.info.readsn()
        assert isinstance(info.temperature, float) and isinstance(info.uptime, int)
        assert info.max_current is not None and info.ets_present == (False,) * 4
        assert info.stage_serial_numbers == {}
        assert info.as_dict()["max_current"] == list(info.max_current)
