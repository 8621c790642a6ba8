"""Tests of the instruction catalog, the command-line grammar and the reply parsers.

The reference data (``../shared/reference/instructions.json``, taken from the manual for
firmware 1.71) drives most tests: every documented example must encode and every
documented reply must parse, except the explicit lists of known-bad examples below.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tango_aio.catalog._encode import build, check_framing, check_rows_framing
from tango_aio.catalog._instructions import (
    AXES,
    INSTRUCTIONS,
    MAX_LINE_BYTES,
    AxisRule,
    Command,
    Context,
    Form,
    Instruction,
    Kind,
    Param,
    Shape,
    Signature,
    encode,
    format_number,
    lookup,
    parse,
)
from tango_aio.catalog._replies import DetInfo, VersionInfo, parse_reply, reply_rule
from tango_aio.errors import InvalidCommandError, ProtocolError, TangoError

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = ROOT / "reference" / "instructions.json"
SPEC: list[dict[str, Any]] = json.loads(REFERENCE.read_text(encoding="utf-8"))


def _examples() -> Iterator[tuple[str, dict[str, Any]]]:
    for entry in SPEC:
        for example in entry["examples"]:
            yield entry["name"], example


def _example_id(name: str, example: dict[str, Any]) -> str:
    return f"{name}-L{example['line']}-{example['cmd']}"


EXAMPLES = [pytest.param(name, ex, id=_example_id(name, ex)) for name, ex in _examples()]


def invalid(line: str, context: Context | None = None) -> InvalidCommandError:
    """Parse ``line``, which must be rejected, and return the error."""
    with pytest.raises(InvalidCommandError) as info:
        parse(line, context)
    return info.value


# ======================================================================================
# 1. The catalog holds every instruction of the manual


def test_catalog_has_227_instructions() -> None:
    assert len(INSTRUCTIONS) == 227
    assert all(name == entry.name for name, entry in INSTRUCTIONS.items())


def test_catalog_names_match_the_reference() -> None:
    assert sorted(INSTRUCTIONS) == sorted(entry["name"] for entry in SPEC)


@pytest.mark.parametrize("entry", SPEC, ids=[e["name"] for e in SPEC])
def test_catalog_entry_matches_the_reference(entry: dict[str, Any]) -> None:
    instruction = INSTRUCTIONS[entry["name"]]
    forms = {Form.SET if f == "!" else Form.READ if f == "?" else Form.BARE
             for f in entry["forms"]}
    assert instruction.forms == forms
    assert set(instruction.aliases) == set(entry["aliases"])
    assert instruction.saved is (entry["saved"] in ("Y", "(Y)"))
    assert instruction.line == entry["manual_lines"][0]
    # A form that sets has a write grammar, a form that reads a read grammar.
    if Form.SET in forms or (Form.BARE in forms and not instruction.is_read(Form.BARE)):
        assert instruction.write
    if Form.READ in forms or instruction.is_read(Form.BARE):
        assert instruction.read


@pytest.mark.parametrize(
    ("alias", "name"),
    [("sa", "statusaxis"), ("SA", "statusaxis"), ("Sa", "statusaxis"),
     ("poweramplifier", "pa"), ("PowerAmplifier", "pa"), ("POWERAMPLIFIER", "pa"),
     ("VEL", "vel"), ("StatusAxis", "statusaxis")],
)
def test_lookup_resolves_aliases_case_insensitively(alias: str, name: str) -> None:
    assert lookup(alias) is INSTRUCTIONS[name]


def test_aliases_parse_to_the_canonical_name() -> None:
    assert parse("sa x").line == "statusaxis x"
    assert parse("!poweramplifier 1").line == "!pa 1"


def test_lookup_of_an_unknown_name_is_error_4() -> None:
    with pytest.raises(InvalidCommandError) as info:
        lookup("frobnicate")
    assert info.value.number == 4


def _params(sig: Signature) -> list[Param]:
    return [*sig.lead, *sig.per_axis]


@pytest.mark.parametrize("name", sorted(INSTRUCTIONS))
def test_catalog_entries_are_consistent(name: str) -> None:
    entry = INSTRUCTIONS[name]
    for sig in (*entry.write, *entry.read):
        for param in _params(sig):
            if param.lo is not None and param.hi is not None:
                assert param.lo <= param.hi, param
            if param.kind is Kind.CHOICE:
                assert param.choices, param
            if param.kind is Kind.BITS:
                assert param.width > 0, param
            if param.hi_dim9 is not None:
                assert param.hi is not None and param.hi_dim9 > param.hi
        if sig.precision is not None:
            assert 0 <= sig.precision.lo < sig.precision.hi
            # The parser reads a digit count only where no per-axis values follow.
            assert not sig.per_axis
    if entry.reply_group > 1:
        assert entry.reply in (Shape.AXES_FLOAT, Shape.AXES_INT, Shape.AXES_TEXT)
    if entry.completion is not None:
        assert entry.write and Form.SET in entry.forms


# ======================================================================================
# 2. Every documented example command encodes

#: Examples of the manual that are not valid command lines, with the reason.
KNOWN_BAD_EXAMPLES: dict[tuple[str, int], str] = {
    ("!moa / !mor / m / a / cal / rm", 2134):
        "pseudo-example: the autostatus table lists several instructions in one row",
    ("!moa / !mor / m / !moc / !mol", 2141):
        "pseudo-example: the autostatus table lists several instructions in one row",
    ("!cal / !rm", 2143):
        "pseudo-example: the autostatus table lists several instructions in one row",
    ("!moa / !mor / m / a / cal / rm", 2161):
        "pseudo-example: the autostatus table lists several instructions in one row",
    ("!vel -10", 2152):
        "documented-invalid: answers 'ERR 5', vel is 0.000001 to 200 (L3455)",
    ("vel 10", 2154):
        "the autostatus table says a bare 'vel 10' executes without reply, but the syntax of "
        "vel is '!vel or ?vel' (L3443): the catalog follows the syntax line (error 7)",
    ("!calbspeed 50 50", 5833):
        "documented-invalid: 'ILLEGAL INSTRUCTION!', one value sets all axes (L5809-5845)",
    ("!calrefspeed 5 5", 5878):
        "documented-invalid: 'ILLEGAL INSTRUCTION!', one value sets all axes (L5866-5890)",
    ("!calvel 10 0.5", 6093): "documented-invalid: calvel is set per axis only",
    ("!rmvel 10 0.5", 6157): "documented-invalid: rmvel is set per axis only",
    ("go 10.1 –0.5 0", 6674): "manual typo: an en dash as the minus sign (notes §13.23)",
    ("!joyspeed z 1", 7348):
        "manual typo: printed under joyvel, meaning '!joyvel z 1' (notes §13.9)",
    ("!pa0", 10196): "manual typo: printed without the space (notes §13.10)",
    ("!encpos 1 1 0", 11232): "documented-invalid: '!encpos 1' applies to all axes",
    ("!ctrff 2 2 2 2", 11971): "documented-invalid: 'Not supported!', per axis only",
    ("!ctrd 50 50 50", 12047): "documented-invalid: 'Not supported!', one value or per axis",
    ("?triga y", 13979): "comment typo: '(read the trigger axis)' is '?triga', no argument",
}

#: What the typos of KNOWN_BAD_EXAMPLES mean; these must encode.
CORRECTED_EXAMPLES: dict[tuple[str, int], str] = {
    ("go 10.1 –0.5 0", 6674): "go 10.1 -0.5 0",
    ("!joyspeed z 1", 7348): "!joyvel z 1",
    ("!pa0", 10196): "!pa 0",
    ("?triga y", 13979): "?triga",
    ("vel 10", 2154): "!vel 10",
}

#: The error number each documented-invalid example gets.
KNOWN_BAD_CODES: dict[tuple[str, int], int] = {
    ("!vel -10", 2152): 5,  # the manual's own reply is 'ERR 5'
    ("vel 10", 2154): 7,
    ("!calbspeed 50 50", 5833): 6,
    ("!calrefspeed 5 5", 5878): 6,
    ("!encpos 1 1 0", 11232): 6,
    ("!ctrd 50 50 50", 12047): 6,
    ("!calvel 10 0.5", 6093): 1,
    ("!rmvel 10 0.5", 6157): 1,
    ("!ctrff 2 2 2 2", 11971): 1,
}


def test_known_bad_examples_exist_in_the_reference() -> None:
    documented = {(ex["cmd"], ex["line"]) for _, ex in _examples()}
    assert set(KNOWN_BAD_EXAMPLES) <= documented
    assert set(CORRECTED_EXAMPLES) <= set(KNOWN_BAD_EXAMPLES)
    assert set(KNOWN_BAD_CODES) <= set(KNOWN_BAD_EXAMPLES)


@pytest.mark.parametrize(("name", "example"), EXAMPLES)
def test_documented_example_encodes(name: str, example: dict[str, Any]) -> None:
    cmd: str = example["cmd"]
    key = (cmd, example["line"])
    if key in KNOWN_BAD_EXAMPLES:
        error = invalid(cmd)
        if key in KNOWN_BAD_CODES:
            assert error.number == KNOWN_BAD_CODES[key], KNOWN_BAD_EXAMPLES[key]
        if key in CORRECTED_EXAMPLES:
            assert encode(CORRECTED_EXAMPLES[key]).endswith(b"\r")
        return
    data = encode(cmd)
    assert data.endswith(b"\r")
    assert data.count(b"\r") == 1
    assert b"\n" not in data and b"\x03" not in data
    assert len(data) <= MAX_LINE_BYTES
    text = data[:-1].decode("ascii")
    first = parse(cmd)
    again = parse(text)
    assert again.line == text == first.line
    assert again.values == first.values and again.axis == first.axis
    assert again.instruction is first.instruction
    assert encode(text) == data


# ======================================================================================
# 3. Every documented reply parses to a typed value

#: Documented replies that parse_reply does not handle, with the reason. The protocol core
#: handles acknowledgements, echoes and completion strings itself.
REPLY_EXCEPTIONS: dict[tuple[str, int], str] = {
    ("!vel 10", 2150): "autostatus 2 acknowledgement 'OK...' of a set instruction",
    ("!moa 10 5 0", 2168): "autostatus 4 echo of the instruction",
    ("cal", 5330): "autostatus completion string of cal",
    ("cal y", 5332): "autostatus completion string of cal",
    ("!cal", 5340): "autostatus completion string of cal",
    ("rm", 5410): "autostatus completion string of rm",
    ("rm y", 5412): "autostatus completion string of rm",
    ("!rm", 5420): "autostatus completion string of rm",
    ("!cal x", 10628): "autostatus completion string of cal",
    ("!joy 0", 7154): "'!joy 0' produces an autostatus string (notes §13.3)",
    ("?encref z", 10976):
        "manual quirk (notes §13.17): a one-axis read is shown returning three values",
}


def reply_lines(reply: str) -> list[str]:
    """The reply lines of a documented reply; the manual writes a CR as '[CR]'."""
    lines = reply.replace("[CR]", "\n").split("\n")
    return lines[:-1] if len(lines) > 1 and lines[-1] == "" else lines


#: Exact values of documented replies (command, manual line) → parse_reply result.
EXPECTED_REPLIES: dict[tuple[str, int], object] = {
    ("?version", 1105): VersionInfo("TANGO-DTe", "1.69", "Mar  6 2018", "15:52:19"),
    ("?version 1", 1107): VersionInfo("", "1.69"),
    ("?det", 1171): DetInfo(0x13F21),
    ("detext", 1212): ["02832", "= MR Encoder", "= 3 Axes", "= Snapshot", "= Trigger out"],
    ("?readsn", 1265): "140413045",
    ("?ver", 1300): "Vers:LS32.00.038",
    ("uptime", 1347): 8731,
    ("temp", 1368): 28.5,
    ("?maxaxis", 1389): "3",
    ("?etspresent", 1466): "1000",
    ("?stagesn", 1522): "140328015 --------- --------- ---------",
    ("?maxpos", 1586): {"x": 2600.0, "y": 2600.0, "z": 2600.0},
    ("?maxpos x", 1588): 2600.0,
    ("?pa", 1969): [1],
    ("?pa -1", 1971): [1, 1, 1],
    ("?err", 1985): 29,
    ("?statusaxis", 2715): {"x": "@", "y": "@", "z": "@"},
    ("?statusaxis", 2721): {"x": "J", "y": "M"},
    ("sa", 2723): {"x": "A", "y": "@", "z": "@"},
    ("sa x", 2725): "M",
    ("calst", 2767): {"x": 3, "y": 3, "z": 1},
    ("?status", 2818): (4, None),
    ("?status", 2820): (0, None),
    ("err", 2871): 0,
    ("?err", 2877): 5,
    ("help", 2915): (0, "no error"),
    ("help", 2917): (5, "number outside range"),
    ("help 29", 2919): (29, "servo amplifier off"),
    ("?pitch", 3192): {"x": 1.0, "y": 1.0},
    ("?accel 6", 3345): {"x": 0.5, "y": 0.123456, "z": 0.2},
    ("?vel 6", 3523): {"x": 20.0, "y": 0.123456, "z": 5.0},
    ("?vel y 4", 3525): 0.1235,
    ("?secvel y 5", 3673): 0.0001,
    ("?lock", 4291): "0000000000000000",
    ("?lockaxis", 4322): {"x": 1, "y": 1, "z": 0, "a": 0},
    ("?lockstate x", 4382): "1100000000000000",
    ("?lim", 4619): {"x": (-2600.0, 2600.0), "y": (-2600.0, 2600.0), "z": (-800.0, 800.0)},
    ("?lim", 4621): {"x": (-2600.0, 2600.0), "y": (-2600.0, 2600.0), "z": (-800.0, 800.0)},
    ("?clim 1", 4671): [0.0],
    ("?swtyp y", 4814): (1, 0, 1),
    ("?swtyp", 4820): {"x": (1, 1, 1), "y": (1, 1, 1), "z": (1, 1, 1)},
    ("?swtyp", 4822): {"x": (1, 1, 1), "y": (1, 1, 1), "z": (1, 1, 1)},
    ("?swact a", 4966): (1, 0, 1),
    ("readsw", 5078): "000000001000",
    ("swin 1", 5135): "1",
    ("?statuslimit", 5191): "AA-A---D-LL-L--L",
    ("?calzeropos", 6005): {"x": 0.0, "y": -153.1433, "z": 0.0, "a": 0.0},
    ("?calvel y", 6091): (10.0, 0.5),
    ("?keyspeed x", 7557): (1.0, 10.0),
    ("?keyspeed", 7559): {"x": (2.0, 20.0), "y": (2.0, 20.0), "z": (0.1, 1.0)},
    ("key", 7630): [0, 0, 0, 0],
    ("keyl", 7667): [0, 1, 0, 0],
    ("?zwaxis", 7946): "z",
    ("?hdi -1", 8205): "12 97 [Joystick 2 axis]",
    ("?digin 8", 8575): "1",
    ("?adiginfunc", 9261): [0, 0, 1, 2],
    ("?adiginfunc 3", 9263): [2],
    ("anain v 10", 9450): 509.75,
    ("?anaout", 9564): [0.0, 0.0, 0.0],
    ("?anaout c 0", 9568): [100.0],
    ("?drop 0", 10272): 7,
    ("?enc 1", 10622): {"x": 0, "y": 0},
    ("?enctype a 1", 10859): -1,
    ("?encerr", 11151): {"x": "0", "y": "0", "z": "e"},
    ("?encamp 1", 11190): {"x": 57.3, "y": 73.8, "z": 0.5},
    ("encsync -1", 11293): "2 3 -1  2 2 0  0 0 0",
    ("?ctrff", 11983): {"x": (2.0, 2.0), "y": (2.0, 2.0), "z": (2.0, 2.0)},
    ("?ctrff y", 11985): (2.0, 2.0),
    ("?ctrstatus 1", 12375): {"x": "1", "y": "1", "z": "0"},
    ("?ctrstatus x 1", 12377): "1",
    ("ctrstatus x 0", 12393): ("2", "7"),
    ("ctrstatus 0", 12395): {"x": ("2", "7"), "y": ("2", "7"), "z": ("0", "0")},
    ("?ctrdiff y", 12443): 0.0015,
    ("?trigbf", 13386): 1000.0,
    ("?trigr", 13690): [11.5, 16.5, 11.0],
    ("?triga", 13692): "y",
    ("?trigp x 3", 14064): 11.0,
    ("?trigp -1", 14066): 32.0,
    ("?snsc", 14636): 3,
    ("?snsa y 1", 14636): 1.2345,
}

REPLY_EXAMPLES = [
    pytest.param(name, ex, id=_example_id(name, ex))
    for name, ex in _examples()
    if ex.get("reply") is not None and (ex["cmd"], ex["line"]) not in KNOWN_BAD_EXAMPLES
]

_NUMERIC_SHAPES = {Shape.INT, Shape.FLOAT, Shape.ERROR_NUMBER, Shape.AXES_FLOAT,
                   Shape.AXES_INT, Shape.AXES_TEXT, Shape.NUMBERS, Shape.INTS}
_ITEM_TYPES: dict[Shape, type] = {
    Shape.AXES_FLOAT: float, Shape.AXES_INT: int, Shape.AXES_TEXT: str,
    Shape.NUMBERS: float, Shape.INTS: int, Shape.INT: int, Shape.FLOAT: float,
    Shape.ERROR_NUMBER: int,
}


def _flatten(value: object) -> list[object]:
    if isinstance(value, dict):
        return [item for v in value.values() for item in _flatten(v)]
    if isinstance(value, tuple | list):
        return [item for v in value for item in _flatten(v)]
    return [value]


def _check_structure(command: Command, reply: str, result: object) -> None:
    """Generic checks: types per shape, axes in order, and the reply's values in order."""
    shape = command.instruction.reply
    if shape in (Shape.AXES_FLOAT, Shape.AXES_INT, Shape.AXES_TEXT):
        if command.axis is None:
            assert isinstance(result, dict)
            assert list(result) == list(AXES[: len(result)])
            values = list(result.values())
        else:
            values = [result]
        for value in values:
            if isinstance(value, tuple):
                assert len(value) > 1
    if shape in _NUMERIC_SHAPES:
        items = _flatten(result)
        assert all(type(item) is _ITEM_TYPES[shape] for item in items), result
        tokens = [t for t in re.split(r"[\s,]+", reply.replace("[CR]", " ")) if t]
        if command.instruction.digit_values:
            tokens = [d for t in tokens for d in t]
        # The reply's values, in order, are the parsed values.
        if _ITEM_TYPES[shape] is str:
            assert items == tokens
        else:
            assert [float(str(i)) for i in items] == [float(t) for t in tokens]
    if shape in (Shape.TEXT, Shape.FLAGS):
        assert result == reply.strip()
    if shape is Shape.FLAGS:
        assert isinstance(result, str) and re.fullmatch(r"\S+", result)


@pytest.mark.parametrize(("name", "example"), REPLY_EXAMPLES)
def test_documented_reply_parses(name: str, example: dict[str, Any]) -> None:
    cmd, reply = example["cmd"], example["reply"]
    key = (cmd, example["line"])
    command = parse(cmd)
    if key in REPLY_EXCEPTIONS:
        # The exception must still be one: parse_reply refuses it rather than guessing.
        with pytest.raises(ProtocolError):
            parse_reply(command, reply_lines(reply))
        return
    assert command.is_read, f"{cmd!r} has a documented reply but does not read"
    result = parse_reply(command, reply_lines(reply))
    _check_structure(command, reply, result)
    if key in EXPECTED_REPLIES:
        assert result == EXPECTED_REPLIES[key]


def test_reply_tables_name_documented_examples() -> None:
    documented = {(ex["cmd"], ex["line"]) for _, ex in _examples() if ex.get("reply")}
    assert set(REPLY_EXCEPTIONS) <= documented
    assert set(EXPECTED_REPLIES) <= documented


def test_completion_exceptions_are_completions() -> None:
    for cmd in ("cal", "cal y", "!cal", "rm", "!rm", "!cal x", "!moa 10 5 0"):
        assert parse(cmd).instruction.completion is not None


def test_version_reply() -> None:
    info = parse_reply(parse("?version"), ["TANGO-DTe, Version 1.69, Mar  6 2018 , 15:52:19"])
    assert isinstance(info, VersionInfo)
    assert info.model == "TANGO-DTe"
    assert info.firmware == "1.69"
    assert info.firmware_tuple == (1, 69)
    old = parse_reply(parse("version"), ["TANGO-DT-S, Version 1.57, Apr 17 2012 , 12:12:02"])
    assert old == VersionInfo("TANGO-DT-S", "1.57", "Apr 17 2012", "12:12:02")
    with pytest.raises(ProtocolError):
        parse_reply(parse("?version"), ["garbage"])


def test_det_reply_bits() -> None:
    # L1119-1185: 81697 = 0x13F21 = I/O1 extension, TVRin + trigger out, display, speedpoti,
    # hand wheel, snapshot, 2 axes, 1Vpp encoder.
    info = parse_reply(parse("?det"), ["81697"])
    assert isinstance(info, DetInfo)
    assert info.value == 0x13F21
    assert info.axes == 2
    assert info.options == {"encoder_1vpp", "display", "speedpoti", "handwheel", "snapshot",
                            "tvr_in", "trigger_out", "io_extension"}
    assert info.has("snapshot") and info.has("trigger_out")
    assert not info.has("tvr_out") and not info.has("multi_io")
    assert DetInfo(0x30).axes == 3


def test_help_reply() -> None:
    assert parse_reply(parse("help"), ["ERROR 5,number outside range"]) == (
        5, "number outside range")


def test_err_reply_is_int() -> None:
    value = parse_reply(parse("?err"), ["29"])
    assert value == 29 and type(value) is int
    with pytest.raises(ProtocolError):
        parse_reply(parse("?err"), ["OK..."])


def test_grouped_reply_must_be_complete() -> None:
    with pytest.raises(ProtocolError):
        parse_reply(parse("?lim"), ["-2600 2600 -2600"])
    with pytest.raises(ProtocolError):
        parse_reply(parse("?vel x"), ["1.0 2.0"])
    with pytest.raises(ProtocolError):
        parse_reply(parse("?vel"), ["1 2 3 4 5"])


def test_ctrstatus_groups_depend_on_the_option() -> None:
    assert parse_reply(parse("?ctrstatus"), ["2 2 0"]) == {"x": "2", "y": "2", "z": "0"}
    assert parse_reply(parse("?ctrstatus 0"), ["2 7 2 3"]) == {"x": ("2", "7"),
                                                             "y": ("2", "3")}


def test_execute_without_reply_refuses_data() -> None:
    with pytest.raises(ProtocolError):
        parse_reply(parse("!vel 10"), ["10.000"])
    assert parse_reply(parse("save"), ["OK..."]) == (0, None)
    assert parse_reply(parse("!save"), ["ERR"]) == (None, None)


def test_reply_rules() -> None:
    assert reply_rule(parse("?vel")).count == 1
    assert reply_rule(parse("!vel 1")).count == 0
    assert reply_rule(parse("save")).count == 1
    assert reply_rule(parse("?mrt 5")).count == 5
    assert reply_rule(parse("?mrt -3")).count == 3
    assert reply_rule(parse("?mrt")).count == 10
    assert reply_rule(parse("?service")).terminator == "END_SERVICE_PRINT."
    lim = reply_rule(parse("?lim"))
    assert lim.continuation is not None and lim.continuation.match("-2600 2600, -800 800")
    assert not lim.continuation.match("0")
    assert reply_rule(parse("?lim"), Context(extmode=1)).continuation is None
    assert reply_rule(parse("?lim x")).continuation is None


# ======================================================================================
# 4. Every documented range is enforced: boundaries accepted, just outside rejected


def _valid(param: Param) -> str:
    """A value that ``param`` accepts."""
    if param.kind is Kind.CHOICE:
        return str(param.choices[0])
    if param.kind is Kind.BITS:
        return "0"
    for bound in (param.lo, param.hi):
        if bound is not None:
            return _fmt(param, bound)
    return _fmt(param, param.min_abs or 0)


def _fmt(param: Param, value: float | Decimal) -> str:
    if param.kind is Kind.FLOAT:
        return format(Decimal(format_number(float(value))), "f")
    return str(int(value))


def _step(param: Param) -> Decimal:
    return Decimal("0.000001") if param.kind is Kind.FLOAT else Decimal(1)


@dataclass(frozen=True)
class Slot:
    """One ranged value position of one signature of one form of an instruction."""

    name: str
    form: Form
    index: int  # which alternative signature
    where: str  # "lead", "axis" or "digits"
    position: int

    @property
    def instruction(self) -> Instruction:
        return INSTRUCTIONS[self.name]

    @property
    def signature(self) -> Signature:
        entry = self.instruction
        return entry.signatures(self.form)[self.index]

    @property
    def param(self) -> Param:
        sig = self.signature
        if self.where == "lead":
            return sig.lead[self.position]
        if self.where == "axis":
            return sig.per_axis[self.position]
        assert sig.precision is not None
        return Param("digits", Kind.INT, sig.precision.lo, sig.precision.hi)

    def line(self, value: str) -> str:
        """A complete line with ``value`` in this slot and valid values elsewhere."""
        sig = self.signature
        parts = [self.form.value + self.name]
        if sig.axis is AxisRule.REQUIRED:
            parts.append("x")
        for i, param in enumerate(sig.lead):
            parts.append(value if (self.where, self.position) == ("lead", i) else _valid(param))
        for i, param in enumerate(sig.per_axis):
            parts.append(value if (self.where, self.position) == ("axis", i) else _valid(param))
        if self.where == "digits":
            parts.append(value)
        return " ".join(parts)


def _ranged(param: Param) -> bool:
    return (param.kind in (Kind.CHOICE, Kind.BITS) or param.lo is not None
            or param.hi is not None or param.min_abs is not None)


def _slots() -> Iterator[Slot]:
    for name, entry in sorted(INSTRUCTIONS.items()):
        for form, sigs in ((Form.SET, entry.write), (Form.READ, entry.read)):
            if not entry.allows(form):
                form = Form.BARE  # the bare form uses the same grammar
            for index, sig in enumerate(sigs):
                for i, param in enumerate(sig.lead):
                    if _ranged(param):
                        yield Slot(name, form, index, "lead", i)
                for i, param in enumerate(sig.per_axis):
                    if _ranged(param):
                        yield Slot(name, form, index, "axis", i)
                if sig.precision is not None and not sig.per_axis:
                    yield Slot(name, form, index, "digits", 0)


SLOTS = [pytest.param(s, id=f"{s.form.value or 'bare:'}{s.name}-{s.index}-{s.where}"
                         f"{s.position}-{s.param.name}") for s in _slots()]


def _accepted_and_rejected(param: Param) -> tuple[list[str], list[str]]:
    accepted: list[str] = []
    rejected: list[str] = []
    if param.kind is Kind.CHOICE:
        words = [c for c in param.choices if isinstance(c, str)]
        numbers = [c for c in param.choices if isinstance(c, int)]
        accepted += [str(c) for c in param.choices]
        if words:
            # Words only: a number could be valid in an alternative signature (anaout).
            rejected += ["q", "xy"]
            if any(word.isdigit() for word in words):
                rejected.append("9")
        if numbers:
            # Every gap of a small set (trigm 12..19), the neighbours of each choice else.
            low, high = min(numbers), max(numbers)
            candidates = (set(range(low - 1, high + 2)) if high - low <= 256
                          else {n + d for n in numbers for d in (-1, 1)})
            rejected += [str(n) for n in sorted(candidates - set(numbers))]
            rejected.append(f"{numbers[0]}.5")
        return accepted, rejected
    if param.kind is Kind.BITS:
        return (["0", "1", "1" * param.width, "0" * param.width],
                ["0" * (param.width + 1), "2", "01x"])
    step = _step(param)
    if param.lo is not None:
        accepted.append(_fmt(param, param.lo))
        rejected.append(_fmt(param, Decimal(_fmt(param, param.lo)) - step))
    if param.hi is not None:
        accepted.append(_fmt(param, param.hi))
        rejected.append(_fmt(param, Decimal(_fmt(param, param.hi)) + step))
    if param.min_abs is not None:
        accepted += [_fmt(param, param.min_abs), _fmt(param, -param.min_abs)]
        smaller = Decimal(_fmt(param, param.min_abs)) - step
        rejected += [_fmt(param, smaller), _fmt(param, -smaller)]
    if param.kind is Kind.INT:
        rejected.append(f"{_valid(param)}.5")
    return accepted, rejected


@pytest.mark.parametrize("slot", SLOTS)
def test_range_boundaries(slot: Slot) -> None:
    param = slot.param
    accepted, rejected = _accepted_and_rejected(param)
    for value in accepted:
        command = parse(slot.line(value))
        assert value.lower() in command.tokens, (slot.line(value), command.tokens)
    for value in rejected:
        error = invalid(slot.line(value))
        assert error.number == 5, (slot.line(value), error)
        if len(slot.signature.lead) + len(slot.signature.per_axis) and len(
                slot.instruction.signatures(slot.form)) == 1:
            assert error.parameter == param.name, (slot.line(value), error)


def test_every_ranged_parameter_is_covered() -> None:
    # Guard against the generator above silently finding nothing.
    assert len(SLOTS) > 250
    names = {slot.name for slot in _slots()}
    assert {"vel", "trigm", "lock", "anaout", "flash", "snsv", "pitch", "swtyp"} <= names


def _dim9_params() -> Iterator[Any]:
    for slot in _slots():
        if slot.where != "digits" and slot.param.hi_dim9 is not None:
            yield pytest.param(slot, id=f"{slot.name}-{slot.param.name}")


@pytest.mark.parametrize("slot", list(_dim9_params()))
def test_dim9_raises_velocity_limits(slot: Slot) -> None:
    param = slot.param
    assert param.hi is not None and param.hi_dim9 is not None
    dim9 = Context(dims=(9, 2, 2, 2))
    above = _fmt(param, Decimal(_fmt(param, param.hi)) + _step(param))
    assert invalid(slot.line(above)).number == 5
    assert parse(slot.line(above), dim9).values
    assert parse(slot.line(_fmt(param, param.hi_dim9)), dim9).values
    over9 = _fmt(param, Decimal(_fmt(param, param.hi_dim9)) + _step(param))
    assert invalid(slot.line(over9), dim9).number == 5


def test_dim_dependent_velocity() -> None:
    assert invalid("!vel 200.5").number == 5
    assert parse("!vel 200.5", Context(dims=(9, 2, 2, 2))).values == (200.5,)
    assert invalid("!vel 3000.5", Context(dims=(9, 2, 2, 2))).number == 5
    # The limit is per axis: Y is still in dim 2.
    assert invalid("!vel 10 200.5", Context(dims=(9, 2, 2, 2))).number == 5
    assert parse("!vel y 200.5", Context(dims=(2, 9, 2, 2))).values == (200.5,)
    assert invalid("!vel y 200.5", Context(dims=(9, 2, 2, 2))).number == 5


def test_precision_ranges() -> None:
    assert parse("?vel y 4").values == (4,)
    assert parse("?vel 16").values == (16,)
    assert invalid("?vel 17").number == 5
    assert invalid("?accel 11").number == 5
    assert parse("?accel x 10").values == (10,)


def test_value_holes() -> None:
    # !flash is ±0.00001 .. ±32500 ms (L9864-9876), ?snsv ±1 .. ±1024 (L15444), ?mrt
    # ±1 .. ±32767 (L11479).
    assert invalid("!flash 0").number == 5
    assert parse("!flash -0.01").values == (-0.01,)
    assert invalid("?snsv 0").number == 5
    assert parse("?snsv -2").values == (-2,)
    assert invalid("?mrt 0").number == 5
    assert parse("?mrt x -1").values == (-1,)


# ======================================================================================
# 5. Injection and framing


@pytest.mark.parametrize("char", ["\r", "\n", "\x03"])
@pytest.mark.parametrize("where", [0, 4, 7])
def test_control_characters_are_rejected(char: str, where: int) -> None:
    line = "!vel 10"
    bad = line[:where] + char + line[where:]
    with pytest.raises(InvalidCommandError):
        encode(bad)
    with pytest.raises(InvalidCommandError):
        parse(bad)


@pytest.mark.parametrize("line", ["!vel 10\r", "!vel 10\r\n", "!vel 1\r!moa 5", "?err\x03",
                                  "!vel\t10", "!vel 10\x00", "\x1b!vel 10"])
def test_framing_characters_never_pass(line: str) -> None:
    with pytest.raises(InvalidCommandError):
        encode(line)


def test_control_characters_in_build_values() -> None:
    with pytest.raises(InvalidCommandError):
        build("anain", "c\r!moa 10", 1, form="?")
    with pytest.raises(InvalidCommandError):
        build("vel", x="1\r")


@pytest.mark.parametrize("token", ["10\r!moa x 5", "10\x03", "10\n", "1\u0660", "10\x00"])
def test_a_command_built_by_hand_with_framing_characters_is_refused(token: str) -> None:
    # parse and build refuse these; a Command made without them is checked before writing.
    good = parse("!vel x 10")
    check_framing(good)
    bad = dataclasses.replace(good, tokens=(token,))
    with pytest.raises(InvalidCommandError, match="control or non-ASCII") as caught:
        check_framing(bad)
    assert caught.value.number == 4


@pytest.mark.parametrize(("blob", "count", "ok"), [
    (b"!trigp -1 1.0\r!trigp -1 2.0\r", 2, True),
    (b"!trigp -1 1.0\r!trigp -1 2.0\r", 1, False),  # one line more than entries
    (b"!trigp -1 1.0\r!trigp -1 2.0", 2, False),  # the last CR missing
    (b"!trigp -1 1.0\r!trigp -1 2.0\x03\r", 2, False),
    (b"!trigp -1 1.0\r!trigp -1 2.0\n\r", 2, False),
    (b"!trigp -1 1.0\r!trigp -1 2.0\xe9\r", 2, False),
])
def test_list_entries_as_bytes_are_checked_for_framing(blob: bytes, count: int,
                                                        ok: bool) -> None:
    template = parse("!trigp -1 1.0")
    if ok:
        check_rows_framing(template, blob, count)
        return
    with pytest.raises(InvalidCommandError, match="list line"):
        check_rows_framing(template, blob, count)


@pytest.mark.parametrize("line", ["go 10.1 –0.5 0", "!vel 1０", "!vél 10", "!vel 10 µ"])
def test_non_ascii_is_rejected(line: str) -> None:
    with pytest.raises(InvalidCommandError):
        encode(line)


def _long_moa(total: int) -> str:
    """A valid '!moa' line of ``total`` bytes including the CR."""
    head = "!moa 1."
    return head + "0" * (total - 1 - len(head))


def test_line_of_255_bytes_is_accepted() -> None:
    line = _long_moa(MAX_LINE_BYTES)
    data = encode(line)
    assert len(data) == MAX_LINE_BYTES == 255
    assert parse(line).values == (1.0,)


def test_line_of_256_bytes_is_rejected_with_code_3() -> None:
    error = invalid(_long_moa(MAX_LINE_BYTES + 1))
    assert error.number == 3
    with pytest.raises(InvalidCommandError):
        encode(_long_moa(MAX_LINE_BYTES + 1))


def test_realistic_long_lim_line() -> None:
    values = [f"-{i}23456789012.345678901234567890" for i in range(1, 9)]
    line = "!lim " + " ".join(values)
    assert len(line) + 1 > MAX_LINE_BYTES
    assert invalid(line).number == 3
    shorter = "!lim " + " ".join(v[:-14] for v in values)
    assert len(shorter) + 1 <= MAX_LINE_BYTES
    assert len(parse(shorter).values) == 8


def test_redundant_spaces_do_not_count() -> None:
    assert encode("!vel" + " " * 300 + "10") == b"!vel 10\r"


@pytest.mark.parametrize("token", ["nan", "NaN", "inf", "-inf", "Infinity", "1e-06", "1E2",
                                   "1e+3", "0x10", "1,5", "--1", "1.2.3", "+", "."])
def test_non_decimal_numbers_are_rejected(token: str) -> None:
    with pytest.raises(InvalidCommandError) as info:
        encode(f"!vel {token}")
    # A word where an axis letter may stand is a bad axis name (error 1).
    assert info.value.number == (1 if token.isalpha() else 5)
    with pytest.raises(InvalidCommandError) as info:
        encode(f"!vel x {token}")
    assert info.value.number == 5
    with pytest.raises(InvalidCommandError):
        encode(f"!moa y {token}")


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_build_rejects_non_finite(value: float) -> None:
    with pytest.raises(InvalidCommandError):
        build("vel", x=value)
    with pytest.raises(InvalidCommandError):
        build("moa", value)
    with pytest.raises(ValueError):
        format_number(value)


def test_format_number_examples() -> None:
    assert format_number(1e-06) == "0.000001"
    assert format_number(1e-7) == "0.0000001"
    assert format_number(10.0) == "10.0"
    assert format_number(10) == "10"
    assert format_number(-0.5) == "-0.5"
    assert format_number(1e22) == "10000000000000000000000.0"
    with pytest.raises(TypeError):
        format_number(True)


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_format_number_never_uses_exponents(value: float) -> None:
    text = format_number(value)
    assert "e" not in text.lower()
    assert re.fullmatch(r"-?\d+\.\d+", text), text
    assert float(text) == value
    line = f"!moa x {text}"
    if len(line) + 1 <= MAX_LINE_BYTES:
        assert parse(line).values == (value,)
    else:
        assert invalid(line).number == 3


@given(st.integers(min_value=-(10**30), max_value=10**30))
def test_format_number_of_ints(value: int) -> None:
    assert format_number(value) == str(value)
    assert int(format_number(value)) == value


# ======================================================================================
# 6. Grammar rules (manual chapter 2, notes §2)


def test_single_value_without_axis_goes_to_x() -> None:
    bare, explicit = parse("moa 10.2"), parse("moa x 10.2")
    assert bare.values == explicit.values == (10.2,)
    assert bare.axis is None and explicit.axis == "x"
    assert parse("!pos -0.1").values == (-0.1,)


def test_too_many_values_is_code_6() -> None:
    assert invalid("!vel 1 2 3 4 5").number == 6
    assert invalid("!vel x 1 2").number == 6
    assert invalid("?err 1").number == 6


def test_bad_axis_letter_is_code_1() -> None:
    assert invalid("!vel b 1").number == 1
    assert invalid("?pos q").number == 1


def test_unknown_instruction_is_code_4() -> None:
    assert invalid("!frobnicate 1").number == 4
    assert invalid("?").number == 4
    assert invalid("").number == 4
    assert invalid("!!vel 1").number == 4


def test_missing_prefix_is_code_7() -> None:
    assert invalid("vel 10").number == 7
    assert invalid("pos").number == 7


def test_bare_forms() -> None:
    assert parse("moa 1 2").executes
    assert parse("version").is_read
    assert parse("sa").is_read
    assert parse("cal").executes
    assert invalid("?moa 1").number == 4  # moa has no read form


def test_per_axis_only_set_forms() -> None:
    assert parse("!calvel x 10 0.5").values == (10.0, 0.5)
    assert invalid("!calvel 10 0.5").number == 1
    assert parse("!ctrff x 2 3.5").values == (2.0, 3.5)


def test_all_axes_group() -> None:
    command = parse("!swtyp 1 0 1")
    assert command.axis is None and command.values == (1, 0, 1)
    assert invalid("!swtyp 1 0").number == 6
    assert invalid("!swtyp 1 0 1 1 0 1").number == 6
    assert parse("!swtyp y 1 0 1").axis == "y"
    assert parse("!calbspeed 15").values == (15.0,)
    assert parse("!ctrd 100").values == (100,)
    assert parse("!encpos 1").values == (1,)


def test_brakepos_needs_an_axis() -> None:
    assert invalid("brakepos").number == 1
    assert invalid("!brakepos 1").number == 1
    assert parse("brakepos z -1").values == (-1,)


def test_case_is_canonicalised() -> None:
    command = parse("MOA Z 10")
    assert command.line == "moa z 10"
    assert encode("MOA Z 10") == b"moa z 10\r"
    assert parse("!AnaOut C 1 17.5").line == "!anaout c 1 17.5"
    assert parse("!TRIGA Y").values == ("y",)


def test_read_precision_vs_axis() -> None:
    command = parse("?vel y 4")
    assert command.axis == "y" and command.values == (4,)
    assert parse("?vel 6").axis is None
    assert invalid("?vel 17").number == 5


def test_words_where_the_grammar_has_no_axis() -> None:
    assert parse("!zwaxis z").values == ("z",)
    assert parse("anain c 3").values == ("c", 3)
    assert invalid("!tvrjoy y").number == 5


def test_trigger_position_lists() -> None:
    assert parse("!trigp -1 2.5").values == (-1, 2.5)
    assert parse("!trigp 0").values == (0,)
    assert parse("!trigp x 0").axis == "x"
    assert parse("!trigp y 11.5").values == (11.5,)
    assert parse("?trigp x 3").values == (3,)
    assert invalid("!trigp 1.5 2").number == 5


def test_optional_group_members() -> None:
    assert parse("!lim z 45.37").values == (45.37,)
    assert parse("!mrp x 0 0").values == (0, 0)
    assert parse("go").values == ()
    assert parse("go y").axis == "y"
    assert invalid("!vel").number == 6


# ======================================================================================
# 7. build()


def test_build_writes_ints_as_ints_and_floats_with_a_point() -> None:
    assert build("vel", x=10, y=5).line == "!vel 10 5"
    assert build("vel", x=10.0, y=5.5).line == "!vel 10.0 5.5"
    assert build("vel", x=10, y=5).values == (10.0, 5.0)


def test_build_single_axis() -> None:
    assert build("vel", y=5).line == "!vel y 5"
    assert build("vel", 5, axis="y").line == "!vel y 5"
    assert build("vel", x=5).line == "!vel 5"
    assert build("lim", z=(0, 315)).line == "!lim z 0 315"
    assert build("lim", x=(0, 10), y=[0.5, 20]).line == "!lim 0 10 0.5 20"


def test_build_rejects_gaps_and_conflicts() -> None:
    with pytest.raises(InvalidCommandError) as info:
        build("vel", x=1, z=2)
    assert info.value.number == 1
    with pytest.raises(InvalidCommandError):
        build("vel", y=1, axis="y")
    with pytest.raises(InvalidCommandError):
        build("vel", b=1)


def test_build_never_writes_exponents() -> None:
    command = build("moa", x=1e-7)
    assert command.line == "!moa 0.0000001"
    assert command.to_bytes() == b"!moa 0.0000001\r"
    assert build("vel", x=1e-06).line == "!vel 0.000001"
    assert build("pos", x=1e16, y=-2.5e-5).line == "!pos 10000000000000000.0 -0.000025"
    with pytest.raises(InvalidCommandError):
        build("vel", x="1e-06")


def test_build_lead_values_and_forms() -> None:
    assert build("trigp", -1, 2.5).line == "!trigp -1 2.5"
    assert build("pos", form="?").line == "?pos"
    assert build("pos", form=Form.READ, axis="z").line == "?pos z"
    assert build("moa", form="", x=1).line == "moa 1"
    assert build("version", 1, form="?").line == "?version 1"


def test_build_validates() -> None:
    with pytest.raises(InvalidCommandError):
        build("vel", x=float("nan"))
    with pytest.raises(InvalidCommandError) as info:
        build("vel", x=201)
    assert info.value.number == 5
    with pytest.raises(InvalidCommandError):
        build("nosuch")
    with pytest.raises(InvalidCommandError):
        build("joy", True)


# ======================================================================================
# 10. The catalog imports on its own


def test_catalog_imports_in_a_fresh_interpreter() -> None:
    result = subprocess.run(
        [sys.executable, "-c",
         "import tango_aio.catalog._instructions as i; print(len(i.INSTRUCTIONS))"],
        capture_output=True, text=True, check=True, cwd=ROOT, timeout=60,
    )
    assert result.stdout.strip() == "227"


def test_errors_are_value_errors() -> None:
    error = invalid("!vel 500")
    assert isinstance(error, ValueError) and isinstance(error, TangoError)
    assert error.instruction == "vel" and error.parameter == "velocity"
