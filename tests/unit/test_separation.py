"""Two reads in a row never take each other's replies: the separator rule of the write
scheduler (tango_aio.sansio._scheduler, rule 3) in every autostatus mode and on every firmware
variant, checked against the emulator's own replies under single faults.

Each example feeds the scheduler two reads of the catalog (with a core set up as the
driver sees that firmware after connecting: how ``?help N`` answers, whether reads are
acknowledged in mode 2), takes the bytes it writes, runs them through the emulator's
interpreter (its own reading of the manual) and records which written line each reply
line came from. Then it replays that stream into a fresh core with one fault at a time:
a reply line lost, a written line lost (none of its lines come), or one extra well-formed
line (a copy of another line of the stream) anywhere. Whatever each read gets must be its
own line or the extra line itself (a stray line that fits the request it reaches cannot
be told by any protocol without ids: tango_aio.sansio._patterns), never the other read's, nor a
separator's or marker's. When the second read is not written with the first (no separator
fits), it must not be written until the first got the lines it was sure to get.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import INSTRUCTIONS, Context, parse
from tango_aio.sansio._core import AckReads, HelpStyle, Mismatched, ProtocolCore, Replied
from tango_aio.sansio._patterns import ReplyKind, reply_pattern
from tango_aio.sansio._scheduler import Line, WriteScheduler
from tango_aio.sim.model import ControllerModel, SimConfig
from tango_aio.sim.profiles import Firmware, variants

#: Every firmware variant a client's matrix runs (profiles and single switches).
VARIANTS = dict(variants())
#: The marker number a core with ``marker_seed=0`` uses first, and the number asked for
#: when the driver learns the text of ``?help N`` (HelpStyle.TEXT).
CODE = 70
#: Origin of a line that no written line sent (the extra line of a fault).
STRAY = -1


def _model(firmware: Firmware) -> tuple[ControllerModel, bytearray]:
    out = bytearray()
    return ControllerModel(out.extend, SimConfig(firmware=firmware), now=0.0), out


def _answer(model: ControllerModel, out: bytearray, line: str) -> list[str]:
    """The lines the emulator sends for ``line`` (the line ends of any firmware)."""
    del out[:]
    model.handle_line(line.encode("ascii"), 0.0)
    return out.decode("latin-1").replace("\n", "").split("\r")[:-1]


def _catalog_reads() -> list[str]:
    """Every read form of the catalog the emulator answers with one reply (a read it
    refuses gets no line at all: nothing to confuse)."""
    model, out = _model(Firmware())
    context = model.context()
    reads = []
    for name, entry in sorted(INSTRUCTIONS.items()):
        if not entry.read:
            continue
        for text in (f"?{name}", name, f"?{name} x", f"?{name} 1", f"?{name} x 1"):
            try:
                line = parse(text, context).line
            except ValueError:
                continue
            if _answer(model, out, line) and _answer(model, out, "?err") == ["0"]:
                reads.append(line)
    return reads


READS = _catalog_reads()


@dataclass(frozen=True)
class View:
    """How the driver sees a firmware after connecting (what ``connect`` detects)."""

    mode: int
    help_style: HelpStyle
    help_text: tuple[int, str] | None
    ack_reads: AckReads | None
    context: Context


def _view(firmware: Firmware, mode: int, detected: bool) -> View:
    model, out = _model(firmware)
    answer = _answer(model, out, f"?help {CODE}")
    if answer and answer[0].upper().startswith(f"ERROR {CODE},"):
        style, text = HelpStyle.NUMBER, None
    elif answer:
        style, text = HelpStyle.TEXT, (CODE, answer[0])
    else:
        style, text = HelpStyle.NONE, None
    # Mode 2 finds out whether reads are acknowledged when it is entered; until then
    # (``detected`` false) both are optional.
    acks = AckReads(firmware.ack_reads) if detected or mode != 2 else None
    return View(mode, style, text, acks, model.context())


def _core(view: View) -> ProtocolCore:
    core = ProtocolCore(autostatus=view.mode, context=view.context, marker_seed=0)
    core.help_style, core.help_text, core.ack_reads = view.help_style, view.help_text, \
        view.ack_reads
    return core


@dataclass
class Run:
    """The two reads through a scheduler: the bytes written, the lines' tags."""

    core: ProtocolCore
    scheduler: WriteScheduler
    tags: tuple[int, int]
    written: bytes


def _start(view: View, separators: bool, first: str, second: str) -> Run:
    core = _core(view)
    scheduler = WriteScheduler(core, separators=separators)
    tags = []
    for text in (first, second):
        command = parse(text, view.context)
        tag, mode, expect = scheduler.plan(command)
        scheduler.submit(Line(command, tag, expect, mode))
        tags.append(tag)
    return Run(core, scheduler, (tags[0], tags[1]), scheduler.next_write())


def _stream(firmware: Firmware, mode: int, written: bytes) -> list[tuple[str, int]]:
    """The emulator's reply lines to ``written``, each with the index of the written
    line it answers."""
    model, out = _model(firmware)
    _answer(model, out, f"!autostatus {mode}")
    lines = written.decode("ascii").split("\r")[:-1]
    return [(reply, index) for index, line in enumerate(lines)
            for reply in _answer(model, out, line)]


def _faults(stream: list[tuple[str, int]]) -> Iterator[tuple[str, list[tuple[str, int]]]]:
    yield "none", stream
    for index in range(len(stream)):
        yield f"reply {index} lost", stream[:index] + stream[index + 1:]
    for origin in sorted({origin for _, origin in stream}):
        yield f"line {origin} lost", [item for item in stream if item[1] != origin]
    copies = dict.fromkeys(text for text, _ in stream)
    for at, copy in itertools.product(range(len(stream) + 1), copies):
        yield f"extra {copy!r} at {at}", [*stream[:at], (copy, STRAY), *stream[at:]]


def _deliveries(run: Run, stream: list[tuple[str, int]]
                ) -> dict[int, list[int] | None]:
    """Feed ``stream`` line by line: the origins of the lines each read got (``None``:
    it got a typed failure instead)."""
    got: dict[int, list[int] | None] = {}
    for index, (text, _) in enumerate(stream):
        for event in run.core.events(text.encode("latin-1") + b"\r"):
            if isinstance(event, Mismatched):
                return got  # the protocol resyncs: what is in flight fails, typed
            if isinstance(event, Replied) and event.tag in run.tags:
                # The reply's lines end with this line, or with the one before (a read
                # that ends where the next line does not continue it).
                block = _block(stream[:index + 1], event.lines)
                if block is None:
                    raise AssertionError(f"{event} is not in the stream")
                got[event.tag] = block
    return got


def _block(fed: list[tuple[str, int]], lines: tuple[str, ...]) -> list[int] | None:
    """The origins of the fed lines a reply's ``lines`` are: those ending with the last
    line fed, or with the one before (a read that ends where the next line does not
    continue it); a stray empty line (a bare CR) inside a multi-line reply may be passed
    over, as the core passes it over."""
    wanted = [line.upper() for line in lines]  # the core puts OK, ERR, ERROR in capitals
    without_stray_blanks = [entry for entry in fed if entry != ("", STRAY)]
    for seen in (fed, without_stray_blanks):
        for end in (len(seen), len(seen) - 1):
            block = seen[max(end - len(lines), 0):end]
            if [line.upper() for line, _ in block] == wanted:
                return [origin for _, origin in block]
    return None


def _check(firmware: Firmware, view: View, separators: bool, first: str,
           second: str) -> None:
    first, second = (parse(text, view.context).line for text in (first, second))
    run = _start(view, separators, first, second)
    lines = run.written.decode("ascii").split("\r")[:-1]
    stream = _stream(firmware, view.mode, run.written)
    if second not in lines[1:]:
        # No separator fits: the second waits until the first got what it is sure to get.
        answered = False
        for text, _ in stream:
            events = run.core.events(text.encode("latin-1") + b"\r")
            answered = answered or any(isinstance(event, Replied)
                                       and event.tag == run.tags[0] for event in events)
            later = run.scheduler.next_write()
            if later:
                assert answered, (first, second)
                assert parse(second, view.context).to_bytes() in later
                return
        # Never answered (a read this firmware does not know): it times out first.
        assert not answered
        return
    own = {run.tags[0]: lines.index(first), run.tags[1]: len(lines) - 1 - lines[::-1].index(
        second)}
    # Free text (one line or several) fits any line: a read of it whose own reply or line
    # is lost takes the next line, which no check can tell (tango_aio.sansio._patterns). What the
    # other read gets is checked all the same.
    free = {index for index, line in enumerate(lines)
            if reply_pattern(parse(line, view.context), view.context).kind is ReplyKind.ANY}
    for name, faulty in _faults(stream):
        again = _start(view, separators, first, second)
        assert again.written == run.written
        got = _deliveries(again, faulty)
        if name == "none":
            # A read this firmware does not know gets no line (it times out).
            assume(set(got) == set(own))
        for tag, origins in got.items():
            if own[tag] in free:
                continue
            assert origins is not None
            assert all(origin in (own[tag], STRAY) for origin in origins), (
                f"{name}: {lines[own[tag]]!r} got {origins} of {lines} "
                f"from {faulty}")


@st.composite
def cases(draw: st.DrawFn) -> tuple[str, int, bool, bool, str, str]:
    variant = draw(st.sampled_from(sorted(VARIANTS)))
    mode = draw(st.integers(0, 4))
    return (variant, mode, draw(st.booleans()), draw(st.booleans()),
            draw(st.sampled_from(READS)), draw(st.sampled_from(READS)))


def _run(case: tuple[str, int, bool, bool, str, str]) -> None:
    name, mode, detected, separators, first, second = case
    firmware = VARIANTS[name]
    _check(firmware, _view(firmware, mode, detected), separators, first, second)


# The pairs of the issue (#37): mode 4, the manual's firmware, four look-alike reads.
@example(("manual", 4, True, True, "?accel z", "?vel y"))
@example(("manual", 4, True, True, "?vel y", "?accel x"))
@example(("legacy", 4, True, True, "?statusaxis", "sa"))
@example(("echo_all=yes", 4, True, True, "?pos", "?encerr"))
@example(("move_ok=completion", 2, False, True, "?vel x", "?vel x"))
@example(("ack_reads=after", 2, True, True, "?vel x", "?accel x"))
@example(("help_number=no", 1, True, False, "?vel x", "?accel x"))
@example(("manual", 1, True, True, "?vel x", "?encerr x"))  # a marker between
@example(("manual", 1, True, True, "?accel", "?lockstate"))  # the marker may look alike
@example(("manual", 0, True, True, "?lim", "?mro"))  # ?lim's lines after its follow-up
@example(("manual", 0, True, False, "?lim", "?mro"))
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_two_reads_never_take_each_others_replies(
        case: tuple[str, int, bool, bool, str, str]) -> None:
    _run(case)


@pytest.mark.slow
@settings(max_examples=5000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_two_reads_never_take_each_others_replies_long(
        case: tuple[str, int, bool, bool, str, str]) -> None:
    _run(case)
