"""The documentation's pictures (docs/_ext/tango_pictures.py, issue 30 item 9) show what
a real run of the emulator did: every line of the move on the wire, each reply joined to
its request, and the raster scan's pulses where the emulator fired them."""

from __future__ import annotations

import importlib.util
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path
from types import ModuleType

EXT = Path(__file__).resolve().parents[2] / "docs" / "_ext" / "tango_pictures.py"
SVG = "{http://www.w3.org/2000/svg}"


def _pictures() -> ModuleType:
    spec = importlib.util.spec_from_file_location("tango_pictures", EXT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("tango_pictures", module)
    spec.loader.exec_module(module)
    return module


async def test_the_reply_routing_picture_is_the_wire_log_of_one_move() -> None:
    pictures = _pictures()
    lines = await pictures.record_move()
    sent = [line.text for line in lines if line.sent]
    received = {line.text: line.meaning for line in lines if not line.sent}
    # The confirmation reads the letters with sa, ?statusaxis spelt short (#28).
    assert "!moa 10.0 5.0" in sent and "sa" in sent
    assert received["@@@-."].startswith("completion report")
    assert received["@@@-.-"] == "reply to sa"
    assert received["10.0000 5.0000 0.0000"] == "reply to ?pos"
    # Every reply answers a read sent before it: as many replies as reads.
    reads = [line for line in lines
             if line.sent and (line.text.startswith("?") or line.text == "sa")]
    replies = [line for line in lines if not line.sent and line.meaning.startswith("reply")]
    assert len(reads) == len(replies)
    svg = ElementTree.fromstring(pictures.routing_svg(lines))
    arrows = svg.findall(f".//{SVG}line[@class='wire-line']")
    assert len(arrows) == len(lines)
    texts = {element.text for element in svg.iter(f"{SVG}text")}
    assert "!moa 10.0 5.0" in texts and "reply to sa" in texts


async def test_the_raster_picture_shows_where_the_emulator_fired() -> None:
    pictures = _pictures()
    run = await pictures.record_raster()
    assert run.count == len(run.pulses) == pictures.ROWS * len(pictures.POSITIONS)
    rows = {y for _, y in run.pulses}
    assert rows == {row * pictures.ROW_STEP for row in range(pictures.ROWS)}
    assert sorted({x for x, _ in run.pulses}) == pictures.POSITIONS
    assert run.path[-1] == (0.0, (pictures.ROWS - 1) * pictures.ROW_STEP)
    svg = ElementTree.fromstring(pictures.raster_svg(run))
    assert len(svg.findall(f".//{SVG}circle[@class='pulse']")) == run.count
    assert len(svg.findall(f".//{SVG}line[@class='listed']")) == \
        pictures.ROWS * len(pictures.POSITIONS)
