"""The read-back that proves a set line (tango_aio.sansio._readback), synchronously: which read
each set gets, what its reply must hold, and that the emulator's own reading of the
manual agrees for every instruction the rule covers."""

from __future__ import annotations

import pickle
from decimal import Decimal

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tango_aio.catalog._encode import build
from tango_aio.catalog._instructions import (
    INSTRUCTIONS,
    AxisRule,
    Command,
    Context,
    Form,
    Kind,
    Param,
    parse,
)
from tango_aio.errors import SettingNotAppliedError, TangoError
from tango_aio.sansio._readback import NO_READ_BACK, ReadBack, mismatch, read_back
from tango_aio.sim.model import ControllerModel, SimConfig

CONTEXT = Context.of((2, 2, 2, 2), axes=3)


def _proof(line: str) -> ReadBack:
    proof = read_back(parse(line, CONTEXT), CONTEXT)
    assert proof is not None, line
    return proof


@pytest.mark.parametrize(("line", "read", "expected"), [
    ("!vel x 55.5", "?vel x", ("55.5",)),
    ("!vel 5 6", "?vel", ("5", "6")),
    ("!lim y 0 100", "?lim y", ("0", "100")),
    ("!delay 10", "?delay", ("10",)),
    ("!joyspeed 2 25", "?joyspeed 2", ("25",)),
    ("!triga y", "?triga", ("y",)),
    ("!trigr x 5 10 6", "?trigr", ("5", "10", "6")),
    ("!lock 2 1", "?lock 2", ("1",)),
    ("!lock 0101", "?lock", ("0101",)),
])
def test_each_set_gets_the_read_of_its_setting(line: str, read: str,
                                               expected: tuple[str, ...]) -> None:
    proof = _proof(line)
    assert (proof.read.line, proof.expected) == (read, expected)


def test_values_for_axes_the_controller_lacks_are_not_expected_back() -> None:
    proof = read_back(parse("!vel 1 2 3 4"), CONTEXT)  # checked against 4 axes
    assert proof is not None and proof.expected == ("1", "2", "3")


@pytest.mark.parametrize("line", [
    "!save", "!reset", "!moa x 1", "!cal", "!speed x 5", "!pos x 0", "!posclr",
    "!trigcount 0", "!baud 115200", "!autostatus 0", "!trigp -1 2.5", "!clim 5",
    "!a", "!zero",
])
def test_lines_no_read_proves_get_none(line: str) -> None:
    assert read_back(parse(line, CONTEXT), CONTEXT) is None


def test_every_instruction_left_out_has_a_reason_and_a_read_form() -> None:
    for name, reason in NO_READ_BACK.items():
        assert INSTRUCTIONS[name].allows(Form.READ), name
        assert "(L" in reason, name  # each cites the manual


@pytest.mark.parametrize(("line", "reply", "held"), [
    ("!vel x 55.5", ["55.500"], None),
    ("!vel x 55.4999", ["55.500"], None),  # equal at the digits printed
    ("!vel x 55.5", ["10.000"], "10.000"),  # the line was lost
    ("!vel x 55.5", ["55.502"], "55.502"),  # a value the controller changed
    ("!vel 5 6", ["5.000 6.000 10.000"], None),
    ("!vel 5 6", ["5.000 7.000 10.000"], "5.000 7.000 10.000"),
    ("!vel 5 6", ["5.000"], "5.000"),  # too short to show Y
    ("!ctrf x 3.7", ["4"], None),  # printed as an integer (L11904-11908)
    ("!lim x 0 10", ["0.0000,10.0000"], None),  # extmode 0's commas (L4559)
    ("!swtyp 1 0 1", ["1 0 11 0 11 0 1"], None),  # groups without a space
    ("!swtyp 1 0 1", ["1 0 11 0 11 1 1"], "1 0 11 0 11 1 1"),
    ("!swtyp y 1 0 1", ["1 0 1"], None),
    ("!triga y", ["Y"], None),
    ("!lock 0101", ["0101000000000000"], None),
    ("!lock 0101", ["0100000000000000"], "0100000000000000"),
    ("!trigs 90", ["80"], None),  # the documented 40 µs step (L12965-12967)
    ("!trigs 100", ["120"], None),
    ("!trigs 100", ["100"], None),  # a firmware that keeps the value as written
    ("!trigs 100", ["80"], "80"),
    ("!trigs 100 30 60", ["120"], None),  # OUT2's delay and width are not read (L13001)
    ("!trigs 100 30 60", ["80"], "80"),
    ("!trigf 2600", ["2500.00"], None),  # the true value: whole 40 µs periods (L13278)
    ("!trigf 2600", ["2777.78"], None),  # the tick count rounded down
    ("!trigf 2600", ["2600.00"], None),  # a firmware that keeps the value as written
    ("!trigf 2600", ["2272.73"], "2272.73"),  # two ticks off
    ("!trigf 0.01", ["0.01"], None),
    ("!trigcomp 15", ["20"], None),  # its 10 µs step (L13060)
    ("!trigcomp -15", ["-10"], None),
    ("!trigcomp 15", ["15"], None),
    ("!trigcomp 15", ["10"], "10"),
    ("!delay 10", ["ERROR 4,parameter"], "ERROR 4,parameter"),
])
def test_the_reply_is_compared_at_the_controller_s_precision(
        line: str, reply: list[str], held: str | None) -> None:
    assert mismatch(_proof(line), reply) == held


@given(st.decimals(min_value=-99, max_value=99, places=4, allow_nan=False),
       st.integers(min_value=0, max_value=4))
def test_a_float_matches_exactly_its_own_rounding(value: Decimal, digits: int) -> None:
    proof = _proof(f"!backlash x {value}")
    printed = f"{value:.{digits}f}"
    assert mismatch(proof, [printed]) is None
    # One printed step further from the value (a value halfway between two printed ones
    # matches both, as a controller may round either way).
    step = Decimal(1).scaleb(-digits)
    further = Decimal(printed) + (step if Decimal(printed) >= value else -step)
    assert mismatch(proof, [f"{further:.{digits}f}"]) is not None


def _sample(param: Param) -> float | int | str:
    """A valid value unlike the power-on ones (a lost line then shows)."""
    if param.kind is Kind.CHOICE:
        return param.choices[-1] if param.choices[-1] != 0 else param.choices[0]
    if param.kind is Kind.BITS:
        return "1"
    lo = param.lo if param.lo is not None else 0
    hi = param.hi if param.hi is not None else lo + 100
    if param.kind is Kind.INT:
        return int(lo + (hi - lo) // 3) or 1
    return round(lo + (hi - lo) / 7 + 0.123, 3)


def _samples() -> list[Command]:
    out = []
    for name, entry in INSTRUCTIONS.items():
        if Form.SET not in entry.forms or not entry.write:
            continue
        sig = entry.write[0]
        values = [_sample(p) for p in (*sig.lead, *sig.per_axis)]
        axis = "y" if sig.per_axis and sig.axis is not AxisRule.NONE else None
        try:
            out.append(build(name, *values, axis=axis, context=CONTEXT))
        except TangoError:
            continue  # (brakepos: needs its axis in another place)
    return out


def _answers(lines: list[str]) -> list[str]:
    out = bytearray()
    model = ControllerModel(out.extend, SimConfig(), now=0.0)
    for line in lines:
        model.handle_line(line.encode(), 0.0)
    return [line for line in out.decode().split("\r") if line]


def test_the_emulator_holds_what_every_proven_set_wrote() -> None:
    """The emulator (its own reading of the manual) answers each read-back with a reply
    that proves its set, and, without the set line, one that does not (where the value
    differs from the power-on one)."""
    proven = caught = 0
    for command in _samples():
        proof = read_back(command, CONTEXT)
        if proof is None:
            continue
        error, *reply = _answers([command.line, "?err", proof.read.line])
        if error != "0":
            continue  # refused (!trigc beyond the list): the error decides
        assert mismatch(proof, reply) is None, (command.line, reply)
        proven += 1
        lost = _answers([proof.read.line])
        if lost != reply:
            assert mismatch(proof, lost) is not None, (command.line, lost)
            caught += 1
    assert proven > 120 and caught > 110


def test_the_error_names_line_axis_and_both_values() -> None:
    error = SettingNotAppliedError("!vel x 55.5", instruction="vel", axis="x", sent="55.5",
                                   read="?vel x", held="10.000")
    text = str(error)
    assert "may not have been applied" in text
    assert all(part in text for part in ("'!vel x 55.5'", "vel X", "55.5", "'10.000'"))
    again = pickle.loads(pickle.dumps(error))
    assert (again.axis, again.sent, again.held, str(again)) == ("x", "55.5", "10.000", text)
    assert isinstance(error, TangoError)
