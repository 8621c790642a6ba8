"""Sans-IO tests of the emulated controller: the interpreter behind a wire in virtual time.

Every test drives ``Wire(lambda emit: ControllerModel(emit, SimConfig(...)),
WireConfig(baud=None))`` with ``feed(bytes, now)`` / ``poll(now)``: replies leave at the
instant they are emitted, so times read off the wire are the interpreter's own times.

Sections: documented reply shapes (every example of instructions.json with a reply),
the settings store, the error state, autostatus 0-4, kinematics through the command
layer, aborts and Ctrl+C, trigger and snapshot lists, persistence.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tango_aio.catalog._instructions import (
    INSTRUCTIONS,
    AxisRule,
    Context,
    Kind,
    Param,
    parse,
)
from tango_aio.sansio._expect import expectation
from tango_aio.sansio._patterns import reply_pattern
from tango_aio.sim.lists import MAX_SNAPSHOTS, MAX_TRIGGERS
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.state import StateFileError
from tango_aio.sim.wire import Wire, WireConfig

pytestmark = pytest.mark.timeout(30)

#: The manual's examples, from the reference data the repository carries.
REFERENCE = Path(__file__).resolve().parents[2] / "reference" / "instructions.json"


# ---------------------------------------------------------------------------------------
# Harness


class Sim:
    """One emulated controller on an instant wire, driven in virtual time."""

    def __init__(self, axes: int = 3, wire: WireConfig | None = None, **config: Any) -> None:
        self.now = 0.0
        self.config = SimConfig(axes=axes, **config)
        self.wire = Wire(lambda emit: ControllerModel(emit, self.config, now=0.0),
                         wire or WireConfig(baud=None))
        self._partial = b""

    @property
    def model(self) -> ControllerModel:
        handler = self.wire.handler
        assert isinstance(handler, ControllerModel)
        return handler

    @property
    def err(self) -> int:
        return self.model.error

    def write(self, data: bytes) -> None:
        """Bytes from the host at the current virtual time."""
        self.wire.feed(data, self.now)

    def take(self) -> list[str]:
        """Reply lines that reached the host by now (without their CR)."""
        data = self._partial + self.wire.poll(self.now)
        *lines, self._partial = data.split(b"\r")
        return [line.decode("latin-1") for line in lines]

    def send(self, *lines: str) -> list[str]:
        """Write command lines; return every reply line available at once."""
        self.write(b"".join(line.encode("latin-1") + b"\r" for line in lines))
        return self.take()

    def ask(self, line: str) -> str:
        """A read that must answer with exactly one line."""
        replies = self.send(line)
        assert len(replies) == 1, (line, replies)
        return replies[0]

    def advance(self, seconds: float) -> list[str]:
        self.now += seconds
        return self.take()

    def events(self, until: float = 600.0) -> list[tuple[float, str]]:
        """Run to the wire's deadlines up to ``until`` seconds from now; timed reply lines."""
        end = self.now + until
        out: list[tuple[float, str]] = []
        for _ in range(100_000):
            deadline = self.wire.next_deadline()
            if deadline is None or deadline > end:
                break
            self.now = max(self.now, deadline)
            out += [(self.now, line) for line in self.take()]
        self.now = max(self.now, end) if until < 600.0 else self.now
        return out

    def settle(self, until: float = 600.0) -> list[str]:
        """Let everything finish; the reply lines in order."""
        return [line for _, line in self.events(until)]


def trapezoid_time(distance: float, vel: float, accel: float) -> float:
    """Duration of a rest-to-rest move with a linear ramp."""
    ramp = vel / accel
    if accel * ramp * ramp >= distance:
        return 2.0 * math.sqrt(distance / accel)
    return ramp + distance / vel


# ---------------------------------------------------------------------------------------
# 1. Every documented example with a reply has the documented shape


def _shape_regex(reply: str) -> re.Pattern[str]:
    """A pattern of the documented reply's shape: numbers keep their digit count,
    everything else (status letters, words, separators) is literal."""
    parts: list[str] = []
    pos = 0
    for match in re.finditer(r"-?\d+(?:\.(\d+))?", reply):
        parts.append(re.escape(reply[pos:match.start()]))
        decimals = match.group(1)
        parts.append(r"-?\d+" + (rf"\.\d{{{len(decimals)}}}" if decimals else ""))
        pos = match.end()
    parts.append(re.escape(reply[pos:]))
    return re.compile("".join(parts))


@dataclass(frozen=True)
class Case:
    """How to reproduce the situation of one documented example."""

    axes: int = 3
    setup: tuple[str, ...] = ()
    #: The command to send instead of the printed one (the printed one is not a line).
    cmd: str | None = None
    #: Let moves finish after sending the command and collect their reports too.
    settle: bool = False
    #: The shape to expect instead of the printed reply, and why.
    expect: str | None = None
    why: str = ""


_CAL_ALL = ("cal", "@@")
_REF_LIST = tuple(f"!trigp -1 {p}" for p in (
    10, 10.5, 11, 11.5, 12, 20, 20.5, 21, 21.5, 22, 30, 30.5, 31, 31.5, 32))

#: Context of examples whose reply depends on state, keyed by (instruction, manual line).
CASES: dict[tuple[str, int], Case] = {
    ("version", 1105): Case(expect="TANGO-DT, Version 1.71, Jun  4 2019 , 12:00:00",
                            why="another model and firmware; same ' , ' and double space"),
    ("version", 1107): Case(expect="1.71", why="firmware 1.71 instead of 1.69"),
    ("detext", 1212): Case(expect="02830\n= 3 Axes\n= Snapshot\n= Trigger out",
                           why="no encoder option; the hex word has 5 digits"),
    ("pa", 1977): Case(setup=("!pa 0",)),
    ("pa", 1983): Case(setup=("!pa 0",)),
    ("autostatus", 2141): Case(cmd="!moa 1 1 1", settle=True),
    ("autostatus", 2143): Case(cmd="!cal", settle=True, expect="AAA-.",
                               why="one string holds one kind: cal reports A, rm D"),
    ("autostatus", 2150): Case(setup=("!autostatus 2",)),
    ("autostatus", 2152): Case(setup=("!autostatus 2",)),
    ("autostatus", 2161): Case(setup=("!autostatus 3",), cmd="!moa 1", settle=True),
    ("autostatus", 2168): Case(setup=("!autostatus 4",), expect="!moa 10 5 0\n@@@-.",
                               settle=True, why="the echo, then the completion"),
    ("scanvel", 2483): Case(setup=("!scanvel 0.1",)),
    ("modulomode", 2594): Case(axes=4, setup=("!modulomode 0 0 1 4",)),
    ("modulomode", 2596): Case(setup=("!modulomode z 1",)),
    ("statusaxis", 2721): Case(axes=2, setup=("!moa y 5",), expect="@M--.-",
                               why="manual profile: idle axes show @ (J: switch joystick_letter)"),
    ("statusaxis", 2723): Case(setup=("cal x", "@@")),
    ("statusaxis", 2725): Case(setup=("!moa x 5",)),
    ("calst", 2767): Case(setup=("cal", "@@", "rm x", "@@", "rm y", "@@")),
    ("calst", 2769): Case(setup=("cal", "@@")),
    ("status", 2818): Case(setup=("!nonsense",)),
    ("err", 2877): Case(setup=("!vel -1",)),
    ("help", 2917): Case(setup=("!vel -1",)),
    ("pitch", 3192): Case(axes=2),
    ("lockaxis", 4322): Case(axes=4, setup=("!lockaxis 1 1 0 0",)),
    ("lockstate", 4382): Case(setup=("!lockaxis 1", "!lock 1100000000000000")),
    ("lim", 4619): Case(expect="-2600.0000 2600.0000,\n-2600.0000 2600.0000, -800.0000 800.0000",
                        setup=("!lim z -800 800",),
                        why="positions carry resolution digits (L4144); printed without"),
    ("lim", 4621): Case(expect="-2600.0000 2600.0000 -2600.0000 2600.0000 -800.0000 800.0000",
                        setup=("!extmode 1", "!lim z -800 800"),
                        why="positions carry resolution digits (L4144); printed without"),
    ("swtyp", 4814): Case(setup=("!swtyp y 1 0 1",)),
    ("swtyp", 4822): Case(setup=("!extmode 1",)),
    ("readsw", 5078): Case(expect="000000000000", why="no switch is actuated at power-on"),
    ("statuslimit", 5191): Case(axes=4, setup=(
        "!nosetlimit 1 1 1 1", "cal x", "@@", "cal y", "@@", "cal a", "@@", "rm a", "@@",
        "!lim y 0", "!lim z 0"), expect="AA-A---D-LL-----",
        why="an upper limit alone cannot be sent with !lim (pairs, L4549)"),
    ("cal", 5330): Case(settle=True),
    ("cal", 5332): Case(settle=True),
    ("cal", 5340): Case(setup=("!axis 1 0 1",), settle=True),
    ("rm", 5410): Case(settle=True),
    ("rm", 5412): Case(settle=True),
    ("rm", 5420): Case(setup=("!axis 1 0 1",), settle=True),
    ("vrm", 5510): Case(setup=("!nosetlimit 1 1 1", "cal", "@@")),
    ("vrm", 5514): Case(setup=("!nosetlimit 1 1 1", "cal", "@@", "!vrm 100 100 100")),
    ("calzeropos", 6003): Case(setup=("!calmode 2 1 0", "cal", "@@")),
    ("calzeropos", 6005): Case(axes=4, setup=("!calmode 2 1 0 0", "cal", "@@")),
    ("calzeropos", 6007): Case(setup=("!calmode 2 1 0", "cal", "@@")),
    ("calzeropos", 6017): Case(setup=("!calmode 2 1 0", "cal", "@@", "!mor y 10", "@@")),
    ("calzeropos", 6023): Case(setup=("!calmode 2 1 0", "cal", "@@", "!mor x 10", "@@")),
    ("calzeropos", 6029): Case(setup=("!calmode 2 1 0", "cal", "@@", "!mor z 10", "@@")),
    ("posclr", 6986): Case(setup=("!pos 1 2 3",)),
    ("posclr", 6990): Case(setup=("!pos 1 8 3",)),
    ("posclr", 6992): Case(setup=("!pos 1 8 3",)),
    ("posclr", 6996): Case(setup=("!pos 1 8 3", "!posclr y")),
    ("keymode", 7499): Case(setup=("!keymode 1",)),
    ("keyl", 7667): Case(setup=("snse 2",)),
    ("isvel", 3019): Case(expect="0.0000 0.0000 0.0000",
                          why="the comment shows the format of one value"),
    ("hdi", 8201): Case(),
    ("hdi", 8203): Case(expect="16 99", why="no HDI device is emulated (ID 16)"),
    ("hdi", 8205): Case(expect="16 99 [No device connected]",
                        why="no HDI device is emulated (ID 16)"),
    ("hdi", 8207): Case(expect="16 99 [No device connected]",
                        why="no HDI device is emulated (ID 16)"),
    ("hdimode", 8321): Case(setup=("!hdimode 1000100000000000",)),
    ("adiginfunc", 9261): Case(),
    ("anain", 9450): Case(expect="0.00", why="two decimals (printed 509.75)"),
    ("enc", 10620): Case(axes=2),
    ("enc", 10622): Case(axes=2),
    ("enc", 10628): Case(axes=2, settle=True),
    ("enc", 10630): Case(axes=2),
    ("enc", 10632): Case(axes=2),
    ("enc", 10636): Case(axes=2),
    ("enc", 10638): Case(axes=2),
    ("enc", 10642): Case(axes=2),
    ("enctype", 10859): Case(expect="0", why="encoder type of an absent A axis reads 0"),
    ("encref", 10976): Case(expect="0", why="printed with three values for one axis (L10976)"),
    ("encerr", 11151): Case(expect="0 0 0", why="no encoder error ('e') is emulated"),
    ("encsync", 11291): Case(expect="0 0 0", why="shape of the printed '2 3 -1'"),
    ("encsync", 11293): Case(expect="0 0 0  0 0 0  0 0 0", why="shape of the printed reply"),
    ("trigbwidth", 13349): Case(cmd="?trigbwidth", why="printed as ?trigbdelay (sic)"),
    ("trigr", 13690): Case(setup=("!trigr y 11.5 16.5 11",),
                           why="printed ?trigr is inconsistent with its !trigr (L13690)"),
    ("trigr", 13692): Case(setup=("!trigr y 11.5 16.5 11",)),
    ("trigp", 14058): Case(setup=_REF_LIST),
    ("trigp", 14062): Case(setup=_REF_LIST),
    ("trigp", 14064): Case(setup=_REF_LIST),
    ("trigp", 14066): Case(setup=_REF_LIST),
    ("snsc", 14636): Case(setup=("snse 2", "snse 2", "snse 2")),
    ("snsaxis", 15276): Case(setup=("!snsaxis z 1",)),
    ("snsa", 14636): Case(setup=("!snsa -1 2.12 1.352 0.9343", "!snsa -1 2.12 1.352 0.9343")),
}

#: Examples whose reply the emulator cannot take the shape of, with the reason.
NOT_REPRODUCIBLE: dict[tuple[str, int], str] = {
    **{("stagesn", line): "no ETS is emulated: every address reads ---------"
       for line in (1522, 1524, 1526, 1536, 1538, 1546, 1554, 1556, 1558, 1560)},
    ("pa", 1985): "error 29 after an external power-stage event (hardware)",
}


def _examples() -> list[tuple[str, int, str, str]]:
    entries = json.loads(REFERENCE.read_text(encoding="utf-8"))
    out = []
    for entry in entries:
        for example in entry["examples"]:
            if example.get("reply") is not None:
                out.append((entry["name"], example["line"], example["cmd"], example["reply"]))
    return out


EXAMPLES = _examples()


def _run_setup(sim: Sim, setup: Iterable[str]) -> None:
    for line in setup:
        if line == "@@":
            sim.settle()
        else:
            sim.send(line)
    sim.take()


def _reproduce(name: str, line: int, cmd: str) -> tuple[Sim, list[str], str]:
    case = CASES.get((name, line), Case())
    sim = Sim(axes=case.axes)
    _run_setup(sim, case.setup)
    command = case.cmd or cmd
    replies = sim.send(command)
    if case.settle:
        replies += sim.settle()
    return sim, replies, command


def test_every_example_with_a_reply_is_covered() -> None:
    assert len(EXAMPLES) > 200
    keys = {(name, line) for name, line, _, _ in EXAMPLES}
    assert set(CASES) <= keys
    assert set(NOT_REPRODUCIBLE) <= keys


@pytest.mark.parametrize(("name", "line", "cmd", "reply"), EXAMPLES,
                         ids=[f"{n}-L{ln}-{i}" for i, (n, ln, _, _) in enumerate(EXAMPLES)])
def test_documented_reply_shape(name: str, line: int, cmd: str, reply: str) -> None:
    if (name, line) in NOT_REPRODUCIBLE:
        pytest.skip(NOT_REPRODUCIBLE[(name, line)])
    case = CASES.get((name, line), Case())
    documented = case.expect if case.expect is not None else reply
    expected = documented.replace("[CR]", "\n").split("\n")
    if expected[-1] == "" and documented.endswith("[CR]"):
        expected.pop()
    sim, replies, command = _reproduce(name, line, cmd)
    assert len(replies) == len(expected), (command, replies, expected)
    for got, want in zip(replies, expected, strict=True):
        assert _shape_regex(want).fullmatch(got), (command, got, want)
    assert sim.model.internal_errors == []


@pytest.mark.parametrize(("name", "line", "cmd", "reply"), EXAMPLES,
                         ids=[f"{n}-L{ln}-{i}" for i, (n, ln, _, _) in enumerate(EXAMPLES)])
def test_documented_replies_fit_their_reply_pattern(name: str, line: int, cmd: str,
                                                    reply: str) -> None:
    """The driver's reply check (tango_aio.sansio._patterns) accepts every one-line reply the
    manual documents and the emulator gives: it never rejects a real reply."""
    case = CASES.get((name, line), Case())
    sim = Sim(axes=case.axes)
    _run_setup(sim, case.setup)
    try:
        command = parse(case.cmd or cmd, sim.model.context())
    except ValueError:
        return  # the driver refuses the line (e.g. !vel -10, L2154): no reply to check
    documented = case.expect if case.expect is not None else reply
    if not command.is_read or "[CR]" in documented or "\n" in documented:
        return  # executing lines answer with acknowledgements, tested in test_core
    pattern = reply_pattern(command, sim.model.context())
    replies = [documented]
    if (name, line) not in NOT_REPRODUCIBLE:
        replies += sim.send(command.line)
    for text in replies:
        assert pattern.accepts(text), (command.line, text, pattern)


# Explicit shapes named by the brief, each with the exact bytes.


def test_read_digits_by_instruction() -> None:
    sim = Sim()
    assert sim.ask("?vel") == "10.000 10.000 10.000"
    assert sim.ask("?secvel") == "10.00 10.00 10.00"
    assert sim.ask("?pitch") == "1.0000 1.0000 1.0000"
    assert sim.ask("?accel x") == "1.00"
    assert sim.ask("?gear y") == "1.000"
    assert sim.ask("?pos") == "0.0000 0.0000 0.0000"
    assert sim.ask("?vel y 6") == "10.000000"
    assert sim.ask("?secvel x 5") == "10.00000"
    assert sim.ask("?pitch 9") == "1.000000000 1.000000000 1.000000000"
    assert sim.ask("?calvel y") == "10.000 0.500"
    assert sim.ask("?keyspeed x") == "1.00 10.00"
    assert sim.ask("?ctrff y") == "2.0 2.0"


def test_resolution_5_in_dim_2_and_dim_1() -> None:
    """``!resolution 5`` then ``?pos x``: 0.00000 in dim 2/9, 0.00 in dim 1 (L4160-4162)."""
    sim = Sim()
    sim.send("!resolution 5")
    assert sim.ask("?pos x") == "0.00000"
    sim.send("!dim x 9")
    assert sim.ask("?pos x") == "0.00000"
    sim.send("!dim x 1")
    assert sim.ask("?pos x") == "0.00"
    sim.send("!resolution 6")
    assert sim.ask("?pos x") == "0.000"
    sim.send("!resolution 4")
    assert sim.ask("?pos x") == "0.0"
    sim.send("!dim x 0")
    assert sim.ask("?pos x") == "0"


def test_statusaxis_forms() -> None:
    sim = Sim()
    assert sim.send("?statusaxis", "statusaxis", "sa") == ["@@@-.-"] * 3
    assert sim.send("sa x", "?statusaxis z") == ["@", "@"]
    sim.send("!moa y 5")
    assert sim.send("sa", "sa y", "sa x") == ["@M@-.-", "M", "@"]
    assert Sim(axes=4).ask("sa") == "@@@@.-"
    assert Sim(axes=1).ask("sa") == "@---.-"


def test_version_and_identity() -> None:
    sim = Sim()
    version = sim.ask("?version")
    assert version == "TANGO-DT, Version 1.71, Jun  4 2019 , 12:00:00"
    assert re.fullmatch(r"TANGO-[\w-]+, Version \d\.\d\d, [A-Z][a-z]{2} [ \d]\d \d{4} , "
                        r"\d\d:\d\d:\d\d", version)
    assert sim.send("version", "?version 1") == [version, "1.71"]
    assert sim.ask("?det") == str(0x2800 | 3 << 4)
    assert sim.send("detext") == ["02830", "= 3 Axes", "= Snapshot", "= Trigger out"]
    assert sim.ask("?ver") == "Vers:LS32.00.038"
    assert sim.ask("?readsn") == "190604001"
    assert sim.ask("?maxaxis") == "3"


def test_encpos_reads_the_ored_source_without_an_axis() -> None:
    """``?encpos`` returns just one 0 or 1, the "ored" source of all axes (L11238)."""
    sim = Sim()
    assert sim.send("?encpos", "?encpos y") == ["0", "0"]
    sim.send("!encpos 1")
    assert sim.send("?encpos", "?encpos x") == ["1", "1"]
    sim.send("!encpos x 0", "!encpos z 0")
    assert sim.send("?encpos", "?encpos x", "?encpos y") == ["1", "0", "1"]
    sim.send("!encpos y 0")
    assert sim.ask("?encpos") == "0"


def test_help_and_err_formats() -> None:
    sim = Sim()
    assert sim.send("help", "?help 29") == ["ERROR 0,no error", "ERROR 29,servo amplifier off"]
    sim.send("!vel -1")
    assert sim.send("help", "?err", "err") == ["ERROR 5,number outside range", "5", "5"]
    assert re.fullmatch(r"ERROR 4,.+", sim.ask("help 4"))


def test_every_read_answers_the_lines_the_catalog_expects() -> None:
    """Cross-check with the driver's catalog: for every read form without arguments, the
    emulator answers exactly the reply lines :func:`reply_rule` announces (nothing a
    host could wait for in vain), each fitting the reply pattern, in every extmode."""
    for extmode in (0, 1):
        sim = Sim()
        sim.send(f"!extmode {extmode}")
        for name, entry in INSTRUCTIONS.items():
            if not entry.read or name in ("detext",):
                continue
            text = f"?{name}" if "?" in {f.value for f in entry.forms} else name
            try:
                command = parse(text, sim.model.context())
            except ValueError:
                continue  # the read needs arguments
            rule = expectation(command, 1, sim.model.context()).rule
            replies = sim.send(text)
            if rule.terminator is not None:
                assert replies[-1] == rule.terminator, name
            elif rule.continuation is None:
                assert len(replies) == rule.count, (name, replies)
                pattern = reply_pattern(command, sim.model.context())
                assert all(pattern.accepts(r) for r in replies), (name, replies, pattern)
            else:
                assert replies and all(rule.continuation.match(r) for r in replies[1:]), name
        assert sim.model.internal_errors == []


def test_indexed_and_hardware_reads_have_documented_shapes() -> None:
    sim = Sim()
    assert sim.send("?digin", "?digin 8", "?edigin", "?adigin 3") == [
        "0" * 24, "0", "0" * 12, "0"]
    assert sim.send("key", "key 1", "?iscur y") == ["0 0 0 0", "0", "1.00"]
    assert sim.send("anain c 15", "anain v 10") == ["512", "0.00"]
    assert sim.send("?encamp", "?encamp x 1", "?ctrdiff y") == ["0 0 0", "0.0", "0.0000"]
    assert sim.send("ctrstatus x 0", "ctrstatus 0", "?ctrstatus 1") == [
        "0 0", "0 0 0 0 0 0", "0 0 0"]
    assert sim.send("?mrt 2", "?mrt y -1") == ["0 0 0 0 0 0"] * 2 + ["0 0"]
    assert sim.send("?calbspeed", "?calbspeed -1", "?ctrd", "?ctrd -1") == [
        "32.0", "32.0 32.0 32.0", "10", "10 10 10"]
    sim.send("!joyspeed 2 25", "!zwtravel 3 2.5", "!adiginfunc 1 2", "!anaout c 1 25.3")
    assert sim.send("?joyspeed 2", "?zwtravel", "?adiginfunc", "?adiginfunc 1") == [
        "25.000", "0.100 0.010 2.500", "0 2 1 2", "2"]
    assert sim.send("?anaout", "?anaout c 1", "?clim 1") == ["0.00 25.30 0.00", "25.30", "0"]
    sim.send("!clim 50 70 10")
    assert sim.send("?clim", "?clim 1") == ["50.0000 70.0000 10.0000", "1"]
    assert sim.ask("?swtyp") == "1 1 11 1 11 1 1"  # extmode 0 quirk, L4820
    assert sim.model.internal_errors == []


# ---------------------------------------------------------------------------------------
# 2. Settings store and read back


#: Settings the generic sweep skips, with the reason.
SWEEP_SKIP: dict[str, str] = {
    "err": "!err clears the error state",
    "posclr": "!posclr clears the offset (tested with pos)",
    "encerr": "!encerr 0 only resets encoder errors",
    "keyl": "!keyl clears latched keys",
    "speed": "starts a constant-velocity move (kinematics tests)",
    "restore": "reloads parameters (persistence tests)",
    "autostatus": "changes the reply protocol (autostatus tests)",
    "joy": "may answer a completion (autostatus tests)",
    "trigp": "a list (list tests)", "trigc": "a list (list tests)",
    "trigi": "a list (list tests)", "trigr": "writes the trigger list (list tests)",
    "snsa": "a list (list tests)", "snsc": "a list (list tests)",
    "snsi": "a list (list tests)", "snsp": "a list (list tests)",
    "snsv": "a list (list tests)",
    "drop": "?drop counts dispensed drops, not the written number",
    "flash": "?flash has no reply ('Response: None', L9880)",
}

#: Settings that read back as integers although written as numbers (L11902).
READ_AS_INTEGER = frozenset({"ctrf"})
#: Settings the controller rounds to a step and reads back rounded (``trigs``: 40 µs,
#: L12965-12967).
READ_IN_STEPS: dict[str, int] = {"trigs": 40}
#: ``trigf`` reads "the true value" its 40 µs ticks give (L13234-13278).
TICKS_OF_40_US = 25_000.0
#: Settings written as ``index value`` and read back per index.
WRITTEN_WITH_INDEX = frozenset({"joyspeed", "zwtravel", "adiginfunc"})


def _sweep_value(param: Param, current: str | None) -> str:
    """A valid value of ``param`` that differs from ``current``."""
    if param.kind is Kind.CHOICE:
        others = [str(c) for c in param.choices if str(c) != current]
        return others[-1] if others else str(param.choices[0])
    if param.kind is Kind.BITS:
        return ("10" * param.width)[: param.width]
    lo = param.lo if param.lo is not None else -100.0
    hi = param.hi if param.hi is not None else 100.0
    if param.kind is Kind.INT:
        whole = int(lo + (hi - lo) // 3)
        return str(whole if str(whole) != current else int(hi))
    value = round(lo + (hi - lo) / 3, 1)
    if not lo <= value <= hi or value == 0.0 or f"{value}" == current:
        value = round(lo + (hi - lo) / 3, 3)
    return f"{value}"


def _sweep_cases() -> list[str]:
    return sorted(name for name, entry in INSTRUCTIONS.items()
                  if entry.write and entry.read and name not in SWEEP_SKIP)


def _same(written: str, read: str) -> bool:
    try:
        return math.isclose(float(written), float(read), abs_tol=1e-9, rel_tol=1e-9)
    except ValueError:
        return written == read


@pytest.mark.parametrize("name", _sweep_cases())
def test_setting_stores_and_reads_back(name: str) -> None:
    sim = Sim()
    entry = INSTRUCTIONS[name]
    sig = entry.write[0]
    axis = " y" if sig.per_axis and sig.axis is not AxisRule.NONE else ""
    before = sim.ask(f"?{name}{axis}").split()
    values: list[str] = []
    for index, param in enumerate((*sig.lead, *sig.per_axis)):
        if param.optional and index > 0:
            break
        values.append(_sweep_value(param, before[index] if index < len(before) else None))
    if name in WRITTEN_WITH_INDEX:  # '!joyspeed 2 25' is read back by '?joyspeed 2'
        read, expect = f"?{name} {values[0]}", values[1:]
    else:
        read, expect = f"?{name}{axis}", values
    assert sim.send(f"!{name}{axis} {' '.join(values)}") == []
    assert sim.err == 0, (name, values)
    after = sim.ask(read)
    assert sim.model.internal_errors == []
    assert name in WRITTEN_WITH_INDEX or after.split() != before, (name, after)
    # '!clim r' centres on the current position: the reply is cx cy r.
    got = after.split()[-1:] if name == "clim" else after.split()[: len(expect)]
    if name in READ_AS_INTEGER:
        expect = [str(round(float(v))) for v in expect]
    if name in READ_IN_STEPS:
        step = READ_IN_STEPS[name]
        expect = [str((int(v) + step // 2) // step * step) for v in expect]
    if name == "trigf":
        expect = [f"{TICKS_OF_40_US / round(TICKS_OF_40_US / float(v)):.2f}" for v in expect]
    assert all(_same(w, r) for w, r in zip(expect, got, strict=True)), (name, values, after)


def test_trigger_widths_are_rounded_to_40_us() -> None:
    """"If the parameter is not a multiple of 40 it will be rounded to the nearest
    multiple: e.g. 90 → 80, 100 → 120. When read back, the corrected (nearest) value is
    returned" (L12965-12967); the secondary output's delay and width too (L12976-12981),
    which "cannot be read back by ?trigs" (L13001-13003)."""
    sim = Sim()
    sim.send("!trigs 90")
    assert sim.ask("?trigs") == "80"
    sim.send("!trigs 100 30 60")
    assert sim.ask("?trigs") == "120"
    assert sim.model.params.global_values["trigs"] == (120, 40, 80)
    assert sim.err == 0


def test_per_axis_values_without_axis_letter_go_x_y_z() -> None:
    sim = Sim()
    sim.send("!vel 1 2.5", "!accel z 0.2", "!secvel 3")
    assert sim.send("?vel", "?accel", "?secvel") == [
        "1.000 2.500 10.000", "1.00 1.00 0.20", "3.00 10.00 10.00"]
    sim.send("!swact 0 1 0")  # one group without axis: every axis (L4928)
    assert sim.send("?swact x", "?swact z") == ["0 1 0", "0 1 0"]
    sim.send("!calbspeed 15")  # one value sets every axis (L5809)
    assert sim.ask("?calbspeed -1") == "15.0 15.0 15.0"
    sim.send("!calbspeed 15 15")  # illegal (L5833)
    assert sim.ask("?err") == "6"
    sim.send("!moa 1 2 3 4")  # a target for the absent A axis
    assert sim.ask("?err") == "1"
    assert sim.settle() == []


# ---------------------------------------------------------------------------------------
# 3. Error state


@pytest.mark.parametrize(("line", "code"), [
    ("!vel q 1", 1),          # not an axis letter
    ("!moa a 5", 1),          # A axis absent on a 3-axis controller
    ("!frobnicate", 4),       # unknown instruction
    ("?moa", 4),              # a form the instruction does not have
    ("!vel -1", 5),           # outside the range
    ("!dim x 11", 5),
    ("!vel 1 2 3 4 5", 6),    # too many values
    ("!moa", 6),              # too few
    ("vel 10", 7),            # missing prefix (forms '!' and '?' only)
])
def test_syntax_errors(line: str, code: int) -> None:
    sim = Sim()
    assert sim.send(line) == []
    assert sim.send("?err", "err", "?err") == [str(code)] * 3  # reading keeps it
    assert sim.ask("?status") == f"ERR {code}"
    assert sim.ask("?err") == str(code)
    assert sim.send("!err", "?err") == ["0"]
    assert sim.ask("?status") == "OK..."


def test_each_instruction_overwrites_the_error() -> None:
    sim = Sim()
    sim.send("!vel -1")
    assert sim.ask("help") == "ERROR 5,number outside range"
    assert sim.ask("?err") == "5"  # help does not change it either
    sim.send("?pos")
    assert sim.ask("?err") == "0"
    sim.send("!bogus")
    sim.send("!vel 5")
    assert sim.ask("?err") == "0"
    sim.send("!moa 9999")  # beyond the soft limits (±2600 mm)
    assert sim.ask("?err") == "5"
    assert sim.settle() == []  # a refused move never reports


def test_limit_switch_error_12() -> None:
    sim = Sim()
    sim.send("!speed x -20")
    sim.settle(10.0)
    assert sim.send("sa x", "?err") == ["S", "0"]
    assert float(sim.ask("?pos x")) < -50.0  # past E0 at -50 mm
    sim.send("!mor x -1")
    assert sim.ask("?err") == "12"
    assert sim.settle(5.0) == []
    sim.send("!mor x 1")  # away from the switch is allowed
    assert sim.settle() == ["@@@-."]


def test_line_over_255_characters_is_error_3_through_the_wire() -> None:
    sim = Sim(wire=WireConfig(baud=None, processing_time_per_line=0.001))
    sim.write(b"!autostatus 2\r")
    sim.now += 0.01
    sim.take()
    long_line = b"!vel " + b"1" * 300 + b"\r"
    sim.write(long_line)
    sim.now += 0.1
    assert sim.take() == ["ERR 3"]
    assert sim.send("?err") == []  # the busy interpreter answers after its time
    sim.now += 0.01
    assert sim.take() == ["3"]
    assert sim.model.params.number("vel") == 10.0


def test_empty_lines_change_nothing() -> None:
    sim = Sim()
    sim.send("!vel -1")
    assert sim.send("", "  ") == []
    assert sim.ask("?err") == "5"


def test_case_insensitive_and_upper_case() -> None:
    sim = Sim()
    assert sim.send("MOA Z 10") == []
    assert sim.settle() == ["@@@-."]
    assert sim.send("?POS Z", "?Vel") == ["10.0000", "10.000 10.000 10.000"]


# ---------------------------------------------------------------------------------------
# 4. Autostatus modes 0-4 (the shared decision of tango_aio.sansio._core.expectation)


def _expected_lines(line: str, mode: int, completion: str | None) -> list[str]:
    command = parse(line, Context(axes=3))
    expect = expectation(command, mode, Context(axes=3))
    out = [line] if expect.echo else []
    if expect.ack:
        out.append("OK...")
    if completion is not None and expect.completion is not None:
        out.append("" if expect.mode_after == 3 else completion)
    return out


JOBS = [
    ("!moa 5 5", "@@@-."), ("moa 5", "@@@-."), ("!mor 1 1", "@@@-."),
    ("mor y 2", "@@@-."), ("m", "@@@-."), ("!m", "@@@-."), ("cal", "AAA-."),
    ("!cal y", "@A@-."), ("rm", "DDD-."), ("!rm z", "@@D-."),
]


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
@pytest.mark.parametrize(("line", "report"), JOBS)
def test_autostatus_of_jobs(mode: int, line: str, report: str) -> None:
    sim = Sim()
    sim.send("!distance 1 1 1")
    sim.send(f"!autostatus {mode}")
    sim.take()
    replies = sim.send(line) + sim.settle()
    assert replies == _expected_lines(line, mode, report)
    # Spelled out, as the manual does (L2079-2168):
    executes_with_bang = line.startswith("!")
    expected = {
        0: [],
        1: [report],
        2: (["OK..."] if executes_with_bang else []) + [report],
        3: [""],
        4: [line, report],
    }[mode]
    assert replies == expected
    assert sim.ask("?err") == "0"


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
def test_autostatus_of_settings_and_reads(mode: int) -> None:
    sim = Sim()
    sim.send(f"!autostatus {mode}")
    sim.take()
    assert sim.send("!vel 5") == {2: ["OK..."], 4: ["!vel 5"]}.get(mode, [])
    assert sim.send("!vel -5") == {2: ["ERR 5"], 4: ["!vel -5"]}.get(mode, [])
    assert sim.send("?vel x") == ["5.000"]  # reads: never echoed, never acknowledged
    assert sim.send("save") == {4: ["save", "OK..."]}.get(mode, ["OK..."])
    assert sim.send("!save") == {4: ["!save", "OK..."]}.get(mode, ["OK..."])
    assert sim.send("?autostatus") == [str(mode)]


_COMPLETION = re.compile(r"[@A-Z-]{4}\.")


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
def test_every_write_answers_what_core_expects(mode: int) -> None:
    """For every executing instruction: exactly the echo, data and acknowledgement lines
    :func:`tango_aio.sansio._core.expectation` announces (completion reports aside)."""
    for name in sorted(INSTRUCTIONS):
        entry = INSTRUCTIONS[name]
        if not entry.write or name in ("reset", "restore", "autostatus"):
            # restarts: tested with persistence; autostatus: the core owes its echo and
            # acknowledgement only optionally (the protocol's mode-change barrier)
            continue
        sig = entry.write[0]
        lettered = sig.axis is AxisRule.REQUIRED or (sig.per_axis and sig.axis is not AxisRule.NONE)
        axis = " y" if lettered else ""
        values = [_sweep_value(p, None) for i, p in enumerate((*sig.lead, *sig.per_axis))
                  if not (p.optional and i > 0)]
        line = f"!{name}{axis} {' '.join(values)}".rstrip()
        sim = Sim()
        sim.send(f"!autostatus {mode}")
        sim.take()
        expect = expectation(parse(line, sim.model.context()), mode, sim.model.context())
        replies = [r for r in sim.send(line)
                   if not (_COMPLETION.fullmatch(r) or (r == "" and mode == 3))]
        assert len(replies) == expect.echo + expect.rule.count + expect.ack, (line, replies)
        assert sim.model.internal_errors == []


def test_autostatus_switches_take_effect_as_core_says() -> None:
    sim = Sim()
    assert sim.send("!autostatus 2") == ["OK..."]  # acknowledged in the new mode
    assert sim.send("!autostatus 4") == []          # mode 2 ended before the ack
    assert sim.send("!autostatus 2") == ["!autostatus 2", "OK..."]
    assert sim.send("!autostatus 7") == ["ERR 5"]
    assert sim.send("!autostatus 1") == []
    assert sim.send("!autostatus 4") == []
    assert sim.send("!autostatus 1") == ["!autostatus 1"]


@pytest.mark.parametrize("mode", [0, 1, 2, 3, 4])
def test_joy_0_answers_only_when_the_joystick_was_enabled(mode: int) -> None:
    sim = Sim()
    sim.send(f"!autostatus {mode}")
    sim.take()
    assert sim.ask("?joy") == "2"  # enabled by default
    report = {0: [], 1: ["@@@-."], 2: ["@@@-.", "OK..."], 3: [""],
              4: ["!joy 0", "@@@-."]}[mode]
    assert sim.send("!joy 0") == report
    assert sim.send("!joy 0") == {2: ["OK..."], 4: ["!joy 0"]}.get(mode, [])  # already 0
    assert sim.send("!joy 2") == {2: ["OK..."], 4: ["!joy 2"]}.get(mode, [])


def test_a_move_refused_in_mode_2_acknowledges_the_error_and_never_completes() -> None:
    sim = Sim()
    sim.send("!autostatus 2")
    assert sim.send("!moa 9999") == ["ERR 5"]
    assert sim.send("moa 9999") == []
    assert sim.settle() == []


def test_completion_follows_the_mode_in_force_when_the_move_ends() -> None:
    sim = Sim()
    sim.send("!moa 5")
    sim.send("!autostatus 3")
    assert sim.settle() == [""]
    sim.send("!autostatus 0")
    sim.send("!moa 0")
    sim.send("!autostatus 4")
    assert sim.settle() == ["@@@-."]


def test_pause_delays_the_report_and_delay_delays_the_start() -> None:
    move = trapezoid_time(2.0, 10.0, 1000.0)
    sim = Sim()
    sim.send("!pause 500")
    sim.send("!moa 2")
    events = sim.events()
    assert [line for _, line in events] == ["@@@-."]
    assert events[0][0] == pytest.approx(move + 0.5, abs=1e-9)
    assert sim.ask("?pos x") == "2.0000"

    sim = Sim()
    sim.send("!delay 300")
    sim.send("!moa 2")
    sim.advance(0.299)
    assert sim.send("sa x", "?pos x") == ["M", "0.0000"]  # waiting: M, not moving
    events = sim.events()
    assert events[0][1] == "@@@-."
    assert events[0][0] == pytest.approx(0.3 + move, abs=1e-9)


def test_save_answers_in_every_mode_and_mode_2_does_not_ack_twice() -> None:
    sim = Sim()
    for mode in range(5):
        sim.send(f"!autostatus {mode}")
        sim.take()
        echo = ["save"] if mode == 4 else []
        assert sim.send("save") == [*echo, "OK..."]


# ---------------------------------------------------------------------------------------
# 5. Kinematics through the command layer


def test_move_time_is_a_trapezoid_at_default_vel_and_accel() -> None:
    """vel 10 rev/s, pitch 1 mm → 10 mm/s (= secvel); accel 1 m/s² = 1000 mm/s²."""
    duration = trapezoid_time(10.0, 10.0, 1000.0)
    assert duration == pytest.approx(1.01)
    sim = Sim()
    sim.send("!moa 10")
    sim.advance(0.005)  # mid-ramp: x = a t² / 2
    assert sim.ask("?pos x") == f"{0.5 * 1000.0 * 0.005 ** 2:.4f}"
    sim.advance(duration - 0.005 - 1e-4)
    assert sim.send("sa x") == ["M"]
    (when, line), = sim.events()
    assert when == pytest.approx(duration, abs=1e-9)
    assert line == "@@@-."
    assert sim.send("?pos x", "sa x", "?isvel x") == ["10.0000", "@", "0.000"]


def test_short_move_is_a_triangle() -> None:
    sim = Sim()
    sim.send("!mor 0.04")
    (when, _), = sim.events()
    assert when == pytest.approx(2 * math.sqrt(0.04 / 1000.0), abs=1e-9)


def test_vector_move_arrives_together() -> None:
    sim = Sim()
    sim.send("!moa 10 5 2")
    sim.advance(0.5)
    x, y, z = (float(v) for v in sim.ask("?pos").split())
    assert y == pytest.approx(x / 2, abs=1e-3)
    assert z == pytest.approx(x / 5, abs=1e-3)
    vx, vy, _ = (float(v) for v in sim.ask("?isvel").split())
    assert [vx, vy] == pytest.approx([10.0, 5.0])
    (when, line), = sim.events()
    assert line == "@@@-."
    assert when == pytest.approx(trapezoid_time(10.0, 10.0, 1000.0), abs=1e-9)
    assert sim.ask("?pos") == "10.0000 5.0000 2.0000"


def test_go_retargets_and_never_reports() -> None:
    sim = Sim()
    sim.send("!go 10")
    sim.advance(0.3)
    assert sim.ask("sa x") == "M"
    sim.send("!go 5")
    assert sim.settle() == []
    assert sim.send("?pos x", "sa x") == ["5.0000", "@"]
    sim.send("!go 8")
    sim.advance(0.1)
    sim.send("go")  # go without target stops
    assert sim.settle() == []
    assert 5.0 < float(sim.ask("?pos x")) < 8.0


def test_speed_runs_until_speed_0_without_report() -> None:
    sim = Sim()
    sim.send("!speed 2")
    sim.advance(1.0)
    assert sim.ask("?speed x") == "2.000"
    assert float(sim.ask("?pos x")) == pytest.approx(2.0 - 2.0 / 1000.0, abs=1e-6)
    sim.send("!speed 0")
    assert sim.settle() == []
    assert sim.send("sa x", "?speed x") == ["@", "0.000"]


def test_pos_posclr_and_zero() -> None:
    sim = Sim()
    sim.send("!moa 3")
    sim.settle()
    sim.send("!pos 1 8 3")
    assert sim.send("?pos", "?posclr") == ["1.0000 8.0000 3.0000", "-2.0000 8.0000 3.0000"]
    sim.send("!posclr y")
    assert sim.ask("?pos") == "1.0000 0.0000 3.0000"
    sim.send("!posclr")
    assert sim.send("?pos", "?posclr") == ["3.0000 0.0000 0.0000", "0.0000 0.0000 0.0000"]
    sim.send("!lim x -5 5")
    sim.send("!zero x")  # resets the counter; the limits keep their numbers (L7000-7012)
    assert sim.send("?pos x", "?lim x") == ["0.0000", "-5.0000 5.0000"]
    sim.send("!pos y 4", "clearpos y")
    assert sim.send("?pos y", "?posclr y") == ["0.0000", "0.0000"]


def test_soft_limits_refuse_moves_with_error_5() -> None:
    sim = Sim()
    sim.send("!lim x -5 5")
    assert sim.ask("?lim x") == "-5.0000 5.0000"
    sim.send("!moa 6")
    assert sim.send("?err", "sa x") == ["5", "E"]  # not executed (L2705)
    assert sim.settle() == []
    sim.send("!moa 5")
    assert sim.settle() == ["@@@-."]
    sim.send("!mor 0.5")
    assert sim.ask("?err") == "5"


def test_cal_and_rm_set_origin_limits_and_status() -> None:
    sim = Sim()
    assert sim.send("?statuslimit", "calst") == ["----------------", "0 0 0"]
    sim.send("!moa 20")
    sim.settle()
    sim.send("cal")
    events = sim.events()
    assert [line for _, line in events] == ["AAA-."]
    assert events[0][0] > 7.0  # 70 mm at the 10 mm/s secvel cap
    assert sim.send("?pos", "calst", "?statuslimit") == [
        "0.0000 0.0000 0.0000", "1 1 1", "AAA-------------"]
    assert sim.ask("?lim x").startswith("0.0000 ")
    sim.send("rm x")
    assert sim.settle() == ["D@@-."]
    upper = float(sim.ask("?pos x"))
    assert upper == pytest.approx(100.0, abs=1e-3)  # switches at -50 and +50 mm
    assert sim.send("?lim x", "calst", "?statuslimit", "sa") == [
        f"0.0000 {upper:.4f}", "3 1 1", "AAA-D-----------", "DAA-.-"]


def test_secvel_caps_until_cal_and_rm() -> None:
    sim = Sim()
    sim.send("!vel 20")
    sim.send("!mor 5")
    sim.advance(0.2)
    assert sim.ask("?isvel x") == "10.000"  # secvel 10 mm/s
    sim.settle()
    sim.send("cal x")
    sim.settle()
    sim.send("!mor 5")
    sim.advance(0.2)
    assert sim.ask("?isvel x") == "10.000"  # E0 and EE enabled: rm needed too
    sim.settle()
    sim.send("rm x")
    sim.settle()
    sim.send("!mor -5")
    sim.advance(0.1)
    assert sim.ask("?isvel x") == "-20.000"
    sim.settle()
    sim.send("!secvel y 2", "!mor y 1")
    sim.advance(0.2)
    assert sim.ask("?isvel y") == "2.000"


def test_caltimeout_reports_t() -> None:
    sim = Sim()
    sim.send("!caltimeout 1 1 1")
    sim.send("cal")
    events = sim.events()
    assert [line for _, line in events] == ["TTT-."]
    assert events[0][0] == pytest.approx(1.0, abs=0.02)
    assert sim.send("sa", "calst") == ["TTT-.-", "0 0 0"]


# ---------------------------------------------------------------------------------------
# 6. Aborts and Ctrl+C


@pytest.mark.parametrize("abort", ["a", "!a", "a -1", "\x03"])
def test_abort_mid_move_reports_e(abort: str) -> None:
    sim = Sim()
    sim.send("!stopaccel 0.5 0.5")  # a and Ctrl+C brake with stopaccel, a -1 with accel
    sim.send("!moa 30 20")
    sim.advance(0.5)
    if abort == "\x03":
        sim.write(b"\x03")
    else:
        sim.send(abort)
    events = sim.events()
    assert [line for _, line in events] == ["EE@-."]
    stop = 10.0 / (1000.0 if abort == "a -1" else 500.0)
    assert events[0][0] == pytest.approx(0.5 + stop, abs=1e-6)
    assert sim.ask("sa") == "EE@-.-"
    x = float(sim.ask("?pos x"))
    assert 4.0 < x < 6.0


def test_abort_one_axis_and_stopaccel() -> None:
    sim = Sim()
    sim.send("!stopaccel y 0.1", "!moa y 20")
    sim.advance(0.5)
    sim.send("!moa x 10")
    sim.send("a y")
    events = sim.events()
    assert [line for _, line in events] == ["@E@-.", "@@@-."]
    assert events[0][0] == pytest.approx(0.5 + 10.0 / 100.0, abs=1e-6)  # 0.1 m/s²


def test_ctrl_c_clears_the_input_buffer() -> None:
    sim = Sim(wire=WireConfig(baud=None, processing_time_per_line=0.05))
    sim.write(b"!moa 30\r!moa y 5\r?pos\r")
    sim.now += 0.01  # the interpreter is still busy with the first line
    sim.write(b"\x03")
    sim.now += 0.2
    replies = sim.take() + sim.settle()
    assert replies == ["E@@-."]  # moa y and ?pos were discarded
    sim.write(b"?pos y\r")
    assert sim.advance(0.1) == ["0.0000"]
    assert sim.wire.ctrl_c_count == 1


def test_ctrl_c_discards_a_partial_line() -> None:
    sim = Sim()
    sim.write(b"!moa 5\x03\r?err\r")
    assert sim.take() == ["0"]
    assert sim.settle() == []
    assert sim.ask("?pos x") == "0.0000"


# ---------------------------------------------------------------------------------------
# 7. Trigger and snapshot lists


def test_trigp_list_semantics() -> None:
    sim = Sim()
    assert sim.ask("?trigc") == "0"
    sim.send("!trigp x -1 1", "!trigp -1 2", "!trigp -1 3")
    assert sim.send("?trigc", "?triga", "?trigm", "?err") == ["3", "x", "20", "0"]
    sim.send("!trigp y -1 4")  # an axis letter only when the list is empty
    assert sim.send("?err", "?trigc") == ["1", "3"]
    sim.send("!trigp x -1 4")
    assert sim.ask("?err") == "1"
    sim.send("!trigp -1 2.5")  # breaks the rising order
    assert sim.send("?err", "?trigc") == ["5", "3"]
    sim.send("!trigp 4 4")  # n = count + 1 appends
    sim.send("!trigp 2 1.5")  # 1-based overwrite
    assert sim.send("?trigp 1", "?trigp 2", "?trigp -1", "?trigp x 4") == [
        "1.0000", "1.5000", "4.0000", "4.0000"]
    sim.send("!trigp 6 7")  # beyond count + 1
    assert sim.ask("?err") == "5"
    sim.send("!trigp 5")  # an index without a position
    assert sim.ask("?err") == "6"
    sim.send("!trigp 0")
    assert sim.send("?trigc", "?triga") == ["0", "x"]
    sim.send("!trigp y 0")  # clears and selects the axis
    assert sim.ask("?triga") == "y"
    sim.send("!trigp -1 5", "!trigp -1 3")
    assert sim.send("?trigm", "?trigc") == ["21", "2"]
    assert sim.model.internal_errors == []


def test_trigc_and_trigi() -> None:
    sim = Sim()
    sim.send(*(f"!trigp -1 {p}" for p in range(1, 16)))
    assert sim.ask("?trigc") == "15"
    sim.send("!trigc 10")
    assert sim.send("?trigc", "?trigp -1") == ["10", "10.0000"]
    sim.send("!trigc 12")  # only shortening
    assert sim.send("?err", "?trigc") == ["5", "10"]
    assert sim.ask("?trigi") == "1"
    sim.send("!trigi 10")
    assert sim.ask("?trigi") == "10"
    sim.send("!trigi 11")
    assert sim.send("?err", "?trigi") == ["5", "10"]
    sim.send("!trigi 0")  # 1-based
    assert sim.ask("?err") == "5"
    sim.send("!trigi")
    assert sim.ask("?trigi") == "1"
    sim.send("!trigc 0")
    assert sim.ask("?trigc") == "0"


def test_trigr_counts_both_ends_and_replaces_the_list() -> None:
    sim = Sim()
    sim.send("!trigp -1 100", "!trigp -1 200")
    sim.send("!trigr y 0 10 11")
    assert sim.send("?trigr", "?triga", "?trigm", "?trigc") == [
        "0.0000 10.0000 11", "y", "20", "11"]
    assert sim.send("?trigp 1", "?trigp 2", "?trigp -1") == ["0.0000", "1.0000", "10.0000"]
    sim.send("!trigr 20 10 11")
    assert sim.send("?trigm", "?trigp 2", "?triga") == ["21", "19.0000", "y"]
    sim.send("!trigr 0 10 10001")
    assert sim.ask("?err") == "5"


def test_trigcount_counts_crossings_during_a_move() -> None:
    sim = Sim()
    sim.send("!moa -1")
    sim.settle()
    sim.send("!trigr x 0 10 11", "!trigcount 0")
    sim.send("!moa 12")
    sim.settle()
    assert sim.ask("?trigcount") == "0"  # the trigger is globally disabled (trig 0)
    sim.send("!moa -1")
    sim.settle()
    sim.send("!trig 1", "!moa 5.5")
    sim.settle()
    assert sim.send("?trigcount", "?trigi") == ["6", "7"]
    sim.send("!moa 12")
    sim.settle()
    assert sim.ask("?trigcount") == "11"
    sim.send("!moa 0.5")
    sim.settle()
    assert sim.ask("?trigcount") == "11"  # unidirectional: not on the way back
    sim.send("!moa -0.5")
    sim.settle()
    sim.send("!moa 3.5")  # travelled back behind the start: re-armed
    sim.settle()
    assert sim.ask("?trigcount") == "15"
    sim.send("!trigcount 110")
    assert sim.ask("?trigcount") == "110"


def test_trigp_list_fires_at_its_positions() -> None:
    sim = Sim()
    sim.send("!trigp -1 1", "!trigp -1 1.5", "!trigp -1 4", "!trig 1", "!moa 3")
    events = sim.events()
    assert [line for _, line in events] == ["@@@-."]
    assert sim.send("?trigcount", "?trigi") == ["2", "3"]


def test_trigger_list_holds_10000_entries() -> None:
    sim = Sim()
    sim.write(b"".join(f"!trigp -1 {i / 100:.2f}\r".encode() for i in range(MAX_TRIGGERS)))
    assert sim.take() == []
    assert sim.send("?trigc", "?err", "?trigp -1") == ["10000", "0", "99.9900"]
    sim.send("!trigp -1 100")
    assert sim.send("?err", "?trigc") == ["5", "10000"]


def test_snapshot_array() -> None:
    sim = Sim()
    sim.send("!snsa -1 1 2 3", "!snsa -1 4 5 6")
    assert sim.send("?snsc", "?snsa 1", "?snsa y 2", "?snsa -1") == [
        "2", "1.0000 2.0000 3.0000", "5.0000", "4.0000 5.0000 6.0000"]
    sim.send("!snsa 1 7 8 9")
    assert sim.ask("?snsa 1") == "7.0000 8.0000 9.0000"
    sim.send("!snsa 4 1 1 1")  # beyond count + 1
    assert sim.ask("?err") == "5"
    assert sim.ask("?snsi") == "0"  # 0-based: 0..snsc-1
    sim.send("!snsi 1")
    assert sim.ask("?snsi") == "1"
    sim.send("!snsi 2")
    assert sim.send("?err", "?snsi") == ["5", "1"]
    sim.send("!moa 3 4")
    sim.settle()
    sim.send("snse 2")  # captures the current position, always appended
    assert sim.send("?snsc", "?snsa 3", "?snsp", "?snsp y") == [
        "3", "3.0000 4.0000 0.0000", "3.0000 4.0000 0.0000", "4.0000"]
    sim.send("!snsp 5 5 5")
    assert sim.send("?snsc", "?snsp x") == ["4", "5.0000"]
    sim.send("!snsc 1")
    assert sim.ask("?snsc") == "1"
    sim.send("!snsa 0")
    assert sim.ask("?snsc") == "0"
    sim.send("!sns 0", "snse 2")  # snapshots disabled: no capture
    assert sim.ask("?snsc") == "0"


def test_snapshot_array_holds_1024_entries() -> None:
    sim = Sim()
    sim.write(b"".join(f"!snsa -1 {i} 0 0\r".encode() for i in range(MAX_SNAPSHOTS)))
    assert sim.send("?snsc", "?err", "?snsa x 1024") == ["1024", "0", "1023.0000"]
    sim.send("!snsa -1 1 1 1")
    assert sim.send("?err", "?snsc") == ["5", "1024"]
    sim.send("snse 1")  # a capture into a full array is dropped
    assert sim.ask("?snsc") == "1024"


# ---------------------------------------------------------------------------------------
# 8. Persistence


def _saved_pairs() -> list[tuple[str, str, str]]:
    """(set line, read line, expected reply) of a few saved settings."""
    return [
        ("!vel 1 2 3", "?vel", "1.000 2.000 3.000"),
        ("!pitch y 2.5", "?pitch y", "2.5000"),
        ("!dim z 1", "?dim", "2 2 1"),
        ("!swact 1 0 0", "?swact y", "1 0 0"),
        ("!caltimeout 10 20 30", "?caltimeout", "10 20 30"),
        ("!joyspeed 2 25", "?joyspeed 2", "25.000"),
        ("!resolution 3", "?resolution", "3"),
    ]


def test_save_writes_a_state_file_a_new_model_loads(tmp_path: Path) -> None:
    state = tmp_path / "tango.json"
    sim = Sim(state_file=state)
    sim.send(*(line for line, _, _ in _saved_pairs()))
    sim.send("!autostatus 2")  # never saved (L2069)
    assert sim.send("save") == ["OK..."]
    data = json.loads(state.read_text(encoding="utf-8"))
    assert data["axes"]["vel"][0] == [1.0]
    assert "autostatus" not in data["global"]
    assert list(tmp_path.iterdir()) == [state]  # no temp file left behind
    again = Sim(state_file=state)
    for _, read, expected in _saved_pairs():
        assert again.ask(read) == expected
    assert again.send("!vel 4", "?autostatus") == ["1"]


def test_a_failed_save_keeps_the_old_file(tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    state = tmp_path / "tango.json"
    sim = Sim(state_file=state)
    sim.send("!vel 3", "save")
    old = state.read_bytes()

    def crash(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        raise OSError("power failure")

    monkeypatch.setattr(os, "replace", crash)
    assert sim.send("!vel 7", "save") == ["ERR 73"]
    assert sim.ask("?err") == "73"
    assert state.read_bytes() == old
    assert list(tmp_path.iterdir()) == [state]
    monkeypatch.undo()
    assert Sim(state_file=state).ask("?vel x") == "3.000"
    assert sim.model.internal_errors == []


def test_a_corrupt_state_file_is_refused_at_start(tmp_path: Path) -> None:
    state = tmp_path / "tango.json"
    state.write_text('{"axes": {"vel": [[1', encoding="utf-8")
    with pytest.raises(StateFileError, match="not a tango_aio emulator state file"):
        Sim(state_file=state)  # more cases: tests/sim/test_serve.py


def test_restore_reloads_the_saved_set_without_restarting(tmp_path: Path) -> None:
    state = tmp_path / "tango.json"
    sim = Sim(state_file=state)
    sim.send("!vel 3", "save", "!vel 5", "!autostatus 4", "!digout 101")
    sim.take()
    sim.send("!moa 2")
    sim.settle()
    assert sim.send("restore") == ["restore"]  # echoed in mode 4, no reply of its own
    assert sim.send("?vel x", "?autostatus", "?pos x", "?digout") == [
        "3.000", "4", "2.0000", "10100000"]  # digout is not saved: kept
    sim.send("!vel 6")
    assert sim.send("?restore", "?vel x") == ["OK...", "3.000"]


def test_restore_minus_1_is_a_factory_reset(tmp_path: Path) -> None:
    state = tmp_path / "tango.json"
    sim = Sim(state_file=state)
    sim.send("!vel 3", "save", "!autostatus 2")
    sim.take()
    assert sim.send("restore -1") == []  # no reply, also no ack (bare)
    sim.now += 2.0
    assert sim.send("?err", "?vel x", "?autostatus") == ["0", "10.000", "1"]
    assert not state.exists()


def test_reset_restarts_in_mode_1_and_takes_a_second(tmp_path: Path) -> None:
    state = tmp_path / "tango.json"
    sim = Sim(state_file=state)
    sim.send("!vel 3", "save", "!vel 5", "!autostatus 2")
    sim.take()
    sim.write(b"reset\r?err\r")
    assert sim.take() == []
    sim.now += 0.5
    sim.write(b"?err\r")  # the manual's poll loop (L1837-1857): lost while rebooting
    sim.now += 0.499
    assert sim.take() == []  # not responding while rebooting
    sim.now += 0.002
    assert sim.take() == []  # both '?err' lines were lost
    assert sim.wire.lost_bytes == 10
    assert sim.send("?err", "?autostatus", "?vel x", "?pos x") == ["0", "1", "3.000", "0.0000"]


def test_without_a_state_file_the_saved_set_lives_in_memory() -> None:
    sim = Sim()
    sim.send("!vel 3", "!joyspeed 2 25", "save", "!vel 5", "!joyspeed 2 30")
    sim.take()
    assert sim.send("restore") == []
    assert sim.send("?vel x", "?joyspeed 2") == ["3.000", "25.000"]
    sim.send("!vel 6")
    sim.write(b"reset\r")
    sim.now += 2.0
    assert sim.send("?err", "?vel x") == ["0", "3.000"]  # a reset loads it too
    sim.write(b"restore -1\r")
    sim.now += 2.0
    assert sim.send("?err", "?vel x", "?joyspeed 2") == ["0", "10.000", "10.000"]
    assert sim.send("restore") == [] and sim.send("?vel x") == ["10.000"]


def test_saved_settings_sweep(tmp_path: Path) -> None:
    """Every saved setting the generic sweep writes survives save and a new boot."""
    state = tmp_path / "tango.json"
    sim = Sim(state_file=state)
    reads: list[str] = []
    for name in _sweep_cases():
        entry = INSTRUCTIONS[name]
        if not entry.saved or name in ("baud", "ipreter", "configdisplay", "cts"):
            continue  # link settings: take effect at the next boot, still stored
        sig = entry.write[0]
        axis = " y" if sig.per_axis and sig.axis is not AxisRule.NONE else ""
        params: Sequence[Param] = (*sig.lead, *sig.per_axis)
        values = [_sweep_value(p, None) for i, p in enumerate(params)
                  if not (p.optional and i > 0)]
        sim.send(f"!{name}{axis} {' '.join(values)}")
        assert sim.err == 0, name
        reads.append(f"?{name}{axis}")
    before = [sim.ask(read) for read in reads]
    assert sim.send("save") == ["OK..."]
    again = Sim(state_file=state)
    assert [again.ask(read) for read in reads] == before
