"""The switches for the variants of issue #32's table (the emulator side): each value
changes what the emulator sends as its documentation says.

The driver serves every value but local echo (``SwitchDoc.unsupported``), which it refuses
at connect; the others are in the firmware matrix. ``tests/e2e/test_firmware_probe.py``
checks that the probe recognises each.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tango_aio.sim.inprocess import configs_from_url
from tango_aio.sim.profiles import SWITCHES, Firmware, fingerprint_lacks, variants

from .test_model import Sim

pytestmark = pytest.mark.timeout(30)


def sim(**switches: str) -> Sim:
    return Sim(axes=2, firmware=Firmware().with_(**switches))


def test_every_unsupported_value_is_a_value_of_its_switch() -> None:
    # #32 item 4: the driver serves every value of the table but local echo,
    # which it refuses at connect (tests/e2e/test_field_variants.py).
    marked = {(name, value) for name, doc in SWITCHES.items() for value in doc.unsupported}
    assert marked == {("local_echo", "yes")}
    for name, value in marked:
        assert value in SWITCHES[name].values[1:]
    names = [name for name, _ in variants()]
    assert "local_echo=yes" not in names
    assert "local_echo=yes" in [name for name, _ in variants(unsupported=True)]
    for served in ("echo=completion", "echo_text=nobang", "ack_case=lower", "ack_case=title",
                   "save_ack=twice", "status_tail=no", "help_case=lower"):
        assert served in names


@pytest.mark.parametrize("echo", ["before", "completion"])
def test_echo_completion_sends_a_move_echo_with_its_report(echo: str) -> None:
    s = sim(echo=echo)
    s.send("!autostatus 4")
    out = s.send("!vel 20", "!moa 1")
    if echo == "before":
        assert out == ["!vel 20", "!moa 1"]
        assert out + s.settle() == ["!vel 20", "!moa 1", "@@--."]
    else:
        assert out == ["!vel 20"]  # the move's echo waits for its completion
        assert out + s.settle() == ["!vel 20", "!moa 1", "@@--."]
    # A refused move is echoed at once, a read is not echoed.
    assert s.send("!moa 99999") + s.settle() == ["!moa 99999"]
    assert s.send("?err") == ["5"]


def test_echo_nobang_drops_the_leading_bang() -> None:
    s = sim(echo_text="nobang")
    s.send("!autostatus 4")
    assert s.send("!VEL  20") == ["VEL  20"]
    assert s.send("!moa  1") + s.settle() == ["moa  1", "@@--."]


@pytest.mark.parametrize(("case", "ok", "err"), [
    ("upper", "OK...", "ERR 5"), ("lower", "ok...", "err 5"), ("title", "Ok...", "Err 5")])
def test_ack_case(case: str, ok: str, err: str) -> None:
    s = sim(ack_case=case)
    assert s.send("!autostatus 2") == [ok]
    assert s.send("!vel 20") == [ok]
    assert s.send("!vel -1") == [err]
    assert s.send("!moa 1") + s.settle() == [ok, "@@--."]
    assert s.send("?status") == ["OK..."]  # data replies keep the manual's case
    assert s.send("!save") == ["OK..."]


@pytest.mark.parametrize(("save_ack", "expected"), [("once", ["OK..."]),
                                                    ("twice", ["OK...", "OK..."])])
def test_save_ack(save_ack: str, expected: list[str]) -> None:
    s = sim(save_ack=save_ack)
    assert s.send("!save") == ["OK..."]  # mode 1: its own answer only
    s.send("!autostatus 2")
    assert s.send("!save") == expected


@pytest.mark.parametrize(("tail", "expected"), [("yes", "@@--.-"), ("no", "@@--")])
def test_status_tail(tail: str, expected: str) -> None:
    assert sim(status_tail=tail).ask("?statusaxis") == expected
    assert sim(status_tail=tail).ask("?statusaxis y") == "@"


@pytest.mark.parametrize(("case", "expected"), [("upper", "ERROR 5,number outside range"),
                                                ("lower", "error 5,number outside range")])
def test_help_case(case: str, expected: str) -> None:
    assert sim(help_case=case).ask("?help 5").lower() == expected.lower()
    assert sim(help_case=case).ask("?help 5") == expected


def test_local_echo_returns_every_byte_first() -> None:
    s = sim(local_echo="yes")
    assert s.send("?err") == ["?err", "0"]
    assert s.send("!vel x 10") == ["!vel x 10"]
    assert sim().send("!vel x 10") == []


def test_a_fingerprint_selects_switch_values(tmp_path: Path) -> None:
    path = tmp_path / "unit.json"
    path.write_text(json.dumps({"switches": {"echo": "after", "ack_case": "lower",
                                             "numbers": None}}), encoding="utf-8")
    firmware = Firmware.from_fingerprint(path)
    assert firmware.changed() == {"echo": "after", "ack_case": "lower"}
    config, _ = configs_from_url(f"sim://?fingerprint={path}&line_end=crlf")
    assert config.firmware.changed() == {"echo": "after", "ack_case": "lower",
                                         "line_end": "crlf"}


def test_the_emulator_lacks_what_a_fingerprint_lists_and_what_the_url_adds(
        tmp_path: Path) -> None:
    path = tmp_path / "unit.json"
    path.write_text(json.dumps({"switches": {}, "lacks": ["ctrt", "Lim"]}), encoding="utf-8")
    assert fingerprint_lacks(path) == {"ctrt", "lim"}
    config, _ = configs_from_url(f"sim://?fingerprint={path}&lacks=pause")
    assert config.lacks == {"ctrt", "lim", "pause"}
    s = Sim(axes=2, lacks=config.lacks)
    assert s.send("?ctrt", "?err", "?lim x", "?err", "?vel x") == ["4", "4", "10.000"]
    assert fingerprint_lacks({"switches": {}}) == frozenset()  # written before lacks


@pytest.mark.parametrize("lacks", ['"ctrt"', '[1]', '[""]'])
def test_a_fingerprint_whose_lacks_is_no_list_of_names_is_refused(tmp_path: Path,
                                                                   lacks: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(f'{{"switches": {{}}, "lacks": {lacks}}}', encoding="utf-8")
    with pytest.raises(ValueError, match="lacks"):
        configs_from_url(f"sim://?fingerprint={path}")


@pytest.mark.parametrize(("content", "message"), [
    ("[]", "no JSON object"), ("{}", "no 'switches'"), ("nope", "cannot read"),
    ('{"format": "other/1", "switches": {}}', "format 'other/1'"),
    ('{"switches": {"echo": "sideways"}}', "echo='sideways'"),
    ('{"switches": {"speedy": "yes"}}', "speedy")])
def test_a_bad_fingerprint_is_refused_in_words(tmp_path: Path, content: str,
                                               message: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(content, encoding="utf-8")
    with pytest.raises(ValueError, match=message):
        Firmware.from_fingerprint(path)
