"""``tango-aio settings dump|diff|restore`` and ``tango-aio info`` against the emulator."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tango_aio.cli._main import main

URL = "sim://?baud=0"


def _edited(dump: Path, setting: str, axis: str | None, value: float) -> Path:
    data = json.loads(dump.read_text())
    for item in data["settings"]:
        if item["setting"] == setting and item["axis"] == axis:
            item["value"] = value
    edited = dump.with_name("edited.json")
    edited.write_text(json.dumps(data))
    return edited


def test_dump_diff_restore(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    dump = tmp_path / "stage.json"
    assert main(["settings", "dump", URL, "-o", str(dump)]) == 0
    out, err = capsys.readouterr()
    assert out == "" and "settings of TANGO-DT written" in err
    assert json.loads(dump.read_text())["model"] == "TANGO-DT"
    assert main(["settings", "dump", URL]) == 0
    assert json.loads(capsys.readouterr().out)["format"] == "tango_aio settings"

    assert main(["settings", "diff", URL, str(dump)]) == 0
    out, err = capsys.readouterr()
    assert out == "" and "no differences" in err
    edited = _edited(dump, "vel", "x", 3.0)
    assert main(["settings", "diff", URL, str(edited)]) == 0
    assert capsys.readouterr().out == "vel X: snapshot 3.0, unit 10.0\n"
    assert main(["settings", "restore", URL, str(edited), "--yes"]) == 0
    out, err = capsys.readouterr()
    assert out == "vel X: snapshot 3.0, unit 10.0\n" and "restored 1 setting(s)" in err


def test_restore_refuses_another_model_with_one_error_line(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    dump = tmp_path / "stage.json"
    assert main(["settings", "dump", URL, "-o", str(dump)]) == 0
    data = json.loads(dump.read_text())
    data["model"] = "TANGO-PCI"
    dump.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["settings", "restore", URL, str(dump), "--yes"]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("error: ") and "TANGO-PCI" in err


def test_info_shows_what_the_controller_says_about_itself(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", URL]) == 0
    out = capsys.readouterr().out
    for name in ("serial", "temperature", "uptime", "max current", "stage serials"):
        assert name in out, out
    assert "190604001" in out and "°C" in out
