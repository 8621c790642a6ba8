"""``tango-aio tango-server``'s command line: what it asks for before anything opens, and
the way it asks for pytango where the extra is missing."""

from __future__ import annotations

import sys

import pytest

from tango_aio._install import install_hint
from tango_aio.cli import main
from tango_aio.tango_controls import DEFAULT_PREFIX, device_names


def test_without_pytango_it_says_how_to_install_the_extra(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "tango", None)  # import tango raises ImportError
    assert main(["tango-server", "sim://?baud=0", "--nodb"]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    assert "needs pytango" in err and install_hint("tango-controls") in err, err


def test_without_a_database_or_nodb_it_is_a_usage_error(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv("TANGO_HOST", raising=False)
    assert main(["tango-server", "sim://?baud=0"]) == 2
    _, err = capsys.readouterr()
    assert "set TANGO_HOST, or serve with --nodb" in err, err


def test_the_device_names() -> None:
    assert device_names(DEFAULT_PREFIX, 2) == (
        ["marzhauser/stage/x", "marzhauser/stage/y"], "marzhauser/stage/controller")
