"""``tango-aio settings dump|diff|restore``: back up a controller's settings to a JSON
file, compare a controller with one, and bring one back; and the rows of
``tango-aio info`` that the controller says about itself."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import Any

from .._argtypes import UsageError, url_type
from ..controller import connect
from ..errors import SnapshotMismatchError
from ..families import ControllerInfo, SettingDifference, SettingsSnapshot

__all__ = ["add_settings_command", "info_rows"]


def info_rows(info: ControllerInfo) -> list[tuple[str, str]]:
    """The rows ``tango-aio info`` shows of :meth:`~tango_aio.Controller.read_info`."""
    def shown(value: Any, unit: str = "") -> str:
        return "-" if value is None else f"{value}{unit}"

    stages = info.stage_serial_numbers
    return [
        ("serial", shown(info.serial_number)),
        ("version", shown(info.version)),
        ("internal version", shown(info.internal_version)),
        ("temperature", shown(info.temperature, " °C")),
        ("uptime", shown(info.uptime, " s")),
        ("max current", "-" if info.max_current is None else
         "  ".join(f"{value:g} A" for value in info.max_current)),
        ("stage serials", "-" if stages is None else
         "  ".join(f"ETS{address}={serial}" for address, serial in stages.items()) or "none"),
    ]


def _out(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _note(text: str) -> None:
    sys.stderr.write(text + "\n")
    sys.stderr.flush()


def _snapshot_file(path: str) -> SettingsSnapshot:
    """The snapshot in ``path``, checked before anything opens (usage error if not)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UsageError(f"no such file: {path} (check the path)") from None
    except OSError as exc:
        raise UsageError(f"cannot read {path}: {exc.strerror or exc}") from None
    try:
        return SettingsSnapshot.from_json(text)
    except SnapshotMismatchError as exc:
        raise UsageError(f"{path}: {exc}") from None


def _show(differences: list[SettingDifference]) -> None:
    for difference in differences:
        _out(str(difference))


async def _dump(args: argparse.Namespace) -> int:
    """Write every setting of the controller as JSON (to stdout, or ``-o FILE``)."""
    async with connect(args.url) as tango:
        snapshot = await tango.settings.snapshot()
    text = snapshot.to_json()
    if args.output is None:
        _out(text)
    else:
        await asyncio.to_thread(Path(args.output).write_text, text + "\n", encoding="utf-8")
        _note(f"{len(snapshot.values)} settings of {snapshot.model} written to {args.output}")
    return 0


async def _diff(args: argparse.Namespace) -> int:
    """Show each setting whose value on the controller differs from FILE's."""
    snapshot = _snapshot_file(args.file)
    async with connect(args.url) as tango:
        differences = await tango.settings.diff(snapshot)
    _show(differences)
    if not differences:
        _note("no differences")
    return 0


async def _restore(args: argparse.Namespace) -> int:
    """Show the differences, ask (or --yes), write FILE's settings back, read them back."""
    # The link's own settings (baud, cts, ipreter, configdisplay) are not written.
    snapshot = _snapshot_file(args.file)
    if not args.yes and not sys.stdin.isatty():
        raise UsageError("restore writes settings to the controller; confirm with --yes "
                         "(stdin is not a terminal to ask)")
    async with connect(args.url) as tango:
        tango.settings.check(snapshot)
        differences = await tango.settings.diff(snapshot)
        _show(differences)
        if differences and not args.yes:
            try:
                answer = await asyncio.to_thread(
                    input, f"Write {len(differences)} setting(s)? [y/N] ")
            except EOFError:
                answer = ""
            if answer.strip().lower() not in ("y", "yes"):
                _note("restore cancelled: nothing was written")
                return 1
        written = await tango.settings.restore(snapshot)
    _note(f"restored {len(written)} setting(s)" if written else "no differences: nothing "
          "to restore")
    return 0


def _existing_or_stdout(value: str) -> str:
    parent = Path(value).resolve().parent
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"folder {parent} does not exist: create it first")
    return value


def add_settings_command(commands: Any) -> None:
    """Add ``settings`` and its ``dump``, ``diff`` and ``restore`` to the command line."""
    settings = commands.add_parser(
        "settings", help="back up, compare and restore a controller's settings",
        description="Back up a controller's settings to JSON, compare, restore.")
    actions = settings.add_subparsers(dest="action", required=True, metavar="ACTION")
    dump = actions.add_parser("dump", help="every setting as JSON", description=_dump.__doc__)
    dump.add_argument("url", type=url_type, help="controller URL")
    dump.add_argument("-o", "--output", type=_existing_or_stdout, metavar="FILE",
                      help="write to FILE instead of stdout")
    dump.set_defaults(run=_dump)
    diff = actions.add_parser("diff", help="compare with a dump", description=_diff.__doc__)
    diff.add_argument("url", type=url_type, help="controller URL")
    diff.add_argument("file", help="a file written by 'settings dump'")
    diff.set_defaults(run=_diff)
    restore = actions.add_parser("restore", help="write a dump back",
                                 description=_restore.__doc__)
    restore.add_argument("url", type=url_type, help="controller URL")
    restore.add_argument("file", help="a file written by 'settings dump'")
    restore.add_argument("--yes", action="store_true", help="do not ask before writing")
    restore.set_defaults(run=_restore)
