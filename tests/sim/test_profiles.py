"""Firmware profiles and switches (issue #12): their definitions, how they are selected,
and that each value of each switch really changes what the emulator sends.

Behaviour tests run sans-IO in virtual time (the ``Sim`` harness of ``test_model``).
Every switch is tested with each of its values, and a common session runs under every
firmware of :func:`~tango_aio.sim.profiles.variants` against an oracle written here from
the switch documentation (not from the emulator's code).
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import random
from pathlib import Path

import pytest

from tango_aio.catalog._instructions import INSTRUCTIONS, ModeEffect
from tango_aio.sim.inprocess import configs_from_url
from tango_aio.sim.model import SimConfig
from tango_aio.sim.profiles import PROFILES, SWITCHES, Firmware, switch_table, variants

from .test_model import Sim

pytestmark = pytest.mark.timeout(60)

ROOT = Path(__file__).resolve().parents[2]
VARIANTS = variants()
VARIANT_IDS = [name for name, _ in VARIANTS]


def sim(axes: int = 3, **switches: str) -> Sim:
    """A controller under ``manual`` with ``switches`` on top."""
    return Sim(axes=axes, firmware=Firmware().with_(**switches))


def values_of(name: str) -> list[str]:
    return list(SWITCHES[name].values)


# ---------------------------------------------------------------------------------------
# The emulator is an independent reading: it imports nothing of the driver


DRIVER_MODULES = {"sansio", "moves", "transports", "link", "families", "controller", "group"}


@functools.cache  # each file once: the scan reaches most modules from every start
def _imports(path: Path, package: str) -> list[str]:
    """Dotted names of the tango_aio modules one file imports (absolute or relative);
    ``package`` is the file's package (``tango_aio.sim``)."""
    names: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parent, *([base] if base else [])])
            names += [base] + [f"{base}.{alias.name}" for alias in node.names]
    return [name for name in names if name.split(".")[0] == "tango_aio"]


def _module_file(name: str) -> Path | None:
    """The source file of a tango_aio module (``None`` for a name that is no module)."""
    path = ROOT.joinpath(*name.split("."))
    if path.with_suffix(".py").is_file():
        return path.with_suffix(".py")
    return None


def _driver_imports(path: Path, package: str = "tango_aio.sim") -> list[str]:
    """Driver modules that ``path`` imports, directly or through other tango_aio modules
    (the package ``__init__`` files aside: importing any submodule runs those)."""
    found, seen = [], set()
    todo = [(path, package, path.name)]
    while todo:
        file, pkg, chain = todo.pop()
        for name in _imports(file, pkg):
            parts = name.split(".")
            if len(parts) > 1 and parts[1] in DRIVER_MODULES:
                found.append(f"{chain}: tango_aio.{parts[1]}")
                continue
            target = _module_file(name)
            if target is not None and target not in seen:
                seen.add(target)
                todo.append((target, ".".join(parts[:-1]), f"{chain} -> {name}"))
    return sorted(set(found))


def test_the_emulator_imports_nothing_of_the_driver() -> None:
    files = sorted((ROOT / "tango_aio" / "sim").glob("*.py"))
    assert len(files) >= 10
    assert [hit for path in files for hit in _driver_imports(path)] == []


def test_the_import_scan_finds_driver_imports(tmp_path: Path) -> None:
    sample = tmp_path / "sample.py"
    sample.write_text("from ..sansio import expectation\nimport tango_aio.link._protocol\n"
                      "from tango_aio import controller\nfrom ..sansio import _patterns\n"
                      "from ..catalog import parse\n", encoding="utf-8")
    assert _driver_imports(sample) == [
        "sample.py: tango_aio.controller", "sample.py: tango_aio.link",
        "sample.py: tango_aio.sansio"]


def test_the_import_scan_follows_imports_through_other_modules(tmp_path: Path) -> None:
    sample = tmp_path / "sample.py"
    sample.write_text("from ..testing import tango_emulator\n", encoding="utf-8")
    hits = _driver_imports(sample)
    assert hits and all(hit.startswith("sample.py -> tango_aio.testing") for hit in hits)


# ---------------------------------------------------------------------------------------
# Definitions


def test_every_switch_is_a_documented_firmware_field() -> None:
    fields = {f.name: f.default for f in dataclasses.fields(Firmware)}
    assert list(fields) == list(SWITCHES)
    for name, doc in SWITCHES.items():
        assert doc.name == name
        assert len(doc.values) >= 2 and len(set(doc.values)) == len(doc.values)
        assert fields[name] == doc.default == getattr(PROFILES["manual"], name)
        assert "L" in doc.lines and doc.effect


def test_the_legacy_profile_is_the_older_edition() -> None:
    assert PROFILES["legacy"].changed() == {
        "echo_all": "yes", "abort_letter": "@", "abort_report": "yes", "help_number": "no",
        "service_end": "no", "version_format": "old", "instruction_set": "older"}
    assert PROFILES["manual"].changed() == {}


def test_from_options_puts_switches_on_a_profile() -> None:
    firmware = Firmware.from_options("legacy", echo="after", numbers="plus")
    assert firmware.echo == "after" and firmware.numbers == "plus"
    assert firmware.abort_letter == "@"
    assert Firmware.from_options() == Firmware()
    assert firmware.with_(echo="before") == PROFILES["legacy"].with_(numbers="plus")


@pytest.mark.parametrize(("options", "message"), [
    ({"profile": "newest"}, "profile 'newest'; allowed: manual, legacy"),
    ({"echo": "sideways"}, "echo='sideways' is not allowed; allowed: before, after"),
    ({"colour": "red"}, "unknown firmware switch 'colour'"),
])
def test_bad_options_name_the_option_and_the_allowed_values(
        options: dict[str, str], message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        Firmware.from_options(**options)


def test_the_constructor_checks_values_too() -> None:
    with pytest.raises(ValueError, match="line_end='lf'"):
        Firmware(line_end="lf")


def test_variants_are_manual_legacy_and_each_single_switch_value() -> None:
    names = [name for name, _ in VARIANTS]
    assert names[:2] == ["manual", "legacy"]
    assert len(set(names)) == len(names)
    singles = VARIANTS[2:]
    assert len(singles) == sum(len(set(doc.values[1:]) - set(doc.unsupported))
                               for doc in SWITCHES.values())
    for name, firmware in singles:
        switch, value = name.split("=")
        assert firmware.changed() == {switch: value}
        assert value not in SWITCHES[switch].unsupported
    every = variants(unsupported=True)[2:]
    assert len(every) == sum(len(doc.values) - 1 for doc in SWITCHES.values())


def test_sim_urls_select_a_profile_and_switches() -> None:
    sim_config, _ = configs_from_url("sim://?profile=legacy&echo=after&abort_letter=E&axes=2")
    assert sim_config.firmware == PROFILES["legacy"].with_(echo="after", abort_letter="E")
    assert sim_config.axes == 2
    assert configs_from_url("sim://?baud=0")[0].firmware == Firmware()
    assert configs_from_url("sim://?firmware=1.69")[0].version == "1.69"


@pytest.mark.parametrize(("query", "named"), [
    ("profile=nope", "profile"), ("echo=sideways", "echo"), ("speedy=1", "speedy"),
    ("move_during_move=later", "move_during_move")])
def test_sim_urls_reject_unknown_names_and_values(query: str, named: str) -> None:
    with pytest.raises(ValueError, match=named):
        configs_from_url(f"sim://?{query}")


def test_the_version_number_is_separate_from_the_firmware_behaviour() -> None:
    config = SimConfig(version="1.69")
    assert (config.version, config.firmware) == ("1.69", Firmware())
    assert Sim(version="1.69").ask("?version 1") == "1.69"


def test_the_docs_table_lists_every_switch() -> None:
    page = (ROOT / "docs" / "concepts" / "firmware-profiles.md").read_text(encoding="utf-8")
    assert switch_table() in page, "regenerate: python -c 'from tango_aio.sim.profiles " \
        "import switch_table; print(switch_table())'"


def test_the_docs_page_names_every_switch() -> None:
    page = (ROOT / "docs" / "concepts" / "firmware-profiles.md").read_text(encoding="utf-8")
    for name in SWITCHES:
        assert f"`{name}`" in page, name


# ---------------------------------------------------------------------------------------
# The catalog's mode facts agree with what the emulator does


@pytest.mark.parametrize("line, mode_after", [
    ("!autostatus 0", 0), ("!autostatus 3", 3), ("reset", 1), ("restore -1", 1),
    ("restore", 4), ("?autostatus", 4), ("!vel 3", 4)])
def test_the_catalog_mode_effect_is_what_the_emulator_does(line: str, mode_after: int) -> None:
    s = sim()
    s.send("!autostatus 4")
    s.send(line)
    s.settle(3.0)
    assert s.model.autostatus == mode_after
    entry = INSTRUCTIONS[line.lstrip("!?").split()[0]]
    values = line.split()[1:]
    effect = entry.mode_effect
    if effect is ModeEffect.VALUE and line.startswith("!"):
        assert mode_after == int(values[0])
    elif effect is ModeEffect.RESTART or (effect is ModeEffect.RESTART_IF_MINUS_ONE
                                          and values == ["-1"]):
        assert mode_after == 1
    else:
        assert mode_after == 4


def test_only_the_mode_setters_have_a_mode_effect() -> None:
    assert {n for n, e in INSTRUCTIONS.items() if e.mode_effect is not ModeEffect.NONE} == \
        {"autostatus", "reset", "restore"}


# ---------------------------------------------------------------------------------------
# Mode 4


@pytest.mark.parametrize("echo", values_of("echo"))
def test_echo_decides_which_mode_changes_are_echoed(echo: str) -> None:
    s = sim(echo=echo)
    into = s.send("!autostatus 4")
    out = s.send("!vel 3", "!autostatus 1")
    if echo in ("before", "completion"):  # echoed under the mode in force on arrival
        assert into == [] and out == ["!vel 3", "!autostatus 1"]
    else:  # echoed under the mode in force after it ran
        assert into == ["!autostatus 4"] and out == ["!vel 3"]


def test_echo_after_follows_the_lines_own_reply() -> None:
    s = sim(echo="after", echo_all="yes")
    s.send("!autostatus 4")
    assert s.send("?vel x") == ["10.000", "?vel x"]
    s = sim(echo_all="yes")
    s.send("!autostatus 4")
    assert s.send("?vel x") == ["?vel x", "10.000"]


@pytest.mark.parametrize("echo_report", values_of("echo_report"))
def test_echo_report_decides_whether_a_move_reports_in_mode_4(echo_report: str) -> None:
    s = sim(echo_report=echo_report)
    s.send("!autostatus 4")
    lines = s.send("!moa 1") + s.settle()
    assert lines == (["!moa 1", "@@@-."] if echo_report == "yes" else ["!moa 1"])


@pytest.mark.parametrize("echo_all", values_of("echo_all"))
def test_echo_all_echoes_reads_and_bare_lines(echo_all: str) -> None:
    s = sim(echo_all=echo_all)
    s.send("!autostatus 4")
    lines = s.send("?vel x", "?err", "vel 3", "?nosuchthing")
    if echo_all == "yes":
        assert lines == ["?vel x", "10.000", "?err", "0", "vel 3", "?nosuchthing"]
    else:
        assert lines == ["10.000", "0"]
    # An executing bare line is a move line: echoed either way.
    assert s.send("moa 1") + s.settle() == ["moa 1", "@@@-."]


@pytest.mark.parametrize("echo_text", values_of("echo_text"))
def test_echo_text_exact_or_normalized(echo_text: str) -> None:
    s = sim(echo_text=echo_text)
    s.send("!autostatus 4")
    lines = s.send("!MOA  1.50 +0.250") + s.settle()
    echo = {"exact": "!MOA  1.50 +0.250", "normalized": "!moa 1.5 0.25",
            "nobang": "MOA  1.50 +0.250"}[echo_text]
    assert lines == [echo, "@@@-."]


# ---------------------------------------------------------------------------------------
# Mode 2


@pytest.mark.parametrize("ack_reads", values_of("ack_reads"))
def test_ack_reads(ack_reads: str) -> None:
    s = sim(ack_reads=ack_reads)
    s.send("!autostatus 2")
    good, bad = s.send("?vel x"), s.send("?trigp 99")
    expected = {"no": (["10.000"], ["0"]),
                "before": (["OK...", "10.000"], ["ERR 5", "0"]),
                "after": (["10.000", "OK..."], ["0", "ERR 5"])}[ack_reads]
    assert (good, bad) == expected
    assert s.send("!vel 3") == ["OK..."]


@pytest.mark.parametrize("err_number", values_of("err_number"))
def test_err_number(err_number: str) -> None:
    s = sim(err_number=err_number)
    s.send("!autostatus 2")
    refused = "ERR 5" if err_number == "yes" else "ERR"
    assert s.send("!vel -10", "!nosuchthing", "!vel 3") == [
        refused, "ERR 4" if err_number == "yes" else "ERR", "OK..."]
    assert s.ask("?err") == "0"


@pytest.mark.parametrize("ack_mode_change", values_of("ack_mode_change"))
def test_ack_mode_change(ack_mode_change: str) -> None:
    s = sim(ack_mode_change=ack_mode_change)
    into, out = s.send("!autostatus 2"), s.send("!autostatus 1")
    if ack_mode_change == "new":
        assert (into, out) == (["OK..."], [])
    else:
        assert (into, out) == ([], ["OK..."])


@pytest.mark.parametrize("move_ok", values_of("move_ok"))
def test_move_ok(move_ok: str) -> None:
    s = sim(move_ok=move_ok)
    s.send("!autostatus 2")
    at_once = s.send("!moa 2", "?err")
    later = s.settle()
    if move_ok == "immediate":
        assert (at_once, later) == (["OK...", "0"], ["@@@-."])
    else:
        assert (at_once, later) == (["0"], ["OK...", "@@@-."])
    # A refused move is refused at once either way; bare moves never get an OK.
    assert s.send("!moa 99999") == ["ERR 5"]
    assert s.send("moa 0") + s.settle() == ["@@@-."]


# ---------------------------------------------------------------------------------------
# Moves


@pytest.mark.parametrize("mode", [1, 2])
@pytest.mark.parametrize("report", values_of("refused_move_report"))
def test_refused_move_report(report: str, mode: int) -> None:
    s = sim(refused_move_report=report)
    s.send(f"!autostatus {mode}", "!lim y -5 5")
    lines = s.send("!moa 1 20") + s.settle()
    ack = ["ERR 5"] if mode == 2 else []
    assert lines == ack + (["EE@-."] if report == "yes" else [])
    assert s.ask("?err") == "5"
    assert s.ask("?pos") == "0.0000 0.0000 0.0000"  # nothing moved


@pytest.mark.parametrize("policy", values_of("move_during_move"))
def test_move_during_move(policy: str) -> None:
    s = sim(move_during_move=policy)
    s.send("!moa 5")
    s.now += 0.1
    assert s.send("!mor 1", "?err") == (["2"] if policy == "refuse" else ["0"])
    reports = s.settle()
    final = s.ask("?pos x")
    if policy == "refuse":
        assert (reports, final) == (["@@@-."], "5.0000")
    elif policy == "queue":  # each move reports; the relative one from where the first ended
        assert (reports, final) == (["@@@-.", "@@@-."], "6.0000")
    else:  # the first move's target is replaced: one report, at the new target
        assert (reports, final) == (["@@@-."], "6.0000")


def test_retarget_turns_a_moving_axis_around() -> None:
    s = sim(move_during_move="retarget")
    s.send("!moa 5")
    s.now += 0.3
    assert s.send("!moa 0", "?err") == ["0"]
    assert s.settle() == ["@@@-."]
    assert s.ask("?pos x") == "0.0000"


def test_queued_moves_are_cancelled_by_an_abort() -> None:
    s = sim(move_during_move="queue")
    s.send("!moa 5", "!moa 1")
    s.now += 0.1
    assert s.send("a") + s.settle() == ["E@@-.", "E@@-."]
    assert s.ask("sa") == "E@@-.-"


@pytest.mark.parametrize("zero", values_of("zero_move_report"))
def test_zero_move_report(zero: str) -> None:
    s = sim(zero_move_report=zero)
    lines = s.send("!moa 0 0") + s.settle()
    assert lines == (["@@@-."] if zero == "yes" else [])
    s.send("!autostatus 2")
    lines = s.send("!mor 0") + s.settle()
    assert lines == (["OK...", "@@@-."] if zero == "yes" else ["OK..."])


@pytest.mark.parametrize("policy", values_of("disable_during_move"))
@pytest.mark.parametrize("state", ["0", "-1"])
def test_disable_during_move(policy: str, state: str) -> None:
    s = sim(disable_during_move=policy)
    s.send("!moa 5")
    s.now += 0.1
    assert s.ask("sa").startswith("M")
    lines = s.send(f"!axis x {state}")
    assert s.ask("?err") == ("2" if policy == "refuse" else "0")
    assert s.ask("?axis x") == ("1" if policy == "refuse" else state)
    lines += s.settle()
    x = float(s.ask("?pos").split()[0])
    if policy == "stop":
        assert 0.0 < x < 5.0
        assert lines == ["E@@-."]  # stopped as by 'a x'
    else:
        assert x == pytest.approx(5.0)
        assert lines == ["@@@-."]
    # An axis at rest is disabled under every policy.
    s.send("!axis y 0")
    assert s.ask("?err") == "0" and s.ask("?axis y") == "0"


def test_move_ok_at_completion_without_a_report_still_acknowledges() -> None:
    s = sim(move_ok="completion", zero_move_report="no")
    s.send("!autostatus 2")
    assert s.send("!moa 0") + s.settle() == ["OK..."]


# ---------------------------------------------------------------------------------------
# Reports and status


@pytest.mark.parametrize("axes", [1, 2, 4])
@pytest.mark.parametrize("width", values_of("report_width"))
def test_report_width(width: str, axes: int) -> None:
    s = sim(axes=axes, report_width=width)
    lines = s.send("!moa 1") + s.settle()
    letters = "@" * axes
    assert lines == [(letters + "-" * (4 - axes) if width == "four" else letters) + "."]


@pytest.mark.parametrize("absent", values_of("absent_axes"))
def test_absent_axes(absent: str) -> None:
    s = sim(axes=2, absent_axes=absent)
    assert s.ask("sa") == ("@@--.-" if absent == "dash" else "@@.-")
    s.send("!axis y 0")
    assert s.ask("?statusaxis") == ("@---.-" if absent == "dash" else "@.-")
    # One absent axis asked for by name answers '-' in every profile (L2711, L2721).
    assert s.ask("?statusaxis z") == "-"
    assert s.ask("?err") == "0"


@pytest.mark.parametrize("letter", values_of("abort_letter"))
def test_abort_letter(letter: str) -> None:
    s = sim(abort_letter=letter)
    s.send("!moa 5 5")
    s.now += 0.2
    assert s.send("a") + s.settle() == [f"{letter}{letter}@-."]
    assert s.ask("sa") == f"{letter}{letter}@-.-"
    s.send("!moa 1")
    s.now += 0.05
    s.write(b"\x03")
    assert s.settle() == [f"{letter}@@-."]  # the report of the move Ctrl+C stopped


@pytest.mark.parametrize("report", values_of("abort_report"))
def test_abort_report(report: str) -> None:
    s = sim(abort_report=report)
    s.send("!moa 5")
    s.now += 0.2
    lines = s.send("a") + s.settle()
    assert lines == (["E@@-.", "E@@-."] if report == "yes" else ["E@@-."])
    # 'a' with nothing moving: a report of its own only when 'a' is answered like a move.
    assert s.send("a") + s.settle() == (["E@@-."] if report == "yes" else [])


@pytest.mark.parametrize("ctrl_c", values_of("ctrl_c"))
def test_ctrl_c(ctrl_c: str) -> None:
    s = sim(ctrl_c=ctrl_c)
    s.send("!moa 5")
    s.now += 0.2
    s.write(b"\x03")
    lines = s.settle()
    if ctrl_c == "ignore":  # 0x03 waits in the parser's line; the move runs on
        assert lines == ["@@@-."]
        assert s.send("") == []  # the line '\x03' is no instruction
        assert s.ask("?err") != "0"
        assert s.ask("?pos x") == "5.0000"
    else:
        assert lines == (["E@@-.", "E@@-."] if ctrl_c == "stop_report" else ["E@@-."])
        assert float(s.ask("?pos x")) < 5.0
        assert s.wire.ctrl_c_count == 1


# ---------------------------------------------------------------------------------------
# Firmware replies


@pytest.mark.parametrize("help_number", values_of("help_number"))
def test_help_number(help_number: str) -> None:
    s = sim(help_number=help_number)
    assert s.ask("?help 5") == ("ERROR 5,number outside range" if help_number == "yes"
                                else "number outside range")
    assert s.ask("?help") == "ERROR 0,no error"


@pytest.mark.parametrize("end", values_of("service_end"))
def test_service_end(end: str) -> None:
    lines = sim(service_end=end).send("service")
    assert (lines[-1] == "END_SERVICE_PRINT.") is (end == "yes")
    assert lines[0].endswith("service print")


@pytest.mark.parametrize("extmode", [0, 1])
@pytest.mark.parametrize("bug", values_of("lim_cr_bug"))
def test_lim_cr_bug(bug: str, extmode: int) -> None:
    s = sim(axes=2, lim_cr_bug=bug)
    s.send(f"!extmode {extmode}", "!lim -1 1 -2 2")
    split = bug == "both" or (bug == "extmode0" and extmode == 0)
    expected = ["-1.0000 1.0000,", "-2.0000 2.0000"] if split else \
        ["-1.0000 1.0000 -2.0000 2.0000"]
    assert s.send("?lim") == expected
    assert s.send("?lim y") == ["-2.0000 2.0000"]


@pytest.mark.parametrize("version_format", values_of("version_format"))
def test_version_format(version_format: str) -> None:
    s = sim(version_format=version_format)
    assert s.ask("?version") == ("TANGO-DT, Version 1.71, Jun  4 2019 , 12:00:00"
                                 if version_format == "new" else
                                 "TANGO-DT, Version 1.71, Jun  4 2019, 12:00:00")


@pytest.mark.parametrize("line_end", values_of("line_end"))
def test_line_end(line_end: str) -> None:
    s = sim(line_end=line_end)
    s.write(b"?vel x\r!moa 1\r")
    data = s.wire.poll(s.now + 5.0)
    end = b"\r" if line_end == "cr" else b"\r\n"
    assert data == b"10.000" + end + b"@@@-." + end


@pytest.mark.parametrize("numbers", values_of("numbers"))
def test_numbers(numbers: str) -> None:
    s = sim(numbers=numbers)
    s.send("!pos -0.00001 2")
    pos = {"plain": "0.0000 2.0000 0.0000", "plus": "0.0000 +2.0000 0.0000",
           "negzero": "-0.0000 2.0000 0.0000"}[numbers]
    assert s.ask("?pos") == pos
    assert s.ask("?version") == "TANGO-DT, Version 1.71, Jun  4 2019 , 12:00:00"
    assert s.ask("?err") == "0"


@pytest.mark.parametrize("instruction_set", values_of("instruction_set"))
def test_instruction_set(instruction_set: str) -> None:
    s = sim(instruction_set=instruction_set)
    full = instruction_set == "full"
    replies = s.send("?extmode", "?err", "?help 5", "?err", "?version 1", "?err", "?vel x",
                     "?err")
    assert replies == (["0", "0", "ERROR 5,number outside range", "0", "1.71", "0",
                        "10.000", "0"] if full else ["4", "4", "4", "10.000", "0"])


@pytest.mark.parametrize("instruction_set", values_of("instruction_set"))
@pytest.mark.parametrize("version_value", values_of("version_value"))
def test_version_value(version_value: str, instruction_set: str) -> None:
    s = sim(version_value=version_value, instruction_set=instruction_set)
    line = "TANGO-DT, Version 1.71, Jun  4 2019 , 12:00:00"
    if version_value == "line":  # the value ignored, in either instruction set
        version = [line, "0"]
    elif instruction_set == "full":  # the number only (L1057-1059, L1107)
        version = ["1.71", "0"]
    else:  # the older edition's version takes no value (old L416-418)
        version = ["4"]
    assert s.send("?version 1", "?err") == version
    # help's value is the instruction set's business alone (old L805-811)
    assert s.send("?help 5", "?err") == (["ERROR 5,number outside range", "0"]
                                         if instruction_set == "full" else ["4"])


# ---------------------------------------------------------------------------------------
# Every variant: one common session against an oracle written from the switch docs


def _report(firmware: Firmware, letters: str, axes: int) -> str:
    letters = letters.replace("@", firmware.joystick_letter)  # the joystick is on
    if firmware.report_width == "axes":
        letters = letters[:axes]
    return letters + "."


def _number(firmware: Firmware, text: str) -> str:
    return "+" + text if firmware.numbers == "plus" and float(text) > 0 else text


def _status(firmware: Firmware, letters: str) -> str:
    letters = letters.replace("@", firmware.joystick_letter)
    if firmware.absent_axes == "omit":
        letters = letters.replace("-", "")
    return letters + {"yes": ".-", "no": "", "dot": "."}[firmware.status_tail]


def _ack(firmware: Firmware, text: str) -> str:
    """A mode-2 acknowledgement in the case of switch ``ack_case``."""
    return {"upper": text, "lower": text.lower(), "title": text.capitalize()}[
        firmware.ack_case]


@pytest.mark.parametrize("firmware", [f for _, f in VARIANTS], ids=VARIANT_IDS)
def test_a_common_session_under_every_variant(firmware: Firmware) -> None:
    s = Sim(axes=2, firmware=firmware)
    crlf = firmware.line_end == "crlf"

    def lines(out: list[str]) -> list[str]:
        return [line.lstrip("\n") for line in out] if crlf else out

    # Mode 1: a set line answers nothing, a read its value, a move one report.
    assert lines(s.send("!vel 20 20")) == []
    assert lines(s.send("?vel y")) == [_number(firmware, "20.000")]
    assert lines(s.send("!moa 2 -1") + s.settle()) == [_report(firmware, "@@--", 2)]
    assert lines(s.send("?pos")) == [f"{_number(firmware, '2.0000')} -1.0000"]
    assert lines(s.send("sa")) == [_status(firmware, "@@--")]
    # Mode 0: nothing but data; polled to the end.
    s.send("!autostatus 0")
    assert lines(s.send("!mor y 1.5") + s.settle()) == []
    assert lines(s.send("?pos y", "?err")) == [_number(firmware, "0.5000"), "0"]
    # Mode 2: set lines acknowledged, errors numbered per err_number.
    ok = _ack(firmware, "OK...")
    ack = lines(s.send("!autostatus 2"))
    assert ack == ([ok] if firmware.ack_mode_change == "new" else [])
    refused = _ack(firmware, "ERR 5" if firmware.err_number == "yes" else "ERR")
    assert lines(s.send("!vel -1")) == [refused]
    moved = lines(s.send("!moa 0 0") + s.settle())
    assert moved == [ok, _report(firmware, "@@--", 2)]
    assert lines(s.send("?pos")) == (["0.0000 0.0000"] if firmware.ack_reads == "no" else
                                     [ok, "0.0000 0.0000"] if firmware.ack_reads == "before"
                                     else ["0.0000 0.0000", ok])
    left = lines(s.send("!autostatus 1"))
    assert left == ([] if firmware.ack_mode_change == "new" else [ok])
    assert s.model.internal_errors == []


RANDOM_LINES = (
    "!moa 1 2", "!mor 0.5", "m", "!moa 0", "a", "a x", "!autostatus 0", "!autostatus 1",
    "!autostatus 2", "!autostatus 3", "!autostatus 4", "?pos", "sa", "?err", "!joy 0",
    "!joy 2", "!delay 100", "!pause 50", "!delay 0", "!pause 0", "!cal", "!rm y",
    "!moa 99999", "!go 3", "!speed 1", "!speed 0", "!lim x -3 3", "?lim", "?help 5",
    "service", "!vel -1", "!moa y 1", "!encmask 1", "!ctrd x 100", "\x03", "?version",
    "!mor 0", "!moc", "!axis y 0", "!axis y 1")


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("firmware", [f for _, f in VARIANTS], ids=VARIANT_IDS)
def test_random_sessions_never_break_the_emulator(firmware: Firmware, seed: int) -> None:
    rng = random.Random(seed)
    s = Sim(axes=rng.choice([1, 2, 3, 4]), firmware=firmware)
    replies: list[str] = []
    for _ in range(60):
        s.write((rng.choice(RANDOM_LINES) + "\r").encode())
        s.now += rng.choice([0.0, 0.0, 0.01, 0.1, 0.5, 2.0])
        replies += s.take()
    replies += s.settle(120.0)
    assert s.model.internal_errors == []
    assert all(line.lstrip("\n").isprintable() for line in replies)


@pytest.mark.parametrize("joystick_letter", values_of("joystick_letter"))
def test_joystick_letter(joystick_letter: str) -> None:
    s = sim(axes=2, joystick_letter=joystick_letter)
    j = joystick_letter
    assert s.ask("sa") == f"{j}{j}--.-"
    s.send("!moa y 1")
    assert s.ask("sa") == f"{j}M--.-"  # the manual's example JM--.- (L2721)
    assert s.settle() == [f"{j}{j}--."]
    assert s.send("!joy 0") == ["@@--."]  # the joystick is off from then on
    assert s.send("sa", "!moa 0 0") + s.settle() == ["@@--.-", "@@--."]
