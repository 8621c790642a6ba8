"""The probe's rules (sans-IO): what each switch value looks like in the lines, and that
lines come apart the same however the bytes are cut (issue #32)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tango_aio.fieldkit._decide import (
    Exchange,
    decide_ack_case,
    decide_ack_mode_change,
    decide_ack_reads,
    decide_echo_all,
    decide_echo_text,
    decide_err_number,
    decide_help_case,
    decide_help_number,
    decide_instruction_set,
    decide_lim_cr_bug,
    decide_local_echo,
    decide_mode_change_echo,
    decide_numbers,
    decide_save_ack,
    decide_service_end,
    decide_status,
    decide_version_format,
    decide_version_value,
    echo_form,
    exchange_end,
    normalized,
)
from tango_aio.fieldkit._rawlink import _Link

V = "TANGO-DT, Version 1.71, Jun  4 2019 , 12:00:00"


def ex(sent: str | list[str], got: list[str], err: int | None = None) -> Exchange:
    return Exchange([sent] if isinstance(sent, str) else sent, got, err)


def test_echo_forms() -> None:
    assert normalized("!MOA  1.50 +0.250") == "!moa 1.5 0.25"
    assert echo_form("!autostatus  4", "!autostatus  4") == "exact"
    assert echo_form("autostatus  4", "!autostatus  4") == "nobang"
    assert echo_form("!autostatus 4", "!autostatus  4") == "normalized"
    assert echo_form("?version", "!autostatus  4") is None


@pytest.mark.parametrize(("got", "value"), [
    (["!autostatus  4"], "exact"), (["autostatus  4"], "nobang"),
    (["!autostatus 4"], "normalized"), (["!AUTOSTATUS 4"], None), ([], None)])
def test_echo_text(got: list[str], value: str | None) -> None:
    obs = decide_echo_text(ex("!autostatus  4", got))
    assert obs.value == value and obs.unknown == (value is None)


def test_mode_change_echo() -> None:
    before = decide_mode_change_echo(ex("!autostatus 4", []),
                                     ex("!autostatus 1", ["!autostatus 1"]))
    assert before.value is None and before.candidates == ["before", "completion"]
    after = decide_mode_change_echo(ex("!autostatus 4", ["!autostatus 4"]),
                                    ex("!autostatus 1", []))
    assert after.value == "after"
    assert decide_mode_change_echo(ex("!autostatus 4", []), ex("!autostatus 1", [])).unknown


@pytest.mark.parametrize(("got", "value"), [
    ([V], "no"), (["?version", V], "yes"), ([V, "?version"], "yes"), ([V, V], None)])
def test_echo_all(got: list[str], value: str | None) -> None:
    assert decide_echo_all(ex("?version", got), V).value == value


@pytest.mark.parametrize(("got", "value"), [
    ([V], "no"), (["OK...", V], "before"), ([V, "ok..."], "after"), (["OK...", "OK...", V],
                                                                       None)])
def test_ack_reads(got: list[str], value: str | None) -> None:
    assert decide_ack_reads(ex("?version", got), V).value == value


@pytest.mark.parametrize(("oks", "value"), [
    (["OK..."], "upper"), (["ok..."], "lower"), (["Ok..."], "title"), (["OK!"], None),
    (["OK...", "ok..."], None)])
def test_ack_case(oks: list[str], value: str | None) -> None:
    obs = decide_ack_case([ex("!autostatus 2", [ok]) for ok in oks])
    assert obs.value == value and obs.unknown == (value is None)


def test_ack_mode_change() -> None:
    new = decide_ack_mode_change(ex("!autostatus 2", ["OK..."]), ex("!autostatus 1", []))
    old = decide_ack_mode_change(ex("!autostatus 2", []), ex("!autostatus 1", ["ERR"]))
    assert (new.value, old.value) == ("new", "old")
    assert decide_ack_mode_change(ex("!autostatus 2", ["OK..."]),
                                  ex("!autostatus 1", ["OK..."])).unknown


@pytest.mark.parametrize(("got", "value"), [
    (["ERR 5"], "yes"), (["err 5"], "yes"), (["ERR"], "no"), (["Err"], "no"),
    (["ERROR 5"], None), ([], None)])
def test_err_number(got: list[str], value: str | None) -> None:
    assert decide_err_number(ex("!vel x -1", got)).value == value


@pytest.mark.parametrize(("got", "value"), [
    (["OK..."], "once"), (["OK...", "ok..."], "twice"), ([], None), (["OK...", "ERR"], None)])
def test_save_ack(got: list[str], value: str | None) -> None:
    assert decide_save_ack(ex("!save", got)).value == value


def test_identity_and_replies() -> None:
    assert decide_version_format(ex("?version", [V]), V).value == "new"
    old = V.replace(" , ", ", ")
    assert decide_version_format(ex("?version", [old]), old).value == "old"
    assert decide_version_format(ex("?version", ["TANGO"]), "TANGO").unknown
    help5 = ex("?help 5", ["ERROR 5,number outside range"], 0)
    assert decide_instruction_set(ex("?version 1", ["1.71"], 0), help5, V).value == "full"
    assert decide_instruction_set(ex("?version 1", [], 4), ex("?help 5", [], 4), V).value \
        == "older"
    assert decide_instruction_set(ex("?version 1", [], 0), help5, V).unknown
    assert decide_help_number(ex("?help 5", ["ERROR 5,number outside range"], 0)).value \
        == "yes"
    assert decide_help_number(ex("?help 5", ["number outside range"], 0)).value == "no"
    assert decide_help_case(ex("help", ["ERROR 0,no error"], 0)).value == "upper"
    assert decide_help_case(ex("help", ["error 0,no error"], 0)).value == "lower"
    assert decide_help_case(ex("help", ["Error 0,No error"], 0)).unknown
    assert decide_service_end(ex("service", ["a", "END_SERVICE_PRINT."], 0)).value == "yes"
    assert decide_service_end(ex("service", ["a", ""], 0)).value == "no"
    assert decide_service_end(ex("service", [], 4)).value is None
    assert decide_local_echo(ex("?version", ["?version", V])).value == "yes"
    assert decide_local_echo(ex("?version", [V])).value == "no"


def test_lim_cr_bug() -> None:
    one, two = ex("?lim", ["a b c d e f"], 0), ex("?lim", ["a b,", "c d, e f"], 0)
    assert decide_lim_cr_bug(3, two, one).value == "extmode0"
    assert decide_lim_cr_bug(3, one, one).value == "none"
    assert decide_lim_cr_bug(3, two, two).value == "both"
    assert decide_lim_cr_bug(3, one, two).unknown
    assert decide_lim_cr_bug(3, two, None).value == "extmode0"
    assert decide_lim_cr_bug(1, one, None).value is None


@pytest.mark.parametrize(("line", "tail", "absent", "joystick"), [
    ("@@@-.-", "yes", "dash", "@"), ("JJJ-", "no", "dash", "J"), ("@@@.-", "yes", "omit", "@"),
    ("JJJ", "no", "omit", "J"), ("@M@-.-", "yes", "dash", None), ("@@@-.", "dot", "dash", "@"),
    ("JJJ.", "dot", "omit", "J")])
def test_status(line: str, tail: str, absent: str, joystick: str | None) -> None:
    found = decide_status(ex("?statusaxis", [line], 0), 3, 2)
    assert (found["status_tail"].value, found["absent_axes"].value,
            found["joystick_letter"].value) == (tail, absent, joystick)
    assert decide_status(ex("?statusaxis", [line], 0), 3, 0)["joystick_letter"].value is None


def test_status_of_no_known_shape_is_unknown() -> None:
    found = decide_status(ex("?statusaxis", ["@@.@"], 0), 3, 2)
    assert all(obs.unknown for obs in found.values())


def test_numbers() -> None:
    reads = [ex("?vel", ["10.000 10.000"], 0)]
    assert decide_numbers([ex("?vel", ["+10.000 +10.000"], 0)], None).value == "plus"
    assert decide_numbers(reads, None).value is None
    assert decide_numbers(reads, ex("?pos x", ["-0.0000"], 0)).value == "negzero"
    assert decide_numbers(reads, ex("?pos x", ["0.0000"], 0)).value == "plain"
    assert decide_numbers(reads, ex("?pos x", ["-0.0001"], 0)).unknown


@given(st.lists(st.sampled_from([b"1.0000 2.0000", b"OK...", b"", b"@@@-.", b"?pos"]),
                max_size=8),
       st.lists(st.integers(min_value=1, max_value=7), max_size=20),
       st.booleans())
def test_lines_are_the_same_however_the_bytes_are_cut(lines: list[bytes], cuts: list[int],
                                                      crlf: bool) -> None:
    link, whole = _Link(1.0), _Link(1.0)
    end = b"\r\n" if crlf else b"\r"
    data = b"".join(line + end for line in lines)
    whole._feed(data)
    position = 0
    for cut in cuts:
        link._feed(data[position:position + cut])
        position += cut
    link._feed(data[position:])
    assert link.inbox == whole.inbox == [line.decode() for line in lines]
    assert bool(link.lf_lines) == (crlf and len(lines) > 1)  # the LF opens the next line


def test_a_local_echo_is_taken_out_of_the_lines() -> None:
    link = _Link(1.0)
    link.local_echo = True
    link._echo_pending += b"?pos\r\x03\r"
    link._feed(b"?p")
    link._feed(b"os\r1.0\r\n\x03\r?pos\r")
    assert link.inbox == ["1.0", "?pos"]  # the second ?pos is the controller's (mode 4)
    assert link._echo_pending == b""


def test_version_1_answered_by_the_whole_line_and_the_instruction_set_it_leaves() -> None:
    # 1.71: the number only (L1057-1059, L1107); the older edition's version takes no
    # value (old L416-418): refused with error 4, or the value ignored.
    whole = ex("?version 1", [V], 0)
    assert decide_version_value(ex("?version 1", ["1.71"], 0), V).value == "number"
    assert decide_version_value(whole, V).value == "line"
    moot = decide_version_value(ex("?version 1", [], 4), V)
    assert moot.value is None and not moot.unknown and moot.note.startswith("moot")
    assert decide_version_value(ex("?version 1", ["1.71", V], 0), V).unknown
    # The whole line leaves the instruction set to ?help 5, whose value the older
    # edition's help does not take either (old L805-811).
    older = decide_instruction_set(whole, ex("?help 5", [], 4), V)
    assert older.value == "older" and "-> ?help 5" in older.lines
    full = decide_instruction_set(whole, ex("?help 5", ["ERROR 5,number outside range"], 0),
                                  V)
    assert full.value == "full"
    assert decide_instruction_set(whole, ex("?help 5", [], 0), V).unknown


@pytest.mark.parametrize(("got", "end"), [
    (["2", "0", V], (2, 1)),           # a read, ?err, ?version
    (["4", V], (1, 0)),                # refused: nothing, error 4
    ([V, "0", V], (2, 1)),             # ?version 1 answered with the whole line
    ([V], None), ([V, "0"], None),     # not there yet
    (["0", "@@@-.", V], (2, 0)),       # a report between ?err and ?version
    (["1.71", V], None),               # no number before the ?version line
])
def test_a_mode_1_exchange_ends_at_the_version_line_after_the_err_number(
        got: list[str], end: tuple[int, int] | None) -> None:
    assert exchange_end(got, V) == end
