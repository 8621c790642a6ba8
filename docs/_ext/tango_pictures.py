"""Pictures drawn from a real run of the emulator, at documentation build time.

* ``{tango-picture} reply-routing``: the lines of one ``move_to(x=10, y=5)`` on the wire, as
  the ``tango_aio.wire`` log records them, each reply joined to the request it answers
  (replies come in the order of the requests, see docs/concepts/replies.md) and the
  completion report to the move it ends;
* ``{tango-picture} raster-scan``: the raster scan of the raster-scan how-to, its path as
  the positions read after each move and its trigger pulses where the emulator fired
  them (``TriggerFired`` events of its motion model).

Nothing is drawn by hand: :func:`record_move` and :func:`record_raster` run the emulator,
:func:`routing_svg` and :func:`raster_svg` turn what they recorded into SVG (no plotting
library needed), and ``tests/e2e/test_pictures.py`` checks both against the run.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass, field
from html import escape
from typing import Any

from docutils import nodes
from docutils.parsers.rst import Directive

#: The scan of docs/howto/raster-scan.md: rows, their Y, the list on X and X's travel.
ROWS = 3
ROW_STEP = 0.5
POSITIONS = [round(0.5 + 0.25 * i, 4) for i in range(9)]
X_END = 3.0


@dataclass
class WireLine:
    """One line on the wire: ``sent`` by the driver (else received), its text, and what
    it is: the request a reply answers, or ``completion report``."""

    sent: bool
    text: str
    meaning: str = ""


class _WireRecorder(logging.Handler):
    """Collects the ``tango_aio.wire`` log (``-> b'...'`` and ``<- b'...'``)."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.lines: list[WireLine] = []

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        for arrow, sent in (("-> ", True), ("<- ", False)):
            if arrow in message:
                raw = message.split(arrow, 1)[1]
                text = raw[2:-1] if raw.startswith(("b'", 'b"')) else raw
                self.lines.append(WireLine(sent, text))


def label_replies(lines: list[WireLine]) -> list[WireLine]:
    """Join each received line to what it is: a completion report, or the reply to the
    oldest read still unanswered (a read, ``?...`` or ``sa``, gets exactly one reply
    line)."""
    from tango_aio.sansio._core import is_completion_line

    waiting: list[str] = []
    for line in lines:
        if line.sent:
            if line.text.startswith("?") or line.text == "sa":
                waiting.append(line.text)
                line.meaning = ("the driver's separator: a reply like no other"
                                if line.text == "?help" else
                                "a read (?statusaxis, spelt short): one reply line"
                                if line.text == "sa" else "a read: one reply line")
            else:
                line.meaning = "the move: no reply line in autostatus 1"
        elif is_completion_line(line.text):
            line.meaning = "completion report: the move's hint that it ended"
        elif waiting:
            line.meaning = f"reply to {waiting.pop(0)}"
        else:
            line.meaning = "unsolicited"
    return lines


async def record_move() -> list[WireLine]:
    """The wire lines of one ``move_to(x=10, y=5)`` on the emulator (autostatus 1)."""
    import tango_aio

    wire = logging.getLogger("tango_aio.wire")
    recorder = _WireRecorder()
    async with tango_aio.connect("sim://?baud=0&speed=20") as tango:
        level, propagate = wire.level, wire.propagate
        wire.addHandler(recorder)
        wire.setLevel(logging.DEBUG)
        wire.propagate = False  # the recorder's lines only, not the build's log
        try:
            await tango.move_to(x=10.0, y=5.0)
        finally:
            wire.setLevel(level)
            wire.propagate = propagate
            wire.removeHandler(recorder)
    return label_replies(recorder.lines)


@dataclass
class RasterRun:
    """What :func:`record_raster` recorded: the path (X, Y after each move), the pulses
    (X, Y where the emulator fired one) and ``?trigcount`` at the end."""

    path: list[tuple[float, float]] = field(default_factory=list)
    pulses: list[tuple[float, float]] = field(default_factory=list)
    count: int = 0


async def record_raster() -> RasterRun:
    """Run the raster scan of the how-to on the emulator and record it."""
    import tango_aio
    from tango_aio.sim.motion import TriggerFired
    from tango_aio.testing import faults

    run = RasterRun()
    async with tango_aio.connect("sim://?baud=0&speed=20") as tango:
        handler = faults(tango).wire.handler
        model = getattr(handler, "handler", handler)  # inside the clock's ScaledHandler
        motion = model.motion
        advance = motion.advance
        row_y = [0.0]

        def recording(now: float) -> Any:
            events = advance(now)
            run.pulses += [(event.position, row_y[0]) for event in events
                           if isinstance(event, TriggerFired)]
            return events

        motion.advance = recording

        async def point() -> None:
            position = await tango.position()
            run.path.append((position["x"], position["y"]))

        await tango.move_to(x=0.0, y=0.0)
        await point()
        await tango.triggers.upload_positions(POSITIONS, axis="x")
        await tango.command("!trigcount 0")
        await tango.command("!trig 1")
        for row in range(ROWS):
            row_y[0] = row * ROW_STEP
            await tango.move_to(y=row_y[0])
            await point()
            await tango.move_to(x=X_END)
            await point()
            await tango.move_to(x=0.0)
            await point()
        await tango.command("!trig 0")
        run.count = int(await tango.get("trigcount"))
    return run


# -- drawing ----------------------------------------------------------------------------

_FONT = "font-family='ui-monospace, SFMono-Regular, Menlo, monospace' font-size='12'"
_LANES = {"code": 90, "driver": 300, "tango": 510}


def routing_svg(lines: list[WireLine]) -> str:
    """A sequence diagram of ``lines``: the driver in the middle, the controller right,
    each arrow labelled with the line and what it is."""
    step, top = 34, 70
    height = top + step * (len(lines) + 1) + 30
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' viewBox='-40 0 940 {height}' "
           f"width='100%' role='img' aria-label='The lines of one move on the wire'>",
           "<defs><marker id='arrow' viewBox='0 0 10 10' refX='10' refY='5' "
           "markerWidth='8' markerHeight='8' orient='auto-start-reverse'>"
           "<path d='M0,0 L10,5 L0,10 z' fill='currentColor'/></marker></defs>",
           "<g fill='currentColor' stroke='currentColor'>"]
    titles = {"code": "await move_to(x=10, y=5)", "driver": "tango_aio",
              "tango": "TANGO (emulator)"}
    for lane, x in _LANES.items():
        out.append(f"<text x='{x}' y='30' text-anchor='middle' stroke='none' {_FONT} "
                   f"font-weight='bold'>{escape(titles[lane])}</text>")
        out.append(f"<line x1='{x}' y1='42' x2='{x}' y2='{height - 20}' "
                   f"stroke-dasharray='4 4' stroke-width='1'/>")
    y = top
    out.append(f"<line x1='{_LANES['code']}' y1='{y}' x2='{_LANES['driver']}' y2='{y}' "
               f"stroke-width='1.5' marker-end='url(#arrow)'/>")
    out.append(f"<text x='{(_LANES['code'] + _LANES['driver']) / 2}' y='{y - 6}' "
               f"text-anchor='middle' stroke='none' {_FONT}>move_to</text>")
    for line in lines:
        y += step
        start, end = ("driver", "tango") if line.sent else ("tango", "driver")
        out.append(f"<line x1='{_LANES[start]}' y1='{y}' x2='{_LANES[end]}' y2='{y}' "
                   f"stroke-width='1.5' marker-end='url(#arrow)' class='wire-line'/>")
        out.append(f"<text x='{(_LANES['driver'] + _LANES['tango']) / 2}' y='{y - 6}' "
                   f"text-anchor='middle' stroke='none' {_FONT}>{escape(line.text)}</text>")
        out.append(f"<text x='{_LANES['tango'] + 20}' y='{y + 4}' stroke='none' "
                   f"{_FONT}>{escape(line.meaning)}</text>")
    y += step
    out.append(f"<line x1='{_LANES['driver']}' y1='{y}' x2='{_LANES['code']}' y2='{y}' "
               f"stroke-width='1.5' marker-end='url(#arrow)'/>")
    out.append(f"<text x='{(_LANES['code'] + _LANES['driver']) / 2}' y='{y - 6}' "
               f"text-anchor='middle' stroke='none' {_FONT}>returns the letters</text>")
    out.append("</g></svg>")
    return "\n".join(out)


def raster_svg(run: RasterRun) -> str:
    """The scan's path (a line through the positions read after each move), the trigger
    list on every row (ticks) and the pulses where the emulator fired them (dots)."""
    width, height, margin = 640, 320, 60
    x_max = X_END
    y_max = max((ROWS - 1) * ROW_STEP, ROW_STEP)

    def sx(x: float) -> float:
        return margin + (width - 2 * margin) * x / x_max

    def sy(y: float) -> float:
        return height - margin - (height - 2 * margin) * y / y_max

    out = [f"<svg xmlns='http://www.w3.org/2000/svg' viewBox='0 0 {width} {height}' "
           f"width='100%' role='img' aria-label='A raster scan and its trigger pulses'>",
           "<defs><marker id='head' viewBox='0 0 10 10' refX='10' refY='5' "
           "markerWidth='7' markerHeight='7' orient='auto-start-reverse'>"
           "<path d='M0,0 L10,5 L0,10 z' fill='currentColor'/></marker></defs>",
           "<g fill='currentColor' stroke='currentColor'>",
           f"<line x1='{sx(0)}' y1='{sy(0) + 20}' x2='{sx(x_max)}' y2='{sy(0) + 20}' "
           f"stroke-width='1'/>",
           f"<text x='{sx(x_max / 2)}' y='{height - 8}' text-anchor='middle' stroke='none' "
           f"{_FONT}>X (mm)</text>",
           f"<text x='14' y='{sy(y_max / 2)}' stroke='none' {_FONT}>Y</text>"]
    for x in (0.0, 1.0, 2.0, 3.0):
        out.append(f"<text x='{sx(x)}' y='{sy(0) + 36}' text-anchor='middle' "
                   f"stroke='none' {_FONT}>{x:g}</text>")
    for row in range(ROWS):
        y = row * ROW_STEP
        out.append(f"<text x='{margin - 30}' y='{sy(y) + 4}' stroke='none' {_FONT}>"
                   f"{y:g}</text>")
        for position in POSITIONS:
            out.append(f"<line x1='{sx(position)}' y1='{sy(y) - 7}' x2='{sx(position)}' "
                       f"y2='{sy(y) + 7}' stroke-width='1' opacity='0.5' class='listed'/>")
    # The path, segment by segment: a pass in +X solid, a return dashed and drawn a few
    # pixels below its row (it runs over the very same line), a step in Y dotted.
    for (x0, y0), (x1, y1) in zip(run.path, run.path[1:], strict=False):
        if (x0, y0) == (x1, y1):
            continue
        back = x1 < x0
        shift = 9 if back else 0
        style = "stroke-dasharray='6 4'" if back else (
            "stroke-dasharray='2 3'" if x0 == x1 else "")
        out.append(f"<line x1='{sx(x0):.1f}' y1='{sy(y0) + shift:.1f}' x2='{sx(x1):.1f}' "
                   f"y2='{sy(y1) + shift:.1f}' stroke-width='1.5' {style} "
                   f"marker-end='url(#head)' class='path'/>")
    for x, y in run.pulses:
        out.append(f"<circle cx='{sx(x):.1f}' cy='{sy(y):.1f}' r='4' stroke='none' "
                   f"class='pulse'/>")
    out.append(f"<text x='{sx(x_max)}' y='18' text-anchor='end' stroke='none' {_FONT}>"
               f"{len(run.pulses)} pulses (dots) at {len(POSITIONS)} listed positions "
               f"(ticks) on {ROWS} rows; ?trigcount = {run.count}</text>")
    out.append(f"<text x='{sx(x_max)}' y='34' text-anchor='end' stroke='none' {_FONT}>"
               f"solid: passes in +X (they fire); dashed, just below: returns (none)"
               f"</text>")
    out.append("</g></svg>")
    return "\n".join(out)


def draw(name: str) -> str:
    """The SVG of picture ``name`` (``reply-routing`` or ``raster-scan``), from a run of
    the emulator now."""
    if name == "reply-routing":
        return routing_svg(asyncio.run(record_move()))
    if name == "raster-scan":
        return raster_svg(asyncio.run(record_raster()))
    raise ValueError(f"no picture {name!r}: reply-routing or raster-scan")


class Picture(Directive):
    """``{tango-picture} NAME``: the SVG of :func:`draw`, inline."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        svg = draw(self.arguments[0])
        return [nodes.raw("", f"<figure class='tango-picture'>{svg}</figure>",
                          format="html")]


def setup(app: Any) -> dict[str, Any]:
    """Register the ``tango-picture`` directive."""
    app.add_directive("tango-picture", Picture)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
