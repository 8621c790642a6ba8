"""The ``tango-aio ioc`` command line (no caproto needed for these)."""

from __future__ import annotations

import pytest

from tango_aio.cli import main
from tango_aio.epics.command import loopback_only, parse_controllers


def test_one_url_or_named_controllers() -> None:
    assert parse_controllers("/dev/ttyUSB0", []) == {"": "/dev/ttyUSB0"}
    assert parse_controllers(None, ["stage=sim://", "focus=socket://h:4001"]) == {
        "stage": "sim://", "focus": "socket://h:4001"}
    for url, named in [(None, []), ("sim://", ["a=sim://"]), (None, ["a"]),
                       (None, ["=sim://"]), (None, ["a:b=sim://"]),
                       (None, ["a=sim://", "a=sim://?axes=2"])]:
        with pytest.raises(ValueError):
            parse_controllers(url, named)


def test_loopback_detection() -> None:
    assert loopback_only(["127.0.0.1"]) and loopback_only(["127.0.0.1", "::1"])
    assert not loopback_only(["0.0.0.0"]) and not loopback_only(["192.168.1.20"])
    assert not loopback_only(["localhost"])  # a name: not known to be loopback


def test_usage_errors_exit_nonzero(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["ioc", "--prefix", "P:"]) == 1
    assert "controller URL" in capsys.readouterr().out
    assert main(["ioc", "sim://", "--prefix", "P:", "--allow-user", ""]) == 1
    with pytest.raises(SystemExit):
        main(["ioc", "sim://"])  # --prefix is required
