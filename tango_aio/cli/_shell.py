"""``tango-aio shell``: the interactive shell, its line readers (a terminal with history, or
a pipe) and its help."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import sys
import threading
from pathlib import Path
from typing import BinaryIO, Protocol

from ..catalog import AXES, lookup, parse, similar_names
from ..catalog import Command as CommandLine
from ..controller import Controller, connect
from ..errors import (
    InvalidCommandError,
    TangoError,
)
from ..events import (
    ConnectionLost,
    MoveFinished,
    StatusReport,
    Subscription,
)
from ..moves import describe_stop, failed_axes, moved_axes, optional_axes
from ..status import ABSENT, MOVING
from ._describe import (
    describe_error,
    describe_event,
    describe_exception,
    describe_instruction,
    describe_letters,
    describe_reply,
)
from ._output import (
    _complain,
    _plural,
    _say,
    _sigint_calls,
)

# -- shell ------------------------------------------------------------------------------

#: Default history file of the shell; the environment variable TANGO_AIO_HISTORY overrides.
HISTORY_FILE = "~/.tango_aio_history"
_PROMPT = "tango> "
#: Longest input line the shell reads; the rest of a longer line is skipped. Instruction
#: lines are at most 255 bytes (manual L129-131), so the validator rejects such lines.
_MAX_INPUT = 4096

SHELL_HELP = """\
Type instruction lines: ?pos reads, !moa 10 5 sets or runs, sa (bare form) as the manual
allows. Each line is checked against the instruction catalog before it is sent; lines
that set or run something are confirmed, so that a rejection shows its error number.
Shell commands:
  help           this text
  help NAME      an instruction from the catalog, e.g. help moa
  help NUMBER    an error number in words, e.g. help 5
  wait           wait until no axis moves
  exit, quit     leave (Ctrl+D too); axes still moving are stopped
Ctrl+C stops all axes (Ctrl+C to the controller) and the shell goes on.
Status letters: @ ok, M moving, S limit switch, E error/aborted, T timeout,
A calibrated, D range measured, J joystick, - absent."""


class LineReader(Protocol):
    """Where the shell gets its input lines."""

    async def read(self) -> str:
        """The next line; raises EOFError at the end, KeyboardInterrupt for Ctrl+C."""
        ...


class _TerminalReader:
    """prompt_toolkit input with editing and a persistent history (stdin is a tty)."""

    def __init__(self, history: Path) -> None:
        from prompt_toolkit import PromptSession
        from prompt_toolkit.history import FileHistory, History, InMemoryHistory

        class KeptHistory(FileHistory):
            """A history file that, once it cannot be written, warns once and is no
            longer written (instead of an error in the prompt after every line)."""

            failed = False

            def store_string(self, string: str) -> None:
                if not self.failed:
                    try:
                        super().store_string(string)
                    except OSError as exc:
                        self.failed = True
                        _history_warning(history, exc)

        kept: History
        try:
            with open(history, "ab"):  # can it be written? Say so once, at the start
                pass
        except OSError as exc:
            _history_warning(history, exc)
            kept = InMemoryHistory()
        else:
            kept = KeptHistory(str(history))
        self._session: PromptSession[str] = PromptSession(history=kept)

    async def read(self) -> str:
        return await self._session.prompt_async(_PROMPT, handle_sigint=False)


def _history_warning(history: Path, exc: OSError) -> None:
    _complain(f"warning: the history file {history} cannot be written "
         f"({exc.strerror or exc}): no history is kept; set TANGO_AIO_HISTORY to another "
         f"file", "yellow")


def read_bounded_line(stream: BinaryIO, limit: int) -> tuple[bytes, bool]:
    """The next line, reading at most ``limit + 1`` bytes, and whether it is longer than
    ``limit`` bytes (then it was cut, and the next read continues it). ``b""`` with False
    at the end of input."""
    line = stream.readline(limit + 1)
    return line, len(line) > limit and not line.endswith(b"\n")


class _PipeReader:
    """Lines from a non-interactive stdin, read by a daemon thread (never blocks exit).
    Bytes are decoded as UTF-8 with replacement characters, so no input kills the reader;
    a read error ends the input."""

    def __init__(self, stream: BinaryIO | None = None) -> None:
        self._lines: asyncio.Queue[str] = asyncio.Queue()
        loop = asyncio.get_running_loop()
        source = stream if stream is not None else sys.stdin.buffer

        def deliver(text: str) -> bool:
            """Hand ``text`` to the loop; False once the loop is closed (the shell has
            ended while this thread still read: nobody is left to take the line).

            Returns
            -------
            bool
                Whether the loop took the text.
            """
            try:
                loop.call_soon_threadsafe(self._lines.put_nowait, text)
            except RuntimeError:
                return False
            return True

        def pump() -> None:
            skipping = False  # inside the rest of a line that was too long
            try:
                while True:
                    line, cut = read_bounded_line(source, _MAX_INPUT)
                    if not line:
                        break
                    if skipping:
                        skipping = cut
                        continue
                    skipping = cut
                    if not deliver(line.decode("utf-8", errors="replace")):
                        return
            except (OSError, ValueError):
                pass
            finally:
                deliver("")  # the end of the input

        self._thread = threading.Thread(target=pump, name="tango-aio-stdin", daemon=True)
        self._thread.start()

    async def read(self) -> str:
        line = await self._lines.get()
        if not line:
            raise EOFError
        return line.rstrip("\r\n")


def history_path() -> Path:
    """The shell's history file: $TANGO_AIO_HISTORY, or ~/.tango_aio_history."""
    return Path(os.environ.get("TANGO_AIO_HISTORY") or HISTORY_FILE).expanduser()


class Shell:
    """The interactive line shell of ``tango-aio shell`` on a connected controller."""

    def __init__(self, tango: Controller, reader: LineReader, *, script: bool = False
                 ) -> None:
        self.tango = tango
        self.reader = reader
        #: Whether the input is a script (piped): then a failed line makes the exit status 1.
        self.script = script
        self.failures = 0
        self._job: asyncio.Future[None] | None = None
        self._aborting: asyncio.Future[None] | None = None
        self._lost = asyncio.Event()
        #: Moves the shell's lines started and not judged yet: axis -> (serial, target;
        #: ``None`` where the line gives no absolute target: mor, cal, rm, moc).
        self._moves: dict[str, tuple[int, float | None, bool]] = {}
        self._serial = 0
        self._judging = asyncio.Lock()
        #: How many judged moves did not end at their target.
        self.move_failures = 0

    async def run(self) -> int:
        """Read, validate and send lines until ``exit``, ``quit``, end of input or the
        loss of the connection; stop axes still moving when leaving."""
        async with self.tango.events() as events:
            printer = asyncio.ensure_future(self._print_events(events))
            try:
                with _sigint_calls(self._on_sigint):
                    await self._loop()
                    if not self._lost.is_set():
                        await self._settle_abort()
                        await self._judge(leaving=True)
                        await self._stop_moving()
            finally:
                printer.cancel()
                await asyncio.wait({printer})
        failed = (self.script and self.failures) or self.move_failures or self._lost.is_set()
        return 1 if failed else 0

    async def _loop(self) -> None:
        while True:
            try:
                line = await self._next_line()
            except EOFError:
                return
            except KeyboardInterrupt:  # Ctrl+C at the prompt
                await self._abort()
                continue
            if line is None:  # the connection is gone
                return
            if line.lower() in ("exit", "quit"):
                return
            if line:
                await self._settle_abort()
                await self._run_line(line)

    async def _next_line(self) -> str | None:
        """The next input line, or ``None`` as soon as the connection is lost."""
        read = asyncio.ensure_future(self._read())
        lost = asyncio.ensure_future(self._lost.wait())
        try:
            await asyncio.wait({read, lost}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            lost.cancel()
            if not read.done():
                read.cancel()
                await asyncio.wait({read})
        if self._lost.is_set():
            return None
        line = read.result()
        if isinstance(line, BaseException):
            raise line
        return line.strip()

    async def _read(self) -> str | KeyboardInterrupt:
        """A line, or the reader's KeyboardInterrupt as a value: raised inside a task it
        would stop the event loop."""
        try:
            return await self.reader.read()
        except KeyboardInterrupt as interrupt:
            return interrupt

    async def _run_line(self, line: str) -> None:
        """Run one line as a job that Ctrl+C cancels (and then aborts)."""
        job = self._job = asyncio.ensure_future(self.execute(line))
        try:
            await asyncio.wait({job})
        finally:
            self._job = None
            job.cancel()
        if job.cancelled():
            _complain(f"interrupted: {line}", "yellow")
            self.failures += 1
            await self._abort()
            return
        error = job.exception()
        if isinstance(error, InvalidCommandError):
            _complain(f"invalid: {describe_exception(error)} (nothing sent)", "yellow")
        elif isinstance(error, TangoError):
            _complain(f"error: {describe_exception(error)}", "red")
        else:
            job.result()
            return
        self.failures += 1

    async def execute(self, line: str) -> None:
        """Run one line: a shell command (``help``, ``wait``), or an instruction line,
        validated first; a read is sent with ``query`` and its decoded reply shown,
        anything else with ``command`` and confirmed (a rejection raises)."""
        words = line.split()
        if words[0].lower() == "help" and len(words) <= 2:
            _say(self.help(words[1] if len(words) == 2 else None))
            return
        if words == ["wait"]:
            letters = await self.tango.wait_idle()
            _say(f"idle: {describe_letters(letters)}")
            await self._judge()
            return
        command = parse(line, self.tango.context)
        if command.is_read:
            _say(describe_reply(command, await self.tango.query(line)))
        else:
            await self.tango.command(line)
            self._started(command)
            _say("ok", "dim")

    def _started(self, command: CommandLine) -> None:
        """Remember the axes (and absolute targets) of a move line the controller took,
        to judge later whether it ended at its target."""
        if command.instruction.completion is None and command.name != "go":
            return
        present = AXES[: self.tango.context.axes]
        axes = moved_axes(command, present)
        targets: dict[str, float] = {}
        if command.name in ("moa", "go") and command.values:
            targets = dict(zip(axes, (float(v) for v in command.values), strict=False))
        optional = optional_axes(command, axes)
        for axis in axes:
            self._serial += 1
            self._moves[axis] = (self._serial, targets.get(axis), axis in optional)

    async def _judge(self, *, leaving: bool = False) -> None:
        """Judge the moves the shell's lines started whose axes stand now, by the
        driver's own rule (:func:`~tango_aio.moves.failed_axes`). ``leaving``: an axis
        still moving counts as failed (it is stopped next). Failures are printed in words
        and counted."""
        async with self._judging:
            pending = dict(self._moves)
            if not pending:
                return
            try:
                letters = await self.tango.status()
                reply = await self.tango.query("?pos")
            except (TangoError, TimeoutError) as exc:
                _complain(f"error: reading the state after a move: {describe_exception(exc)}",
                     "red")
                self.move_failures += 1
                return
            texts = dict(zip(AXES[: self.tango.context.axes], reply.split(),
                             strict=False))
            failed = []
            for axis, (serial, target, optional) in pending.items():
                letter = letters.get(axis, ABSENT)
                if letter == MOVING and not leaving:
                    continue  # not ended yet
                if self._moves.get(axis, (0, None, False))[0] == serial:
                    del self._moves[axis]
                text = texts.get(axis)
                if letter == MOVING:
                    failed.append(describe_stop(axis, letter, text, target,
                                                why="still moving when the shell was left"))
                elif failed_axes((axis,), None if target is None else {axis: target}, {},
                                 letters, texts, optional=(axis,) if optional else ()):
                    failed.append(describe_stop(axis, letter, text, target))
            if failed:
                self.move_failures += 1
                _complain(f"move failed: {'; '.join(failed)}", "red")

    @staticmethod
    def help(topic: str | None) -> str:
        """The shell's help: its commands, an instruction, or an error number."""
        if topic is None:
            return SHELL_HELP
        if topic.lstrip("-").isdigit():
            return describe_error(int(topic))
        name = topic.lstrip("!?").lower()
        try:
            return describe_instruction(lookup(name))
        except InvalidCommandError:
            close = similar_names(name)
            hint = f"did you mean {' or '.join(close)}? " if close else ""
            return (f"no instruction {topic!r} in the catalog; {hint}'help' lists the "
                    f"shell's commands")

    def _on_sigint(self) -> None:
        if self._job is not None:
            self._job.cancel()  # _run_line aborts once the job is gone
        elif self._aborting is None or self._aborting.done():
            self._aborting = asyncio.ensure_future(self._abort())

    async def _settle_abort(self) -> None:
        if self._aborting is not None:
            await asyncio.wait({self._aborting})

    async def _abort(self) -> None:
        try:
            await self.tango.abort()
        except (TangoError, TimeoutError) as exc:
            _complain(f"error: abort: {describe_exception(exc)}", "red")

    async def _stop_moving(self) -> None:
        """Stop the axes that still move when the shell is left."""
        await self._settle_abort()
        try:
            moving = [a for a, s in (await self.tango.status()).items() if s == MOVING]
            if moving:
                _complain(f"stopping the axes that still move: {' '.join(moving)}", "yellow")
                await self.tango.abort()
        except (TangoError, TimeoutError) as exc:
            _complain(f"error: stopping the axes: {describe_exception(exc)}", "red")
            self.failures += 1

    async def _print_events(self, events: Subscription) -> None:
        async for event in events:
            text = describe_event(event)
            if text is not None:
                _say(text, "red" if isinstance(event, ConnectionLost) else "cyan")
            if isinstance(event, ConnectionLost):
                self._lost.set()
            elif isinstance(event, MoveFinished | StatusReport) and self._moves:
                with contextlib.suppress(TangoError, TimeoutError):
                    await self._judge()


async def _shell(args: argparse.Namespace) -> int:
    """Interactive shell: type instruction lines (``?pos``, ``!moa 10 5``), validated
    before sending; lines that set or run something are confirmed, so that a rejection
    shows its error. Completion reports, error numbers and unsolicited lines are shown in
    words. ``help`` lists the shell's commands, ``help moa`` explains an instruction.
    Ctrl+C aborts (all axes stop); Ctrl+D, ``exit`` or ``quit`` leave, stopping axes that
    still move. Lines piped into the shell run as a script, whose exit status is 1 if any
    line failed; in both modes it is 1 if a move did not end at its target (a move still
    running at the end is stopped and counts as failed). History is kept
    in ~/.tango_aio_history ($TANGO_AIO_HISTORY)."""
    async with connect(args.url) as tango:
        ident = tango.identity
        # On stderr: stdout holds the replies only (a script's).
        _complain(f"connected to {ident.model} firmware {ident.firmware}, "
                  f"{_plural(ident.axes, 'axis', 'axes')} at {args.url}; 'help' lists the "
                  f"commands, Ctrl+C aborts, Ctrl+D or 'exit' leaves", "bold")
        if sys.stdin.isatty() and sys.stdout.isatty():
            from prompt_toolkit.patch_stdout import patch_stdout

            with patch_stdout(raw=True):
                return await Shell(tango, _TerminalReader(history_path())).run()
        return await Shell(tango, _PipeReader(), script=True).run()
