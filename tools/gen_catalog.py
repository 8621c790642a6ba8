"""Generate ``tango_aio/catalog/_table.py`` from the shared reference ``instructions.json``.

The JSON holds what the manual says about each instruction; this script turns it into the
package's compact, typed table. Where the JSON is ambiguous or the manual (firmware 1.71)
says more, the ``OVERRIDES`` below decide, each with the manual line it comes from.

The tables are written in a short notation (``F("velocity", 0, 200)`` for a float
parameter, ``S(OPT, per_axis=...)`` for a signature); :func:`instruction` evaluates an
entry's notation into :mod:`tango_aio.catalog._schema` objects and :func:`literal` writes those as
plain keyword constructor calls, so the generated module holds only data.

Run from the repository root::

    python tools/gen_catalog.py [path/to/instructions.json]

``tests/unit/test_catalog_sync.py`` checks that the committed table matches this script's output.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import re
import sys
import types
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if "tango_aio" not in sys.modules:
    # Load the schema and the reply rules without the package's __init__, which imports
    # the catalog that this script writes (it may be stale or missing).
    _package = types.ModuleType("tango_aio")
    _package.__path__ = [str(ROOT / "tango_aio")]
    sys.modules["tango_aio"] = _package

from tango_aio.catalog import _replyrules as replyrules  # noqa: E402
from tango_aio.catalog import _schema as schema  # noqa: E402
from tango_aio.catalog._schema import Form, Instruction, Param, Precision, Signature  # noqa: E402

DEFAULT_JSON = ROOT / "reference" / "instructions.json"
OUTPUT = ROOT / "tango_aio" / "catalog" / "_table.py"

# --------------------------------------------------------------------------------------
# Decisions the JSON leaves open. Keys are instruction names.

#: Instructions whose every parameter belongs to the read form (``?x n``) although they
#: also have a ``!`` form; the value is the list of read-only parameter names.
READ_ONLY_PARAMS: dict[str, list[str]] = {
    "pa": ["read_option"],
    "calbspeed": ["all_axes_read"],
    "calrefspeed": ["all_axes_read"],
}

#: Read-side lead parameters written out explicitly (Python source of Param tuples).
READ_LEAD: dict[str, str] = {
    "trigp": 'N("index", -1, 10000, optional=True)',
    "snsa": 'N("index", -1, 1024)',
    # '?snsv n': 1 to 1024 or -1 to -1024; 0 is no entry (L15444, L15460).
    "snsv": 'N("index", -1024, 1024, min_abs=1)',
    "joyspeed": 'C("button", 1, 2, 3, optional=True)',
    "zwtravel": 'C("index", 1, 2, 3, optional=True)',
    "clim": 'C("active", 1, optional=True)',
    "drop": 'C("query", 0, optional=True)',
    "enctype": 'C("applied", 1, optional=True)',
    "enc": 'C("once_activated", 1, optional=True)',
    "adiginfunc": 'N("input", 0, 3, optional=True)',
    "anaout": 'C("keyword", "c", optional=True), N("channel", 0, 2, optional=True)',
    "ctrd": 'C("all_axes", -1, optional=True)',
    "keyl": 'N("key", 1, 4, optional=True)',
    "lock": 'N("bit", 0, 15, optional=True)',
    "hdimode": 'N("bit", 0, 15, optional=True)',
    **{name: f'N("index", 0, {width - 1}, optional=True)' for name, width in {
        "digout": 8, "diginpol": 24, "digintyp": 6, "digoutpreset": 8, "edigout": 8,
        "ediginpol": 12, "edigintyp": 12, "edigoutpreset": 8, "adigintyp": 4, "adigout": 4,
    }.items()},
}

#: Bit-field parameters "0/1 string or index + state": name → number of bits.
BIT_FIELDS: dict[str, int] = {
    "lock": 16, "hdimode": 16, "digout": 8, "diginpol": 24, "digintyp": 6,
    "digoutpreset": 8, "edigout": 8, "ediginpol": 12, "edigintyp": 12, "edigoutpreset": 8,
    "adigintyp": 4, "adigout": 4,
}

#: Write signatures spelled out where the generic rules do not fit.
WRITE_OVERRIDES: dict[str, str] = {
    # '!trigp [axis] index [position]' (L13767-13802): the axis letter selects triga.
    # '!trigp y 11.5' (example L13971) sets the axis and appends one position.
    "trigp": 'S(OPT, lead=(N("index", -1, 10000), F("position", optional=True))), '
             'S(REQ, lead=(F("position"),))',
    # trigm 20/21 are set by trigr/trigp but may be written too (examples L13628, L14000).
    "trigm": 'S(NONE, lead=(C("mode", *range(12), 20, 21, *range(100, 106)),))',
    # '!trigr [axis] start end count' (L13496).
    "trigr": 'S(OPT, lead=(F("start"), F("end"), N("count", 1, 10000)))',
    # '!snsa [axis] index pos...' (L15324-15389): index, then one position per axis;
    # '!snsa 0' clears.
    "snsa": 'S(OPT, lead=(N("index", -1, 1024),), per_axis=(F("position"),), min_groups=0)',
    # '!clim r' or '!clim x y r' (L4622-4700); '!clim 0' disables.
    "clim": 'S(NONE, lead=(F("radius", 0),)), '
            'S(NONE, lead=(F("center_x"), F("center_y"), F("radius", 0)))',
    # '!anaout l0 [l1 [l2]]' or '!anaout c|p channel level' (L9512-9516); ?anaout
    # reports three channels (L9564), so a third level is accepted.
    "anaout": 'S(NONE, lead=(F("level", 0, 100), F("level1", 0, 100, optional=True), '
              'F("level2", 0, 100, optional=True))), '
              'S(NONE, lead=(C("keyword", "c", "p"), N("channel", 0, 2), F("level", 0, 100)))',
    # '!adiginfunc input fn', '!adiginfunc f0 f1 f2 f3' or '!adiginfunc -1' (L9247-9259).
    "adiginfunc": 'S(NONE, lead=(N("input", 0, 3), C("function", 0, 1, 2))), '
                  'S(NONE, lead=(C("f0", 0, 1, 2), C("f1", 0, 1, 2), C("f2", 0, 1, 2), '
                  'C("f3", 0, 1, 2))), S(NONE, lead=(C("reset", -1),))',
    # '!joyspeed button speed' (L7356-7391).
    "joyspeed": 'S(NONE, lead=(C("button", 1, 2, 3), F("speed", 0.000001, 200)))',
    "zwtravel": 'S(NONE, lead=(C("index", 1, 2, 3), F("travel", -50, 50)))',
    "snsv": 'S(NONE, lead=(N("index", 1, 1024), I("value")))',
    # '!restore' reloads the saved set, 'restore -1' restores factory defaults (L1791-1813).
    "restore": 'S(NONE, lead=(C("mode", -1, optional=True),))',
    # '!trigc n' shortens the list, '!trigc' or '!trigc 0' clears (L14100-14129).
    "trigc": 'S(NONE, lead=(N("entries", 0, 10000, optional=True),))',
    "trigi": 'S(NONE, lead=(N("index", 1, 10000, optional=True),))',
    "snsc": 'S(NONE, lead=(N("entries", 0, 1024, optional=True),))',
    "snsi": 'S(NONE, lead=(N("index", 0, 1023, optional=True),))',
    "keyl": 'S(NONE, lead=(N("key", 1, 4, optional=True),))',
    # 'a [axis] [-1]' (L6785-6844).
    "a": 'S(OPT, lead=(C("mode", -1, optional=True),))',
    # 'brakepos axis [1|-1]' (L10132).
    "brakepos": 'S(REQ, lead=(C("direction", 1, -1, optional=True),))',
    # 'go' without values stops all axes, 'go y' stops Y (L6598-6712).
    "go": 'S(OPT, per_axis=(F("position"),), min_groups=0)',
    # '!posclr [axis]' clears the offset (L6960).
    "posclr": "S(OPT)",
    # '!lim z 45.37' sets only the lower limit (example L4605).
    "lim": 'S(OPT, per_axis=(F("lower"), F("upper", optional=True)))',
    # '!flash ms': +-0.00001 .. +-32500 ms, the sign selects the polarity (L9864-9883).
    "flash": 'S(NONE, lead=(F("duration", -32500, 32500, min_abs=0.00001),))',
    # '!encerr 0' resets the encoder error state (L11149).
    "encerr": 'S(OPT, lead=(C("reset", 0),))',
    # 'cur' upper bound is ?maxcur, checked by the controller (error 5, L3705).
    "cur": 'S(OPT, per_axis=(F("current", 0.03),))',
    # '!twi' window 0.00001 mm .. 1 mm in dim units (L12104); bounds depend on dim.
    "twi": 'S(OPT, per_axis=(F("window", 0),))',
    "ctrs": 'S(OPT, per_axis=(F("lock_in_range", 0),))',
    "caliboffset": 'S(OPT, per_axis=(F("offset", 0),))',
    "rmoffset": 'S(OPT, per_axis=(F("offset", 0),))',
    "calpos": 'S(OPT, per_axis=(F("position", 0),))',
    "trigd": 'S(NONE, lead=(F("distance", 0, 5000000),))',
    # '!encpos 1' applies to all axes; '!encpos 1 1 0' is invalid (L11214-11232).
    "encpos": 'S(ALL, per_axis=(C("source", 0, 1),))',
    # 'vel' is up to 3000 mm/s in dim 9 (L3457).
    "vel": 'S(OPT, per_axis=(F("velocity", 0.000001, 200, unit="rev/s", hi_dim9=3000),))',
    "joyvel": 'S(OPT, per_axis=(F("velocity", 0.000001, 200, unit="rev/s", hi_dim9=3000),))',
    # '!mrp x 0 0' gives only the sine values (example L11468).
    "mrp": 'S(OPT, per_axis=(N("sin_max", -2048, 2048), N("sin_min", -2048, 2048), '
           'N("cos_max", -2048, 2048, optional=True), '
           'N("cos_min", -2048, 2048, optional=True)))',
    # Word choices: '!tvrjoy 0/z/a' (L8035-8085), '!zwaxis a' (L7927), '!triga x' (L12837).
    "tvrjoy": 'S(NONE, lead=(C("assign", "0", "z", "a"),))',
    "zwaxis": 'S(NONE, lead=(C("axis", "x", "y", "z", "a"),))',
    "triga": 'S(NONE, lead=(C("axis", "x", "y", "z", "a"),))',
    "zwpos": 'S(NONE, lead=(I("counter"),))',
    "trigcount": 'S(NONE, lead=(N("count", 0, 2147483647),))',
    "motortable": 'S(OPT, per_axis=(N("table", 0),))',
    "lockaxis": 'S(OPT, per_axis=(C("apply", 0, 1),))',
    "speed": 'S(OPT, per_axis=(F("speed", -100, 100, unit="rev/s", hi_dim9=3000),))',
}

#: Read signatures spelled out.
READ_OVERRIDES: dict[str, str] = {
    "help": 'S(NONE, lead=(I("error_number", optional=True),))',
    "anain": 'S(NONE, lead=(C("keyword", "c", "v"), N("channel", 0, 31)))',
    # '?mrt n': 1 to 32767 or -1 to -32767 samples (L11479); 0 is no count.
    "mrt": 'S(OPT, lead=(N("samples", -32767, 32767, min_abs=1, optional=True),))',
    "encamp": 'S(OPT, lead=(C("decimals", 1, optional=True),))',
    "stagesn": 'S(NONE, lead=(C("ets_address", -1, 0, 1, 2, 3, optional=True),))',
    "version": 'S(NONE, lead=(C("version_only", 1, optional=True),))',
    "maxcur": 'S(OPT, lead=(C("ets_limit", 1, optional=True),))',
    "ctrstatus": 'S(OPT, lead=(C("query", 0, 1, 2, 3, optional=True),))',
    "ctrdiff": 'S(OPT, lead=(C("option", 1, 2, 3, 4, optional=True),))',
    "encsync": 'S(OPT, lead=(C("detail", -1, optional=True),))',
    "hdi": 'S(NONE, lead=(C("verbose", -1, optional=True),))',
    "key": 'S(NONE, lead=(N("key", 1, 4, optional=True),))',
    "swin": 'S(NONE, lead=(N("index", 0, 7, optional=True),))',
    "digin": 'S(NONE, lead=(N("input", 0, 23, optional=True),))',
    "edigin": 'S(NONE, lead=(N("input", 0, 11, optional=True),))',
    "adigin": 'S(NONE, lead=(N("input", 0, 3, optional=True),))',
    "pa": 'S(NONE, lead=(C("all_axes", -1, optional=True),))',
    "calbspeed": 'S(OPT, lead=(C("all_axes", -1, optional=True),))',
    "calrefspeed": 'S(OPT, lead=(C("all_axes", -1, optional=True),))',
    # 'trigr' and 'trigp' reads take no axis letter.
    "trigr": "S(NONE)",
    "snsa": 'S(OPT, lead=(N("index", -1, 1024),))',
    # '?trigp x 3' names the axis redundantly (L14064).
    "trigp": 'S(OPT, lead=(N("index", -1, 10000, optional=True),))',
}

#: Reply shapes (of the read form) where the generic rules guess wrong.
REPLY: dict[str, str] = {
    "version": "VERSION", "det": "DET", "detext": "LINES", "readsn": "TEXT", "ver": "TEXT",
    "iver": "TEXT", "uptime": "INT", "temp": "FLOAT", "maxaxis": "TEXT", "maxcur": "NUMBERS",
    "etspresent": "FLAGS", "stagesn": "TEXT", "save": "NONE", "restore": "ACK",
    "status": "ACK", "err": "ERROR_NUMBER", "help": "HELP", "service": "LINES",
    "statusaxis": "STATUS", "lockstate": "AXES_TEXT", "readsw": "FLAGS", "swin": "FLAGS",
    "statuslimit": "FLAGS", "lock": "FLAGS", "hdimode": "FLAGS", "digin": "FLAGS",
    "digout": "FLAGS", "diginpol": "FLAGS", "digintyp": "FLAGS", "digoutpreset": "FLAGS",
    "edigin": "FLAGS", "edigout": "FLAGS", "ediginpol": "FLAGS", "edigintyp": "FLAGS",
    "edigoutpreset": "FLAGS", "adigin": "FLAGS", "adigintyp": "FLAGS", "adigout": "FLAGS",
    "adiginfunc": "INTS", "key": "INTS", "keyl": "INTS", "anain": "FLOAT",
    "anaout": "NUMBERS", "hdi": "TEXT", "encsync": "TEXT", "encerr": "AXES_TEXT",
    "mrt": "LINES", "trigr": "NUMBERS", "trigs": "INTS", "clim": "NUMBERS",
    "zwtravel": "NUMBERS", "pa": "INTS", "tvrjoy": "TEXT", "zwaxis": "TEXT",
    "triga": "TEXT", "trigp": "FLOAT", "snsv": "FLOAT", "joyspeed": "FLOAT",
    "ctrstatus": "AXES_TEXT", "ctrd": "INTS", "snsa": "AXES_FLOAT", "calbspeed": "NUMBERS",
    "calrefspeed": "NUMBERS", "encpos": "INT", "pci": "INT", "zwheel": "INT", "drop": "INT",
    "trigbdelay": "FLOAT", "trigbwidth": "FLOAT", "trigbf": "FLOAT", "trigd": "FLOAT",
    "trigf": "FLOAT", "scanvel": "FLOAT", "tvrjoyf": "FLOAT", "flash": "NONE",
    "snse": "NONE", "trigger": "NONE", "ctrdiff": "AXES_FLOAT", "encamp": "AXES_FLOAT",
    "calst": "AXES_INT", "corrst": "AXES_INT", "encrefstatus": "AXES_INT",
    "encrefstatusl": "AXES_INT", "encnasstatus": "AXES_INT", "hwcount": "AXES_INT",
    "motorsteps": "AXES_INT", "curdelay": "AXES_INT", "ecomove": "AXES_INT",
    "ctrf": "AXES_INT", "mro": "AXES_INT", "mrp": "AXES_INT", "caltimeout": "AXES_INT",
    "brake": "AXES_INT", "lockaxis": "AXES_INT", "zwpos": "INT", "trigcount": "INT",
}

#: Reads whose first value changes the number of reply values per axis.
OPTION_GROUPS: dict[str, str] = {
    # '?ctrstatus 0' → '2 7 2 7 0 0', mode and state bits per axis (L12348-12395).
    "ctrstatus": "((0, 2),)",
}

#: Per-axis single-digit replies that the controller may print without the space between
#: axis groups: '?swtyp' in extmode 0 → '1 1 11 1 11 1 1' (L4818-4822); swpol and swact
#: share the E0 REF EE reply format (L4888, L4958).
DIGIT_VALUES = {"swtyp", "swpol", "swact"}

#: Replies that come from the executing form (``save`` always answers, L1723-1760).
EXEC_REPLY: dict[str, str] = {"save": "ACK"}

#: Multi-line reply rules: the name of a function of ``tango_aio/catalog/_replyrules.py``.
LINES: dict[str, str] = {
    "service": "service_lines",
    "detext": "detext_lines",
    "mrt": "mrt_lines",
    "lim": "grouped_lines",
    "swtyp": "grouped_lines",
    "swpol": "grouped_lines",
    "swact": "grouped_lines",
}

#: Completion kinds of executing forms.
COMPLETION: dict[str, str] = {
    "moa": "MOVE", "mor": "MOVE", "m": "MOVE", "moc": "MOVE", "mol": "MOVE",
    "cal": "CAL", "rm": "RM",
}

#: How executing an instruction changes the autostatus mode.
MODE_EFFECT: dict[str, str] = {
    "autostatus": "VALUE",  # '!autostatus n' (L2060-2168)
    "reset": "RESTART",  # restart like power on, mode 1 (L1837-1857, L2062)
    "restore": "RESTART_IF_MINUS_ONE",  # 'restore -1' resets and restarts (L1805-1813)
}

#: Instructions that the older edition documents without parameters although 1.71 has
#: some: 'help' (old L805-819: "Parameter: none"), 'version' (old L414).
OLDER_WITHOUT_VALUES = {"help", "version"}

#: Bare forms that execute (``restore``) where the JSON offers all three forms.
BARE_EXECUTES = {"restore"}

#: Settings the driver caches (move timing and the validation context), with the
#: attribute of ``tango_aio.sansio._state.DriverState`` that mirrors them: dim (L3061), pitch
#: (L3145), accel (L3298), vel (L3452) and secvel (L3568) time a move, extmode (L2236)
#: changes the '?lim' layout (L4559-4621), delay and
#: pause wait before and after moa/mor/m/moc (L6845-6899), ctrt is the longest
#: closed-loop settling (L11616-11631).
CACHED: dict[str, str] = {
    "dim": "dims", "pitch": "pitch", "vel": "vel", "accel": "accel", "secvel": "secvel",
    "extmode": "extmode", "delay": "delay_ms", "pause": "pause_ms", "ctrt": "settle_ms",
}

#: Power-on / factory defaults where the manual states them; the emulator starts
#: everything else at the first allowed value or 0.
DEFAULTS: dict[str, tuple[int | float | str, ...]] = {
    "baud": (57600,), "cts": (0,), "ipreter": (1,), "autostatus": (1,), "extmode": (0,),
    "scanmode": (0,), "scanvel": (10.0,), "dim": (2,), "pitch": (1.0,), "gear": (1.0,),
    "motorsteps": (200,), "accel": (1.0,), "stopaccel": (1.0,), "vel": (10.0,),
    "velfac": (1.0,), "secvel": (10.0,), "cur": (1.0,), "reduction": (1.0,),
    "curdelay": (1000,), "axis": (1,), "usteps": (40000,), "resolution": (4,),
    "swtyp": (1, 1, 1), "swpol": (0, 0, 0), "swact": (1, 0, 1), "limctr": (1,),
    "caltimeout": (40,), "calbspeed": (32.0,), "calrefspeed": (32.0,),
    "calvel": (10.0, 0.5), "rmvel": (10.0, 0.5), "joy": (2,), "joydir": (1,),
    "joywindow": (14,), "joyvel": (10.0,), "joyspeed": (1.0,), "keyspeed": (1.0, 10.0),
    "hwfilter": (1,), "tbfactor": (1.0,), "zwaxis": ("z",), "zwfactor": (1,),
    "zwtravel": (1.0,), "tvrjoyf": (1.0,), "hwfactor": (1.0,), "hwfactorb": (1.0,),
    "pa": (1,), "encvel": (0.5,), "encperiod": (0.02,), "encrefvel": (1.0,), "ctr": (2,),
    "ctrf": (2.0,), "ctrff": (2.0, 2.0), "ctrd": (10,), "ctrt": (1000,), "ctrc": (1,),
    "twi": (0.001,), "ctrs": (0.5,), "mra": (1.0,), "trigf": (1000.0,), "trigbf": (1000.0,),
    "trigbwidth": (40.0,), "trigs": (40,), "trigo": (1,), "triga": ("x",), "trigl": (1,),
    "sns": (1,), "snsf": (10,), "anaout": (0.0,), "trigd": (1.0,), "noled": (0,),
}

#: Settings written as ``index value`` (``!joyspeed 2 25``, ``!anaout c 1 25.3``): the
#: power-on value of each index. adiginfunc: "SnapShot is assigned to the SnapShot input
#: (3) and stop ... to the not available input 2" (L9195); zwtravel presets 0.1 / 0.01 /
#: 1.0 mm/rev (L7863); anaout channels 0-2 at 0 %. The joyspeed presets are not
#: documented: chosen.
INDEXED: dict[str, tuple[int | float | str, ...]] = {
    "adiginfunc": (0, 0, 1, 2),
    "zwtravel": (0.1, 0.01, 1.0),
    "joyspeed": (1.0, 10.0, 30.0),
    "anaout": (0.0, 0.0, 0.0),
}

#: Fractional digits of float replies, from the manual's examples (protocol_notes §3).
DIGITS: dict[str, int] = {
    "vel": 3, "secvel": 2, "accel": 2, "stopaccel": 2, "cur": 2, "iscur": 2, "pitch": 4,
    "gear": 3, "keyspeed": 2, "calvel": 3, "rmvel": 3, "ctrff": 1, "anaout": 2,
    "scanvel": 6, "trigbf": 3, "trigbdelay": 2, "trigbwidth": 2, "isvel": 3,
    "encperiod": 4, "velfac": 2, "reduction": 2, "joyvel": 3, "encrefvel": 3, "encvel": 3,
    "speed": 3, "calbspeed": 1, "calrefspeed": 1, "mra": 4, "trigf": 2, "joyspeed": 3,
    "zwtravel": 3, "tvrjoyf": 3, "hwfactor": 3, "hwfactorb": 3, "tbfactor": 3,
    "backlash": 1, "temp": 1, "flash": 3, "encamp": 0, "ctrf": 0,
}

#: Replies in position units, printed with ``resolution`` digits (L4144).
POSITION_VALUED = {
    "pos", "lim", "maxpos", "posclr", "distance", "twi", "ctrs", "ctrdiff", "caliboffset",
    "rmoffset", "calpos", "calzeropos", "trigd", "snsa", "snsp", "snsj", "prehome", "home",
    "lockpos", "trigp", "trigr", "clim", "vrm",
}

#: Instruction fields whose value a table gives as it is.
VALUE_FIELDS: dict[str, dict[str, Any]] = {
    "cached": CACHED, "default": DEFAULTS, "indexed": INDEXED, "digits": DIGITS,
}

#: Instruction flags that are true for the names of a set.
FLAG_FIELDS: dict[str, set[str]] = {
    "digit_values": DIGIT_VALUES, "position_valued": POSITION_VALUED,
}

# --------------------------------------------------------------------------------------


def _num(value: Any) -> str | None:
    if isinstance(value, int | float) and not isinstance(value, bool):
        return repr(value)
    return None


def param_source(p: dict[str, Any], *, optional: bool | None = None) -> str:
    """Python source of one parameter."""
    opt = p["optional"] if optional is None else optional
    tail = ", optional=True" if opt else ""
    kind = p["type"]
    unit = p.get("unit")
    unit_src = f", unit={unit!r}" if unit and kind == "float" and len(str(unit)) < 40 else ""
    if kind == "enum":
        choices = ", ".join(repr(c) for c in p["values"])
        return f'C({p["name"]!r}, {choices}{tail})'
    lo = hi = None
    rng = p.get("range")
    if isinstance(rng, list) and len(rng) == 2:
        lo, hi = _num(rng[0]), _num(rng[1])
    bounds = ""
    if lo is not None:
        bounds += f", {lo}"
        if hi is not None:
            bounds += f", {hi}"
    elif hi is not None:
        bounds += f", None, {hi}"
    if kind == "float":
        return f'F({p["name"]!r}{bounds}{unit_src}{tail})'
    if kind == "int":
        return f'N({p["name"]!r}{bounds}{tail})' if bounds else f'I({p["name"]!r}{tail})'
    return f'I({p["name"]!r}{tail})'


def axis_rule(entry: dict[str, Any], *, write: bool) -> str:
    mode = entry["axis_param_mode"]
    if mode == "none":
        return "NONE"
    if mode in ("recommended", "optional_or_-1"):
        return "ALL" if write else "OPT"
    if mode == "required_for_set":
        return "REQ" if write else "OPT"
    if mode == "required":
        return "REQ"
    return "OPT"


def bits_signatures(name: str, entry: dict[str, Any]) -> str:
    width = BIT_FIELDS[name]
    return (f'S(NONE, lead=(B("bits", {width}),)), '
            f'S(NONE, lead=(N("index", 0, {width - 1}), C("state", 0, 1)))')


def write_source(name: str, entry: dict[str, Any]) -> str | None:
    forms = entry["forms"]
    executes = "!" in forms or (name in BARE_EXECUTES)
    if not executes:
        return None
    if name in WRITE_OVERRIDES:
        return WRITE_OVERRIDES[name]
    if name in BIT_FIELDS:
        return bits_signatures(name, entry)
    read_only = set(READ_ONLY_PARAMS.get(name, []))
    params = [p for p in entry["params"] if p["name"] not in read_only]
    rule = axis_rule(entry, write=True)
    if entry["per_axis_values"] and params:
        k = entry["values_per_axis"] or 1
        group = ", ".join(param_source(p, optional=i > 0 and p["optional"])
                          for i, p in enumerate(params[:k]))
        lead = params[k:]
        lead_src = f"lead=({', '.join(param_source(p) for p in lead)},), " if lead else ""
        return f"S({rule}, {lead_src}per_axis=({group},))"
    if not params:
        return f"S({rule})"
    lead_src = ", ".join(param_source(p) for p in params)
    return f"S({rule}, lead=({lead_src},))"


def read_source(name: str, entry: dict[str, Any]) -> str | None:
    forms = entry["forms"]
    reads = "?" in forms or ("bare" in forms and "!" not in forms) or name in ("err", "keyl",
                                                                                 "zwpos")
    if not reads:
        return None
    if name in READ_OVERRIDES:
        return READ_OVERRIDES[name]
    rule = axis_rule(entry, write=False)
    precision = ""
    rp = entry.get("read_precision")
    if entry["read_precision_arg"] and rp and rp.get("digits_range") == "0..16":
        precision = f", precision=P(0, 16, {rp['default_digits']})"
    elif entry["read_precision_arg"] and rp and rp.get("digits_range") == "0..10":
        precision = f", precision=P(0, 10, {rp['default_digits']})"
    elif entry["read_precision_arg"]:
        precision = ", precision=P(0, 16, None)"
    lead = READ_LEAD.get(name)
    if lead is None and "!" not in forms and entry["params"]:
        lead = ", ".join(param_source(p, optional=True) for p in entry["params"])
    lead_src = f", lead=({lead},)" if lead else ""
    return f"S({rule}{lead_src}{precision})"


def reply_shape(name: str, entry: dict[str, Any]) -> str:
    if name in REPLY:
        return REPLY[name]
    if read_source(name, entry) is None:
        return "NONE"
    params = entry["params"]
    if entry["per_axis_values"]:
        if params and params[0]["type"] in ("int", "enum"):
            return "AXES_INT"
        return "AXES_FLOAT"
    if params and params[0]["type"] == "float":
        return "FLOAT"
    return "INT"


def bare_mode(name: str, forms: list[str]) -> str:
    if "bare" not in forms:
        return "NONE"
    if name in BARE_EXECUTES or ("!" in forms and "?" not in forms):
        return "EXECUTE"
    return "READ"


def entry_source(entry: dict[str, Any]) -> str:
    name = entry["name"]
    forms = "".join(f for f in ("!", "?") if f in entry["forms"])
    if "bare" in entry["forms"]:
        forms += "b"
    summary = (entry["brief_table"] or {}).get("description") or entry["section_title"]
    parts = [repr(name), repr(summary.strip()), repr(forms)]
    bare = bare_mode(name, entry["forms"])
    if bare != "NONE":
        parts.append(f"bare=Bare.{bare}")
    if entry["aliases"]:
        parts.append(f"aliases={tuple(entry['aliases'])!r}")
    write = write_source(name, entry)
    if write:
        parts.append(f"write=({write},)")
    read = read_source(name, entry)
    if read:
        parts.append(f"read=({read},)")
    shape = reply_shape(name, entry)
    if shape != "NONE":
        parts.append(f"reply=Shape.{shape}")
    group = entry["values_per_axis"] or 1
    if group > 1 and shape.startswith("AXES"):
        parts.append(f"reply_group={group}")
    if name in OPTION_GROUPS:
        parts.append(f"option_groups={OPTION_GROUPS[name]}")
    if name in EXEC_REPLY:
        parts.append(f"exec_reply=Shape.{EXEC_REPLY[name]}")
    if name in COMPLETION:
        parts.append(f"completion=Completion.{COMPLETION[name]}")
    if name in LINES:
        parts.append(f"lines=replyrules.{LINES[name]}")
    if entry["saved"] in ("Y", "(Y)"):
        parts.append("saved=True")
    if name in MODE_EFFECT:
        parts.append(f"mode_effect=ModeEffect.{MODE_EFFECT[name]}")
    parts.extend(f"{field}={table[name]!r}" for field, table in VALUE_FIELDS.items()
                 if name in table)
    parts.extend(f"{field}=True" for field, names in FLAG_FIELDS.items() if name in names)
    if not entry["in_older_manual"]:
        parts.append("in_older_manual=False")
    if name in OLDER_WITHOUT_VALUES:
        parts.append("older_without_values=True")
    parts.append(f"section={entry['manual_section']!r}")
    parts.append(f"line={entry['manual_lines'][0]}")
    return "E(" + ", ".join(parts) + ")"


# --------------------------------------------------------------------------------------
# The short notation of the tables above: each helper makes one catalog object.

AxisRule, Kind = schema.AxisRule, schema.Kind
NONE, OPT, ALL, REQ = AxisRule.NONE, AxisRule.OPTIONAL, AxisRule.ALL, AxisRule.REQUIRED


def F(name: str, lo: float | None = None, hi: float | None = None, *, unit: str = "",
      hi_dim9: float | None = None, min_abs: float | None = None,
      optional: bool = False) -> Param:
    """A float parameter."""
    return Param(name, Kind.FLOAT, lo, hi, unit=unit, hi_dim9=hi_dim9, min_abs=min_abs,
                 optional=optional)


def N(name: str, lo: float | None = None, hi: float | None = None, *,
      min_abs: float | None = None, optional: bool = False) -> Param:
    """An integer parameter with a range."""
    return Param(name, Kind.INT, lo, hi, min_abs=min_abs, optional=optional)


def I(name: str, *, optional: bool = False) -> Param:  # noqa: E743
    """An integer parameter without a documented range."""
    return Param(name, Kind.INT, optional=optional)


def C(name: str, *choices: int | str, optional: bool = False) -> Param:
    """A parameter with a fixed set of values."""
    return Param(name, Kind.CHOICE, choices=choices, optional=optional)


def B(name: str, width: int) -> Param:
    """A string of up to ``width`` 0/1 characters."""
    return Param(name, Kind.BITS, width=width)


def P(lo: int, hi: int, default: int | None) -> Precision:
    """The read-precision (digit count) argument."""
    return Precision(lo, hi, default)


def S(axis: AxisRule, *, lead: tuple[Param, ...] = (), per_axis: tuple[Param, ...] = (),
      min_groups: int = 1, precision: Precision | None = None) -> Signature:
    """A signature."""
    return Signature(axis, lead, per_axis, min_groups, precision)


_FORMS = {"!": Form.SET, "?": Form.READ, "b": Form.BARE}


def E(name: str, summary: str, forms: str, **fields: Any) -> Instruction:
    """One catalog entry; ``forms`` is a string of ``!``, ``?`` and ``b`` (bare)."""
    return Instruction(name=name, summary=summary,
                       forms=frozenset(_FORMS[f] for f in forms), **fields)


_NOTATION: dict[str, Any] = {
    "NONE": NONE, "OPT": OPT, "ALL": ALL, "REQ": REQ, "F": F, "N": N, "I": I, "C": C,
    "B": B, "P": P, "S": S, "E": E, "Bare": schema.Bare, "Shape": schema.Shape,
    "Completion": schema.Completion, "ModeEffect": schema.ModeEffect,
    "replyrules": replyrules,
}


def instruction(entry: dict[str, Any]) -> Instruction:
    """The catalog object of one JSON ``entry`` (its notation evaluated)."""
    made: Instruction = eval(entry_source(entry), dict(_NOTATION))
    return made


# --------------------------------------------------------------------------------------
# Writing the objects as plain constructor calls


def literal(value: object) -> str:
    """Python source that constructs ``value``: schema types by keyword (fields at their
    default left out), enums by member, reply rules by their replyrules name."""
    if isinstance(value, enum.Enum):
        return f"{type(value).__name__}.{value.name}"
    if isinstance(value, types.FunctionType):
        assert getattr(replyrules, value.__name__) is value, value
        return f"replyrules.{value.__name__}"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _constructor(value)
    if isinstance(value, frozenset):
        members = sorted(value, key=_FORM_ORDER.index)
        return "frozenset({" + ", ".join(literal(m) for m in members) + "})"
    if isinstance(value, tuple):
        inner = ", ".join(literal(item) for item in value)
        return f"({inner},)" if len(value) == 1 else f"({inner})"
    assert value is None or isinstance(value, str | int | float), value
    return repr(value)


_FORM_ORDER = [Form.SET, Form.READ, Form.BARE]


def _constructor(value: Any) -> str:
    args = []
    for spec in dataclasses.fields(value):
        if not spec.init:
            continue
        item = getattr(value, spec.name)
        if spec.default is not dataclasses.MISSING and item == spec.default:
            continue
        args.append(f"{spec.name}={literal(item)}")
    return f"{type(value).__name__}({', '.join(args)})"


def _entry_text(made: Instruction) -> str:
    pad = " " * 8
    lines = [f"{pad}{name}={literal(getattr(made, name))}," for name in
             (spec.name for spec in dataclasses.fields(made))
             if name in ("name", "summary", "forms")
             or getattr(made, name) != _DEFAULTS[name]]
    return "    Instruction(\n" + "\n".join(lines) + "\n    ),"


_DEFAULTS = {spec.name: spec.default for spec in dataclasses.fields(Instruction)}


HEADER = '''"""The instruction table. GENERATED by tools/gen_catalog.py from the shared reference
(instructions.json, manual firmware 1.71): edit the generator's tables, not this file.

Pure data: one :class:`~tango_aio.catalog._schema.Instruction` per instruction of the manual, with
its forms (``!``, ``?``, bare), the write and read signatures (alternatives in order), the
reply shape of the read form, the completion kind, whether ``save`` stores it, and the
facts the driver and the emulator share (cached settings, defaults, reply digits).
"""

# ruff: noqa: E501

from __future__ import annotations

from . import _replyrules as replyrules
{imports}

CATALOG: tuple[Instruction, ...] = (
'''


def render(entries: list[dict[str, Any]]) -> str:
    """The full text of ``tango_aio/catalog/_table.py`` for the JSON ``entries``."""
    body = "\n".join(_entry_text(instruction(e)) for e in entries)
    used = [name for name in schema.__all__ if re.search(rf"\b{name}[(.]", body)]
    imports = "from ._schema import (\n" + "".join(f"    {name},\n" for name in used) + ")"
    return HEADER.replace("{imports}", imports) + body + "\n)\n"


def load(source: Path = DEFAULT_JSON) -> list[dict[str, Any]]:
    """Read the reference ``instructions.json``."""
    entries: list[dict[str, Any]] = json.loads(source.read_text(encoding="utf-8"))
    return entries


def main() -> None:
    source = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_JSON
    entries = load(source)
    OUTPUT.write_text(render(entries), encoding="utf-8", newline="\n")
    print(f"wrote {len(entries)} instructions to {OUTPUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
