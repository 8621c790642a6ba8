"""``tango-aio probe`` (issue #32): a probe of the emulator under every profile and every
single-switch variant returns that variant's switch values, with and without moves; without
moves it writes no move line and leaves every setting as it found it; a fingerprint makes
the emulator behave like the unit; behaviour no switch has is recorded as unknown.

Probes run concurrently on one event loop (each on its own emulator), in instant mode, with
short exchanges (``settle``) and quick moves (``speed``): the default run takes the
profiles and the variants the driver does not serve yet; every variant is under ``slow``.
"""

from __future__ import annotations

import asyncio
import copy
import json
import os
import subprocess
import sys
import urllib.parse
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pytest

import tango_aio
from tango_aio.catalog._instructions import lookup
from tango_aio.fieldkit._decide import (
    MOVE_SWITCHES,
    SAVE_SWITCHES,
    SWITCH_NAMES,
    UNPROBED_SWITCHES,
    Exchange,
    decide_ack_case,
    decide_echo_text,
    decide_help_number,
    decide_lim_cr_bug,
)
from tango_aio.fieldkit._probe import (
    ProbeOptions,
    ProbeResult,
    comparable,
    probe,
    write_fingerprint,
)
from tango_aio.fieldkit._trace import parse_trace
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.profiles import PROFILES, SWITCHES, Firmware, variants
from tango_aio.sim.serve import serve_tcp
from tango_aio.sim.wire import Emit, WireConfig
from tango_aio.testing import replay

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]

#: Quick exchanges and moves: instant wire, 10x motion, 0.05 s of silence ends an exchange.
FAST = ProbeOptions(settle=0.05, move_time=0.05)
FAST_MOVES = ProbeOptions(moves=True, save=True, settle=0.05, move_time=0.05)
#: Across processes (another process may be descheduled for a while on a loaded machine).
SLOW_LINK = ProbeOptions(settle=0.3)

ALL = dict(variants(unsupported=True))
UNSUPPORTED = [f"{name}={value}" for name, doc in SWITCHES.items()
               for value in doc.unsupported]


def url_of(name: str, **extra: str) -> str:
    query = {"baud": "0", "speed": "10", **extra}
    if name in PROFILES:
        query["profile"] = name
    else:
        query.update(ALL[name].changed())
    return "sim://?" + urllib.parse.urlencode(query)


def expected(firmware: Firmware, options: ProbeOptions) -> dict[str, str | None]:
    """What the probe must find: every switch value it can see under ``options``, ``None``
    for the rest (each ``None`` is a documented limit of what the wire shows)."""
    out: dict[str, str | None] = {}
    for name in SWITCH_NAMES:
        value: str | None = getattr(firmware, name)
        if name in MOVE_SWITCHES and not options.moves:
            value = None  # only a move shows it
        if name in SAVE_SWITCHES and not options.save:
            value = None  # only !save shows it
        if name in UNPROBED_SWITCHES:
            value = None  # a snapshot step or the trigger output: not probed
        if name == "echo" and not options.moves and value != "after":
            value = None  # before and completion differ only for a move
        if name == "numbers" and not options.moves and value != "plus":
            value = None  # plain and negzero differ only for a value just below 0
        if name == "help_number" and firmware.instruction_set == "older":
            value = None  # moot: '?help N' is refused
        if name == "version_value" and firmware.instruction_set == "older" \
                and value == "number":
            value = None  # moot: '?version 1' is refused
        out[name] = value
    return out


async def probe_all(names: Iterable[str], options: ProbeOptions) -> dict[str, ProbeResult]:
    names = list(names)
    results = await asyncio.gather(*(probe(url_of(name), options) for name in names))
    return dict(zip(names, results, strict=True))


def check(results: dict[str, ProbeResult], options: ProbeOptions) -> None:
    wrong = {}
    for name, result in results.items():
        found = {switch: obs.value for switch, obs in result.observations.items()}
        want = expected(ALL[name], options)
        if found != want or result.unknown:
            wrong[name] = ({s: (found[s], want[s]) for s in want if found[s] != want[s]},
                           list(result.unknown))
    assert not wrong, wrong


def test_the_probe_knows_every_switch_of_the_emulator() -> None:
    assert tuple(SWITCHES) == SWITCH_NAMES
    assert set(SWITCHES) >= MOVE_SWITCHES


async def test_round_trip_profiles_and_new_variants_without_moves() -> None:
    check(await probe_all(["manual", "legacy", *UNSUPPORTED], FAST), FAST)


async def test_round_trip_with_moves_and_the_example_fingerprints_are_current() -> None:
    results = await probe_all(["manual", "legacy", "echo=completion"], FAST_MOVES)
    check(results, FAST_MOVES)
    # The examples of docs/howto/support-your-controller.md are these very probes
    # (tools/gen_fingerprints.py runs them with the same options).
    for name in PROFILES:
        path = ROOT / "examples" / "fingerprints" / f"{name}.json"
        shipped = json.loads(path.read_text(encoding="utf-8"))
        assert comparable(shipped) == comparable(results[name].fingerprint()), \
            f"{path} is out of date: python tools/gen_fingerprints.py"


@pytest.mark.slow
@pytest.mark.parametrize("moves", [False, True], ids=["reads", "moves"])
async def test_round_trip_every_variant(moves: bool) -> None:
    options = FAST_MOVES if moves else ProbeOptions(save=True, settle=0.05)
    names = list(ALL)
    for start in range(0, len(names), 8):  # eight at a time
        check(await probe_all(names[start:start + 8], options), options)


# ---------------------------------------------------------------------------------------
# What the probe does to the controller


def _moves(trace: str) -> list[bytes]:
    """Written lines that move (or stop) an axis."""
    out = []
    for record in parse_trace(trace):
        if record.direction != "->":
            continue
        if b"\x03" in record.data:
            out.append(record.data)
            continue
        words = record.data.decode("latin-1").lstrip("!?").split()
        if not words:
            continue
        entry = lookup(words[0])
        if words[0] == "a" or (entry is not None and entry.completion is not None):
            out.append(record.data)
    return out


async def _served(**state: Any) -> tuple[Any, list[ControllerModel]]:
    """A TCP emulator whose controller starts in ``state`` (autostatus, extmode; the
    instructions it lacks)."""
    models: list[ControllerModel] = []

    def factory(emit: Emit) -> ControllerModel:
        model = ControllerModel(emit, SimConfig(axes=3, lacks=state.get("lacks", frozenset())))
        model.session.autostatus = state.get("autostatus", 1)
        model.params.global_values["extmode"] = (state.get("extmode", 0),)
        models.append(model)
        return model

    server = await serve_tcp(factory, config=WireConfig(baud=None), speed=10)
    return server, models


def _snapshot(model: ControllerModel) -> Any:
    now = model.motion._time  # the model's own time: observe() does not advance it
    return (copy.deepcopy(model.params.axis_values), copy.deepcopy(model.params.global_values),
            model.session.autostatus,
            [round(model.motion.observe(i, now)[0], 4) for i in range(3)])


@pytest.mark.parametrize("autostatus", [1, 4])
async def test_without_moves_nothing_moves_and_every_setting_is_set_back(
        autostatus: int) -> None:
    server, models = await _served(autostatus=autostatus, extmode=1)
    async with server:
        result = await probe(f"socket://127.0.0.1:{server.port}", FAST)
        (model,) = models
        assert model.session.autostatus == autostatus
    assert _moves(result.trace) == []
    assert not any(b"save" in r.data for r in parse_trace(result.trace) if r.direction == "->")
    fresh = ControllerModel(lambda data: None, SimConfig(axes=3))
    fresh.session.autostatus = autostatus
    fresh.params.global_values["extmode"] = (1,)
    assert _snapshot(model)[:3] == _snapshot(fresh)[:3]
    assert result.switches["lim_cr_bug"] == "extmode0"  # read in both extmodes


@pytest.mark.parametrize("lacks", [frozenset(), frozenset({"lim"})], ids=["all", "no_lim"])
async def test_with_moves_x_returns_and_settings_are_set_back(lacks: frozenset[str]) -> None:
    server, models = await _served(lacks=lacks)
    async with server:
        result = await probe(f"socket://127.0.0.1:{server.port}", FAST_MOVES)
        (model,) = models
        after = _snapshot(model)
    fresh = _snapshot(ControllerModel(lambda data: None, SimConfig(axes=3)))
    assert after[:3] == fresh[:3]  # pause, joy, extmode ... as they were; mode 1
    assert after[3] == [0.0, 0.0, 0.0]
    assert _moves(result.trace)  # it did move


# ---------------------------------------------------------------------------------------
# Fingerprints


@pytest.mark.parametrize("options", [FAST, pytest.param(FAST_MOVES, marks=pytest.mark.slow)],
                         ids=["reads", "moves"])
async def test_a_fingerprint_makes_the_emulator_behave_like_the_unit(
        tmp_path: Path, options: ProbeOptions) -> None:
    unit = (await probe_all(["legacy"], options))["legacy"]
    path = write_fingerprint(unit, tmp_path / "unit.json")
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data["format"] == "tango_aio.fingerprint/1" and data["project_version"]
    assert data["identity"]["model"] == "TANGO-DT" and data["axes"] == 3
    assert data["observations"]["echo_all"]["lines"]
    again = await probe(f"sim://?baud=0&speed=10&fingerprint={path}", options)
    assert again.switches == unit.switches
    # What the probe could not see (moot on that unit, or seen only with moves) takes
    # the manual's value; everything it saw is the unit's.
    legacy, loaded = PROFILES["legacy"], Firmware.from_fingerprint(path)
    assert {name: getattr(loaded, name) for name in unit.switches} == \
        {name: getattr(legacy, name) for name in unit.switches}
    assert loaded.help_number == "yes"


def test_the_cli_probes_and_writes_the_fingerprint_and_trace(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    fingerprint, trace = tmp_path / "fp.json", tmp_path / "wire.trace"
    done = subprocess.run(
        [sys.executable, "-m", "tango_aio", "probe", "sim://?baud=0&echo=after",
         "--settle", "0.05", "-o", str(fingerprint), "--trace", str(trace)],
        capture_output=True, text=True, env=env, timeout=60, check=False)
    assert done.returncode == 0, done.stderr
    assert "Please send" in done.stdout
    assert json.loads(fingerprint.read_text(encoding="utf-8"))["switches"]["echo"] == "after"
    records = parse_trace(trace.read_text(encoding="utf-8"))
    assert records[0].direction == "->" and records[0].data == b"?autostatus"


@pytest.mark.slow
async def test_the_emulator_command_serves_a_fingerprint(tmp_path: Path) -> None:
    unit = await probe(url_of("ack_case=title"), FAST)
    path = write_fingerprint(unit, tmp_path / "unit.json")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "tango_aio", "sim", "--fingerprint", str(path), "--tcp",
        "127.0.0.1:0", "--baud", "0", env=env, stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE)
    try:
        assert process.stdout is not None
        url = (await asyncio.wait_for(process.stdout.readline(), 60)).decode().strip()
        assert url.startswith("socket://"), url
        served = await probe(url, SLOW_LINK)
    finally:
        process.terminate()
        await process.wait()
    assert served.switches == unit.switches
    assert served.switches["ack_case"] == "title"
    both = await _cli("sim", "--fingerprint", str(path), "--profile", "legacy")
    assert both[0] != 0 and "exclude" in both[1]


def test_moves_without_yes_on_a_real_port_are_asked_for(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-m", "tango_aio", "probe", "socket://127.0.0.1:9", "--moves",
         "-o", str(tmp_path / "fp.json")],
        capture_output=True, text=True, env=env, timeout=60, stdin=subprocess.DEVNULL,
        check=False)
    assert done.returncode == 1
    assert "--yes" in done.stdout + done.stderr
    assert not (tmp_path / "fp.json").exists()


# ---------------------------------------------------------------------------------------
# Unknown behaviour


async def test_behaviour_no_switch_has_is_recorded_as_unknown_with_its_lines() -> None:
    recorded = await probe("sim://?baud=0", FAST)
    text = recorded.trace.replace("<- b'OK...'", "<- b'OK!'")
    assert text != recorded.trace
    async with replay(text) as player:
        result = await probe(player.url, FAST)
    assert "ack_case" in result.unknown
    assert "<- OK!" in result.unknown["ack_case"].lines
    fingerprint = result.fingerprint()
    assert fingerprint["unknown"]["ack_case"]["lines"]
    assert "ack_case" not in fingerprint["switches"]


def test_the_decisions_name_what_no_value_describes() -> None:
    odd = Exchange(["!autostatus  4"], ["AUTOSTATUS 4"])
    assert decide_echo_text(odd).unknown
    assert decide_ack_case([Exchange(["!autostatus 2"], ["OK...", "ok..."])]).unknown
    assert decide_help_number(Exchange(["?help 5"], ["ERROR 7,other"], 0)).unknown
    assert decide_help_number(Exchange(["?help 5"], [], 4)).value is None
    three = Exchange(["?lim"], ["a", "b", "c"], 0)
    assert decide_lim_cr_bug(3, three, None).unknown


async def _cli(*args: str) -> tuple[int, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "tango_aio", *args, env=env, stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT)
    out, _ = await asyncio.wait_for(process.communicate(), 60)
    assert process.returncode is not None
    return process.returncode, out.decode("utf-8", "replace")


@pytest.mark.slow
async def test_the_cli_says_so_and_asks_for_the_file_when_a_value_is_unknown(
        tmp_path: Path) -> None:
    recorded = await probe("sim://?baud=0", FAST)
    text = recorded.trace.replace("<- b'OK...'", "<- b'OK!'")
    fingerprint = tmp_path / "fp.json"
    async with replay(text) as player:
        code, out = await _cli("probe", player.url, "--settle", "0.3", "-o", str(fingerprint))
    assert code == 0, out
    (said,) = [line for line in out.splitlines() if "does something no switch" in line]
    assert "ack_case" in said
    assert f"Please send {fingerprint}" in out
    assert json.loads(fingerprint.read_text(encoding="utf-8"))["unknown"]["ack_case"]


async def test_a_probe_that_fails_still_writes_the_trace(tmp_path: Path) -> None:
    silent = "1.0 -> b'?autostatus'\n2.0 -> b'?autostatus'\n"  # and no answer
    trace = tmp_path / "wire.trace"
    async with replay(silent) as player:
        code, out = await _cli("probe", player.url, "--settle", "0.1", "--trace", str(trace),
                               "-o", str(tmp_path / "fp.json"))
    assert code == 1
    assert "no answer to ?autostatus" in out and "please send it" in out
    assert [r.data for r in parse_trace(trace.read_text(encoding="utf-8"))] == \
        [b"?autostatus", b"?autostatus"]
    assert not (tmp_path / "fp.json").exists()


# ---------------------------------------------------------------------------------------
# Old units and units that lack instructions

#: An older-edition unit whose version ignores a value (old L416-418) and answers
#: '?version 1' with the whole line; a unit without ?lim; one without ctrt (L11616-11631).
OLD_UNITS = {
    "version_line": ("profile=legacy&version_value=line", []),
    "no_lim": ("lacks=lim", ["lim"]),
    "no_ctrt": ("lacks=ctrt", ["ctrt"]),
}


def _unit_url(query: str, baud: int = 0) -> str:
    return f"sim://?baud={baud}&speed=10&{query}"


@pytest.mark.parametrize(("unit", "options"), [
    *[pytest.param(unit, FAST, id=f"{unit}-reads") for unit in OLD_UNITS],
    pytest.param("no_lim", FAST_MOVES, id="no_lim-moves"),
    *[pytest.param(unit, FAST_MOVES, id=f"{unit}-moves", marks=pytest.mark.slow)
      for unit in OLD_UNITS if unit != "no_lim"]])
async def test_the_probe_fingerprints_old_units_and_units_lacking_instructions(
        unit: str, options: ProbeOptions) -> None:
    query, lacks = OLD_UNITS[unit]
    # At 57600 Bd the replies behind ?version 1's line come after it, as from a unit
    # (in instant mode they come with it).
    baud = 57600 if unit == "version_line" and not options.moves else 0
    result = await probe(_unit_url(query, baud), options)
    assert not result.unknown, result.unknown
    assert set(lacks) <= set(result.lacks)
    fingerprint = result.fingerprint()
    assert fingerprint["lacks"] == result.lacks
    if unit == "version_line":
        assert result.switches["version_value"] == "line"
        assert result.switches["instruction_set"] == "older"
        assert "extmode" in result.lacks  # not in the older edition
    else:
        assert result.lacks == lacks
        assert result.switches["version_value"] == "number"
        assert result.switches["instruction_set"] == "full"
    if unit == "no_lim":
        # Missing, not an unknown behaviour; with moves, nothing goes beyond a limit.
        assert result.observations["lim_cr_bug"].value is None
        assert "lacks ?lim" in result.observations["lim_cr_bug"].note
        assert "lim" not in fingerprint["unknown"]
        if options.moves:
            assert "lacks ?lim" in result.observations["refused_move_report"].note
    else:
        assert result.switches["lim_cr_bug"] == "extmode0"
    if options.moves:
        assert result.switches["move_during_move"] == "refuse"
        assert result.switches["ctrl_c"] == "stop"


@pytest.mark.parametrize("unit", list(OLD_UNITS))
async def test_a_fingerprint_replays_as_its_unit_lacks_included(tmp_path: Path,
                                                                unit: str) -> None:
    query, _ = OLD_UNITS[unit]
    first = await probe(_unit_url(query), FAST)
    path = write_fingerprint(first, tmp_path / "unit.json")
    again = await probe(_unit_url(f"fingerprint={path}"), FAST)
    assert comparable(again.fingerprint()) == comparable(first.fingerprint())
    assert again.lacks == first.lacks


@pytest.mark.parametrize("unit", list(OLD_UNITS))
async def test_the_driver_connects_and_moves_on_those_units(unit: str) -> None:
    query, _ = OLD_UNITS[unit]
    async with tango_aio.connect(_unit_url(query)) as tango:
        await tango.move_to(x=0.2)
        assert (await tango.position())["x"] == pytest.approx(0.2)
