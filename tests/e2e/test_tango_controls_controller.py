"""The Tango Controls controller device end to end (the server in a subprocess, ``--nodb``
on 127.0.0.1, a ``tango.DeviceProxy`` client in another process, the emulator here): what
the controller says about itself, its settings as JSON, and the trigger output set up,
switched and counted through the device, with the emulator's record of pulses."""

from __future__ import annotations

import json

import pytest
from test_tango_controls import client_of, serving

from tango_aio.families import SettingsSnapshot
from tango_aio.sim.devices import TRIGGER_OUT

pytest.importorskip("tango", reason="the tango-controls extra (pytango) is not installed")

pytestmark = pytest.mark.timeout(180)

INFO = ["Info", "SerialNumber", "Version", "InternalVersion", "Uptime", "Temperature"]


async def test_the_controller_device_reads_what_it_says_about_itself_and_its_settings(
        ) -> None:
    async with serving() as served, client_of(served) as client:
        values = (await client.ask(device="controller", op="read", attrs=INFO))["values"]
        info = json.loads(values["Info"])
        assert info["serial_number"] == served.model.config.serial == values["SerialNumber"]
        assert info["model"] == "TANGO-DT"
        for attr, field in (("Version", "version"), ("InternalVersion", "internal_version"),
                            ("Temperature", "temperature")):
            assert info[field] is not None and values[attr] == pytest.approx(info[field])
        assert info["uptime"] <= values["Uptime"] <= info["uptime"] + 60  # read after
        await client.ask(op="write", attr="Velocity", value=12.5)
        # Every setting is read (1.3-1.6 s at 57600 Bd on a loaded machine): beyond the
        # proxy's default 3 s timeout beside CPU burners, so the client sets its own.
        text = (await client.ask(device="controller", op="read", attrs=["Settings"],
                                 timeout_ms=60000))["values"]["Settings"]
        snapshot = SettingsSnapshot.from_json(text)
        assert json.loads(snapshot.to_json()) == json.loads(text)
        assert served.model.params.first("vel") == pytest.approx(12.5)
        assert snapshot.values[("vel", "x", None)] == pytest.approx(12.5)
        assert snapshot.serial_number == served.model.config.serial


async def test_the_trigger_output_is_set_up_switched_and_counted_through_the_device() -> None:
    async with serving() as served, client_of(served) as client:
        ask = client.ask
        await ask(device="controller", op="write", attr="TriggerConfig",
                  value=json.dumps({"axis": "x", "mode": 0, "distance": 1.0,
                                    "width_us": 200}))
        config = json.loads((await ask(device="controller", op="read",
                                       attrs=["TriggerConfig"]))["values"]["TriggerConfig"])
        assert (config["axis"], config["mode"], config["distance"], config["width_us"]) == \
            ("x", 0, 1.0, 200)
        assert served.model.params.first("trigs") == 200
        await ask(device="controller", op="write", attr="TriggerCount", value=0)
        await ask(device="controller", op="write", attr="TriggerEnabled", value=True)
        assert served.model.params.first("trig") == 1
        await ask(op="write", attr="Velocity", value=20.0)
        await ask(op="write", attr="Position", value=3.5)
        assert (await ask(op="until", leave=["MOVING"]))["state"] == "ON"
        values = (await ask(device="controller", op="read",
                            attrs=["TriggerCount", "TriggerEnabled"]))["values"]
        pulses = served.model.devices.pulses_of(TRIGGER_OUT)
        assert [p.position for p in pulses] == pytest.approx([0.0, 1.0, 2.0, 3.0], abs=1e-6)
        assert values == {"TriggerCount": len(pulses), "TriggerEnabled": True}
        assert [p.width for p in pulses] == pytest.approx([0.0002] * len(pulses))
        await ask(device="controller", op="write", attr="TriggerEnabled", value=False)
        assert served.model.params.first("trig") == 0


BAD_CONFIGS = ['{"width_us": 7.5}', '{"colour": 1}', "[1]", "{", '{"mode": 20}', '{"axis": "q"}']


async def test_a_bad_trigger_configuration_is_refused_before_any_line() -> None:
    async with serving() as served, client_of(served) as client:
        before = served.model.params.first("trigs")
        for value in BAD_CONFIGS:
            answer = await client.ask(device="controller", op="write", attr="TriggerConfig",
                                      value=value)
            assert answer.get("error") == "TangoAio_InvalidCommandError", (value, answer)
        assert served.model.params.first("trigs") == before
