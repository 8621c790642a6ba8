"""The CLI's conventions (issue 30 items 7, 12 and 13): exit codes, units on ``move`` and
``info``, ``demo URL``, ``sim --tcp PORT``, trigger files numbered by file line, and
controller text shown with its control characters escaped."""

from __future__ import annotations

import asyncio
import urllib.parse
from pathlib import Path

import pytest

from tango_aio.cli._main import _loop_exception, _parser, main
from tango_aio.cli._output import _escaped
from tango_aio.cli._simcmd import _tcp_address

SIM = "sim://?baud=0"


def cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
    """Run the CLI in this process: exit code and stdout+stderr."""
    try:
        code = main(list(args))
    except SystemExit as exit_:  # argparse: usage errors
        code = int(exit_.code or 0)
    out, err = capsys.readouterr()
    return code, out + err


@pytest.mark.parametrize("args", [
    ("move", SIM, "x=1_000"),
    ("move", SIM, "x=nan"),
    ("move", SIM, "x=1mm", "y=2"),  # a unit on some axes only
    ("move", SIM, "x=1mm", "y=2rev"),  # units that do not convert
    ("move", SIM, "x=1parsec"),
    ("move", SIM, "x=1", "x=2"),
    ("sim", "--tcp", "abc"),
    ("sim", "--tcp", "[::1"),
    ("sim", "--per-connection"),
    ("sim", "--latency", "nan"),
    ("sim", "--processing", "-1"),
    ("sim", "--speed", "0"),
    ("sim", "--switch", "echo"),
    ("info", "sim://?latency=nan"),
])
def test_usage_errors_exit_2_before_anything_runs(capsys: pytest.CaptureFixture[str],
                                                  args: tuple[str, ...]) -> None:
    code, out = cli(capsys, *args)
    assert code == 2, out
    assert "error" in out and "Traceback" not in out


def test_sim_tcp_takes_a_bare_port() -> None:
    assert _tcp_address("47413") == ("127.0.0.1", 47413)
    assert _tcp_address(":47413") == ("127.0.0.1", 47413)
    assert _tcp_address("[::1]:0") == ("::1", 0)


def test_demo_takes_the_url_as_its_argument() -> None:
    parser = _parser()
    assert parser.parse_args(["demo"]).url == "sim://"
    assert parser.parse_args(["demo", "sim://?axes=2"]).url == "sim://?axes=2"
    old = parser.parse_args(["demo", "--url", "sim://?axes=1"])
    assert old.old_url == "sim://?axes=1"  # the deprecated spelling, still taken


def test_move_takes_units(capsys: pytest.CaptureFixture[str]) -> None:
    code, out = cli(capsys, "move", SIM + "&speed=50", "x=1.5mm", "y=-500um")
    assert code == 0, out
    assert "x=   1.5000  y=  -0.5000  z=   0.0000" in out, out  # mm, the common unit
    code, out = cli(capsys, "move", SIM + "&speed=50", "x=2000um")
    assert code == 0 and "x=2000.0000" in out.replace(" ", ""), out


def test_info_shows_units(capsys: pytest.CaptureFixture[str]) -> None:
    code, out = cli(capsys, "info", SIM)
    assert code == 0, out
    flat = " ".join(out.split())
    for text in ("x= 0.0000 mm", "x=2 (mm)", "x=1.0000 mm/rev", "x=10.000 rev/s",
                 "x=1.00 m/s²", "x=10.00 mm/s"):
        assert text in flat, (text, out)


def test_controller_text_is_shown_with_control_characters_escaped(
        capsys: pytest.CaptureFixture[str]) -> None:
    model = "TANGO\x1b]0;owned\x07-DT"
    url = SIM + "&" + urllib.parse.urlencode({"model": model})
    code, out = cli(capsys, "info", url)
    assert code == 0, out
    assert "\x1b" not in out and "\x07" not in out, repr(out)
    assert "TANGO\\x1b]0;owned\\x07-DT" in out, out
    assert _escaped("a\rb\x9bc\nd") == "a\\x0db\\x9bc\nd"


def test_upload_trigp_numbers_entries_by_file_line(capsys: pytest.CaptureFixture[str],
                                                    tmp_path: Path) -> None:
    path = tmp_path / "positions.txt"
    path.write_text("# header\n1.0\n\n2.0\n1.5\n")
    code, out = cli(capsys, "upload-trigp", SIM, str(path))
    assert code == 1 and f"{path}:5: trigp: the position (1.5) breaks the monotonic" in out, out
    path.write_text("1.0\n2.0\ninf\n")
    code, out = cli(capsys, "upload-trigp", SIM, str(path))
    assert code == 1 and f"{path}:3:" in out, out


def test_an_empty_trigger_file_is_an_error(capsys: pytest.CaptureFixture[str],
                                           tmp_path: Path) -> None:
    path = tmp_path / "positions.txt"
    path.write_text("# nothing yet\n\n")
    code, out = cli(capsys, "upload-trigp", SIM, str(path))
    assert code == 1 and "no positions" in out, out


def test_shell_help_gives_one_sentence_a_line_and_suggests_names() -> None:
    from tango_aio.cli._shell import Shell

    text = Shell.help("moa")
    assert text.splitlines()[:2] == ["moa: Move X Y Z absolute to positions 10 10 10",
                                     "  Move Y axis to position 20 (unit depends on dim "
                                     "setting)"], text
    assert "did you mean moa or mro?" in Shell.help("mao")
    assert "did you mean" not in Shell.help("xyzzy")


def test_shell_checks_what_the_controller_would_refuse(tmp_path: Path) -> None:
    import os
    import subprocess
    import sys

    script = "!mao\n!moa 1 2 3 4\n!moa 1e3\n?pos\n"
    result = subprocess.run([sys.executable, "-m", "tango_aio", "shell", SIM], input=script,
                            capture_output=True, text=True, timeout=60, check=False,
                            env={**os.environ, "TANGO_AIO_HISTORY": str(tmp_path / "h")})
    out = result.stderr
    assert result.returncode == 1, result.stdout + out
    assert "invalid: unknown instruction 'mao' (did you mean moa or mro?) (nothing sent)" in out
    assert ("invalid: moa: 4 axis values, but the controller has 3 (axes X Y Z) "
            "(nothing sent)") in out
    assert "invalid: moa: position '1e3' is in exponent notation, which is refused" in out
    assert "controller error" not in out, out  # nothing reached the controller
    assert "0.0000 0.0000 0.0000" in result.stdout and "invalid:" not in result.stdout


def test_a_second_ctrl_c_in_a_task_is_not_reported_as_a_warning(
        capsys: pytest.CaptureFixture[str]) -> None:
    """main() says "interrupted" once; a KeyboardInterrupt that a task got during the
    shutdown (an impatient second Ctrl+C) adds no "warning:" line, other errors do."""
    loop = asyncio.new_event_loop()
    try:
        _loop_exception(loop, {"exception": KeyboardInterrupt(), "message": "x"})
        captured = capsys.readouterr()
        assert "warning" not in captured.err + captured.out
        _loop_exception(loop, {"exception": RuntimeError("boom"), "message": "x"})
        captured = capsys.readouterr()
        assert "warning: " in captured.err + captured.out
    finally:
        loop.close()
