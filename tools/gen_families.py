"""Generate ``tango_aio/families/_generated.py``: one typed accessor per instruction of the
manual's family chapters, from the instruction catalog and the shared reference; and
``tango_aio/sync/_generated.py``: the blocking twin of each accessor class.

Instructions are data: the catalog knows each instruction's forms, parameters, ranges and
per-axis shape; the reference (``reference/instructions.json``) adds the manual's section
title, its line range and the meaning of listed values. For every instruction of a family
chapter this writes a read method named after it (``joy()``) and a write method
``set_<name>(...)`` (an executing instruction without a read form: ``<name>(...)``), each
typed (float, int, bool for a 0/1 choice, a :class:`ManualEnum` where the manual lists
values) with a one-line docstring citing the manual's lines. Range checks are the
catalog's, before a byte is written.

Run from the repository root::

    python tools/gen_families.py

``tests/unit/test_families_sync.py`` checks that the committed modules are this output.
"""

from __future__ import annotations

import json
import keyword
import re
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tango_aio.catalog import (  # noqa: E402
    INSTRUCTIONS,
    AxisRule,
    Form,
    Instruction,
    Kind,
    Param,
    Shape,
    Signature,
)
from tango_aio.catalog._schema import Bare  # noqa: E402

DEFAULT_JSON = ROOT / "reference" / "instructions.json"
OUTPUT = ROOT / "tango_aio" / "families" / "_generated.py"
TWINS_OUTPUT = ROOT / "tango_aio" / "sync" / "_generated.py"

#: Manual chapter -> (class name, what the chapter is about, in the manual's heading).
CHAPTERS: dict[str, tuple[str, str]] = {
    "6": ("ControllerInfoAccess", "Controller information"),
    "7": ("CommunicationAccess", "Communication"),
    "8": ("SystemAccess", "System instructions"),
    "9": ("OperatingModesAccess", "Operating modes"),
    "11": ("AdjustmentsAccess", "General adjustments"),
    "12": ("LimitSwitchAccess", "Limit switches"),
    "13": ("CalibrationAccess", "Calibration and range measure"),
    "15": ("JoystickAccess", "HDI devices (joystick, coaxial drive, trackball, wheel)"),
    "17": ("IOAccess", "Digital and analogue I/O"),
    "18": ("EncoderAccess", "Encoders"),
    "19": ("MREncoderAccess", "MR encoder signal adjustment"),
    "20": ("ClosedLoopAccess", "Closed loop"),
    "21": ("TriggerAccess", "Trigger output"),
    "23": ("SnapshotAccess", "Snapshot input"),
}

#: Instructions whose named API is written by hand elsewhere (they restart the
#: controller, move axes or need a confirmation): instruction -> "Class.method".
HAND_MADE: dict[str, tuple[str, ...]] = {
    "save": ("Settings.save",),
    "restore": ("Settings.reload", "Settings.factory_reset"),
    "reset": ("Settings.reset",),
    "cal": ("Controller.calibrate",),
    "rm": ("Controller.measure_range",),
}

#: Member names where the manual's value notes do not parse into words (manual lines).
ENUM_NAMES: dict[str, dict[int, str]] = {
    # L3082-3100
    "dim": {0: "MICROSTEPS", 1: "UM", 2: "MM", 3: "DEGREES", 4: "REVOLUTIONS", 5: "CM",
            6: "M", 7: "INCH", 8: "MIL", 9: "MM_VELOCITY_MM_S"},
    # L2079-2117
    "autostatus": {0: "OFF", 1: "POSITION_REACHED", 2: "ACKNOWLEDGED", 3: "BARE_CR",
                   4: "ECHO"},
    # L5541-5605
    "calmode": {0: "CAL_SETS_ZERO", 1: "ZERO_AT_POWER_ON", 2: "CAL_SETS_ZERO_CL_FROM_POWER_UP"},
    # L7101-7174
    "joy": {0: "OFF", 1: "ON_COMPATIBLE", 2: "ON", 3: "MODE_3", 4: "MODE_4", 5: "MODE_5"},
    # L7175-7253
    "joydir": {0: "OFF", 1: "ON_NO_REDUCTION", 2: "ON", -1: "REVERSED_NO_REDUCTION",
               -2: "REVERSED"},
    # L10776-10865
    "enctype": {0: "MR_5VPP", 1: "TTL_RS422", 2: "SINE_1VPP"},
    # L15392-15440
    "snse": {1: "F1", 2: "F2", 3: "F3", 4: "F4"},
    # L1486
    "stagesn": {-1: "MAIN", 0: "ADDRESS_0", 1: "ADDRESS_1", 2: "ADDRESS_2", 3: "ADDRESS_3"},
}

#: Choices that are quantities, not named values (written as plain ints).
PLAIN_CHOICES = {"baud"}

_READ_TYPES: dict[Shape, tuple[str, str]] = {
    # shape -> (annotation of one value, converter)
    Shape.INT: ("int", "int"),
    Shape.FLOAT: ("float", "float"),
    Shape.TEXT: ("str", "str"),
    Shape.FLAGS: ("str", "str"),
    Shape.AXES_FLOAT: ("float", "float"),
    Shape.AXES_INT: ("int", "int"),
    Shape.AXES_TEXT: ("str", "str"),
    Shape.NUMBERS: ("list[float]", "_floats"),
    Shape.INTS: ("list[int]", "_ints"),
    Shape.LINES: ("list[str]", "_texts"),
    Shape.VERSION: ("VersionInfo", "_same"),
    Shape.DET: ("DetInfo", "_same"),
    Shape.ACK: ("object", "_same"),
    Shape.NONE: ("object", "_same"),
}
_PER_AXIS = {Shape.AXES_FLOAT, Shape.AXES_INT, Shape.AXES_TEXT}


def load(source: Path = DEFAULT_JSON) -> dict[str, dict[str, Any]]:
    """The reference entries by instruction name."""
    entries: list[dict[str, Any]] = json.loads(source.read_text(encoding="utf-8"))
    return {entry["name"]: entry for entry in entries}


def camel(text: str) -> str:
    return "".join(part[:1].upper() + part[1:] for part in re.split(r"[^A-Za-z0-9]+", text)
                   if part)


def _member(words: str) -> str:
    name = re.sub(r"[^A-Za-z0-9]+", "_", words.strip()).strip("_").upper()
    return name


def enum_members(values: tuple[int, ...], notes: str) -> list[tuple[str, int]]:
    """Member names from the manual's value notes (``0 = off; 1 = on``), else ``VALUE_n``."""
    names: list[str] = []
    for value in values:
        pattern = (rf"(?<![\w.\-]){re.escape(str(value))}(?![\w.])\s*(?:=|:|\))?\s*"
                   r"([A-Za-z][A-Za-z0-9 \-/]*)")
        match = re.search(pattern, notes)
        if match is None:
            break
        words = [word for word in re.split(r"[ /\-]+", match.group(1)) if word][:3]
        names.append(_member(" ".join(words)))
    generic = [(f"VALUE_{v}" if v >= 0 else f"VALUE_MINUS_{-v}") for v in values]
    if (len(names) != len(values) or len(set(names)) != len(names)
            or not all(n.isidentifier() and not n[0].isdigit() for n in names)):
        names = generic
    return list(zip(names, values, strict=True))


class Chapter:
    """The source of one chapter's class, gathered while its instructions are walked."""

    def __init__(self, cls: str, title: str) -> None:
        self.cls = cls
        self.title = title
        self.enums: list[str] = []
        self.methods: list[str] = []
        #: The blocking twin of each method: a descriptor line, or (a per-axis read)
        #: its overloads written out.
        self.twins: list[str] = []
        self.twin_methods: list[str] = []
        self.routes: dict[str, list[str]] = {}


def _lines(ref: dict[str, Any], entry: Instruction) -> str:
    first, last = ref.get("manual_lines") or (entry.line, entry.line)
    return f"manual L{first}-{last}"


def _words(text: str) -> str:
    text = " ".join(text.split()).rstrip(".")
    return text.replace("\\", "\\\\").replace('"', "'")


class Writer:
    """Turns catalog entries into accessor source."""

    def __init__(self, refs: dict[str, dict[str, Any]]) -> None:
        self.refs = refs
        self.enum_names: set[str] = set()

    def _enum(self, chapter: Chapter, entry: Instruction, param: Param) -> str | None:
        """The enum class of an int choice with named values (made once), or None."""
        choices = param.choices
        if (param.kind is not Kind.CHOICE or not choices
                or not all(isinstance(c, int) for c in choices) or len(choices) < 3
                or entry.name in PLAIN_CHOICES):
            return None
        name = camel(entry.name) + camel(param.name)
        if name not in self.enum_names:
            self.enum_names.add(name)
            notes = ""
            for ref_param in self.refs[entry.name].get("params", []):
                if ref_param.get("name") == param.name:
                    notes = ref_param.get("notes") or ""
            members = enum_members(tuple(int(c) for c in choices), notes)
            if entry.name in ENUM_NAMES:
                members = [(ENUM_NAMES[entry.name][v], v) for _, v in members]
            body = "\n".join(f"    {member} = {value}" for member, value in members)
            # A "|" would open a reST substitution (``stoppol |= 4``).
            doc = (_words(notes).replace("|", "\\\\|")
                   or f"The values of {entry.name}'s {param.name}")
            where = _lines(self.refs[entry.name], entry)
            chapter.enums.append(
                f"class {name}(ManualEnum):\n"
                f'    """{entry.name} {param.name}: {doc[:300]} ({where})."""\n\n'
                f"{body}\n")
        return name

    def annotation(self, chapter: Chapter, entry: Instruction, param: Param) -> str:
        if param.kind is Kind.FLOAT:
            return "float"
        if param.kind is Kind.INT:
            return "int"
        if param.kind is Kind.BITS:
            return "str"
        choices = param.choices
        if all(isinstance(c, str) for c in choices):
            return "Literal[" + ", ".join(repr(c) for c in choices) + "]"
        if sorted(choices) == [0, 1]:  # type: ignore[type-var]
            return "bool"
        enum_name = self._enum(chapter, entry, param)
        return f"{enum_name} | int" if enum_name else "int"

    def value_type(self, chapter: Chapter, entry: Instruction, shape: Shape) -> tuple[str, str]:
        """Annotation and converter of one reply value (an enum or bool where the set form
        takes a single listed choice)."""
        base, convert = _READ_TYPES[shape]
        single = entry.write[0] if entry.write else None
        params = (single.per_axis if shape in _PER_AXIS else single.lead) if single else ()
        if (len(params) == 1 and params[0].kind is Kind.CHOICE and shape in
                (Shape.INT, Shape.AXES_INT) and not entry.option_groups):
            annotation = self.annotation(chapter, entry, params[0])
            if annotation == "bool":
                return "bool", "to_bool"
            if annotation.endswith(" | int"):
                enum_name = annotation.removesuffix(" | int")
                return enum_name, enum_name
        if entry.reply_group > 1 and shape in _PER_AXIS:
            return f"tuple[{base}, ...]", convert
        if entry.option_groups:
            return "object", "_same"
        return base, convert

    def params(self, chapter: Chapter, entry: Instruction,
               params: tuple[Param, ...]) -> tuple[list[str], list[str]]:
        """The signature texts and argument names of lead parameters."""
        out, names, optional = [], [], False
        for param in params:
            name = _identifier(param.name)
            annotation = self.annotation(chapter, entry, param)
            optional = optional or param.optional
            out.append(f"{name}: {annotation} | None = None" if optional
                       else f"{name}: {annotation}")
            names.append(name)
        return out, names

    def reader(self, chapter: Chapter, entry: Instruction) -> None:
        ref = self.refs[entry.name]
        signature = entry.read[0] if entry.read else Signature()
        lead, names = self.params(chapter, entry, signature.lead)
        annotation, convert = self.value_type(chapter, entry, entry.reply)
        doc = f"{_words(ref.get('section_title') or entry.summary)} ({_lines(ref, entry)})."
        args = "".join(f", {name}" for name in names)
        method = _identifier(entry.name)
        if signature.axis is not AxisRule.NONE and entry.reply in _PER_AXIS:
            params = ", ".join(["self", *lead])
            chapter.methods.append(
                f"    @overload\n"
                f"    async def {method}({params}) -> dict[str, {annotation}]: ...\n"
                f"    @overload\n"
                f"    async def {method}({params}, *, axis: str) -> {annotation}: ...\n"
                f"    async def {method}({params}, *, axis: str | None = None"
                f") -> dict[str, {annotation}] | {annotation}:\n"
                f'        """{doc}"""\n'
                f"        return await read_axes(self._port, {entry.name!r}, {convert}{args},"
                f" axis=axis)  # type: ignore[no-any-return]\n")
            # A descriptor keeps only an overload's first signature: the twin spells
            # them out, and hands the call to the portal.
            chapter.twin_methods.append(
                f"    @overload\n"
                f"    def {method}({params}) -> dict[str, {annotation}]: ...\n"
                f"    @overload\n"
                f"    def {method}({params}, *, axis: str) -> {annotation}: ...\n"
                f"    def {method}({params}, *, axis: str | None = None"
                f") -> dict[str, {annotation}] | {annotation}:\n"
                f'        """{doc}"""\n'
                f"        return self._per_axis({method!r}{args}, axis=axis)"
                f"  # type: ignore[no-any-return]\n")
        else:
            extra = ["*", "axis: str | None = None"] if signature.axis is not AxisRule.NONE \
                else []
            params = ", ".join(["self", *lead, *extra])
            axis = ", axis=axis" if extra else ""
            chapter.methods.append(
                f"    async def {method}({params}) -> {annotation}:\n"
                f'        """{doc}"""\n'
                f"        return await read(self._port, {entry.name!r}, {convert}{args}{axis})\n")
            chapter.twins.append(_descriptor(chapter, method))
        chapter.routes.setdefault(entry.name, []).append(method)

    def writer(self, chapter: Chapter, entry: Instruction) -> None:
        ref = self.refs[entry.name]
        signature = entry.write[0]
        executes = not entry.allows(Form.READ) or entry.bare is Bare.EXECUTE
        method = _identifier(entry.name) if executes and not entry.read else \
            f"set_{entry.name}"
        lead, names = self.params(chapter, entry, signature.lead)
        title = _words(ref.get("section_title") or entry.summary)
        units = sorted({p.unit for p in (*signature.lead, *signature.per_axis) if p.unit})
        unit = f"; in {', '.join(units)}" if units else ""
        verb = "" if executes and not entry.read else "Set: "
        doc = f"{verb}{title} ({_lines(ref, entry)}{unit})."
        head = "".join(f"{name}, " for name in names)
        if signature.per_axis and signature.axis is AxisRule.OPTIONAL:
            group = [self.annotation(chapter, entry, p) for p in signature.per_axis]
            value = group[0] if len(group) == 1 else "tuple[" + ", ".join(
                dict.fromkeys(group)) + ", ...]" if len(set(group)) == 1 else \
                "tuple[" + ", ".join(group) + "]"
            axes = ", ".join(f"{a}: {value} | None = None" for a in "xyza")
            params = ", ".join(["self", *lead, "*", axes])
            body = (f"        await write_axes(self._port, {entry.name!r}, ({head}),"
                    f" {{'x': x, 'y': y, 'z': z, 'a': a}})\n")
        else:
            per, per_names = self.params(chapter, entry, signature.per_axis)
            if signature.axis is AxisRule.REQUIRED:
                params = ", ".join(["self", "axis: str", *lead, *per])
                axis = "axis=axis"
            elif signature.axis is not AxisRule.NONE:
                params = ", ".join(["self", *lead, *per, "*", "axis: str | None = None"])
                axis = "axis=axis"
            else:
                params = ", ".join(["self", *lead, *per])
                axis = ""
            values = "".join(f", {name}" for name in (*names, *per_names))
            tail = f", {axis}" if axis else ""
            body = f"        await write(self._port, {entry.name!r}{values}{tail})\n"
        chapter.methods.append(
            f"    async def {method}({params}) -> None:\n"
            f'        """{doc}"""\n'
            f"{body}")
        chapter.twins.append(_descriptor(chapter, method))
        chapter.routes.setdefault(entry.name, []).append(method)


def _descriptor(chapter: Chapter, method: str) -> str:
    return f"    {method} = _Blocking(_f.{chapter.cls}.{method})\n"


def _identifier(name: str) -> str:
    name = re.sub(r"\W", "_", name)
    return f"{name}_" if keyword.iskeyword(name) or name in {"set", "type"} else name


def family_entries() -> dict[str, list[Instruction]]:
    """The catalog's instructions of each family chapter, in manual order."""
    seen: set[str] = set()
    out: dict[str, list[Instruction]] = {chapter: [] for chapter in CHAPTERS}
    for entry in INSTRUCTIONS.values():
        chapter = entry.section.split(".")[0]
        if chapter in out and entry.name not in seen:
            seen.add(entry.name)
            out[chapter].append(entry)
    return out


def chapters_of(refs: dict[str, dict[str, Any]]) -> tuple[Writer, list[tuple[str, Chapter]]]:
    """Each family chapter's source, gathered from its instructions."""
    writer = Writer(refs)
    chapters = []
    for number, entries in family_entries().items():
        cls, title = CHAPTERS[number]
        chapter = Chapter(cls, title)
        for entry in entries:
            if entry.name in HAND_MADE:
                continue
            if entry.read and entry.reply is not Shape.NONE:  # ?flash answers nothing
                writer.reader(chapter, entry)
            if entry.write:
                writer.writer(chapter, entry)
        chapters.append((number, chapter))
    return writer, chapters


def render(refs: dict[str, dict[str, Any]]) -> str:
    writer, chapters = chapters_of(refs)
    out = [HEADER]
    for _, chapter in chapters:
        out.extend(f"\n\n{text}" for text in chapter.enums)
    names = []
    for number, chapter in chapters:
        names.append(chapter.cls)
        routes = ", ".join(f"{name!r}: {tuple(methods)!r}"
                           for name, methods in chapter.routes.items())
        out.append(
            f"\n\nclass {chapter.cls}(Family):\n"
            f'    """{chapter.title}: the typed access of manual chapter {number}."""\n\n'
            f"    __slots__ = ()\n\n"
            f"    #: The instructions of the chapter and the methods that reach them.\n"
            f"    ROUTES: ClassVar[dict[str, tuple[str, ...]]] = {{{routes}}}\n")
        for method in chapter.methods:
            out.append("\n" + method)
    enum_names = sorted(writer.enum_names)
    out.append(
        "\n\n#: Every generated family class, by manual chapter.\n"
        "ACCESS: dict[str, type[Family]] = {"
        + ", ".join(f"{number!r}: {chapter.cls}" for number, chapter in chapters) + "}\n"
        "\n#: Instructions whose named API is written by hand: where it is.\n"
        f"HAND_MADE: dict[str, tuple[str, ...]] = {HAND_MADE!r}\n"
        "\n__all__ = [\n" + "".join(f"    {name!r},\n" for name in
                                    sorted(["ACCESS", "HAND_MADE", *names, *enum_names],
                                           key=lambda n: (not n.isupper(), n)))
        + "]\n")
    return "".join(out)


def render_twins(refs: dict[str, dict[str, Any]]) -> str:
    """The blocking twins of the accessor classes (``tango_aio/sync/_generated.py``)."""
    writer, chapters = chapters_of(refs)
    body = []
    for number, chapter in chapters:
        body.append(
            f"\n_{chapter.cls} = TypeVar(\"_{chapter.cls}\", bound=_f.{chapter.cls}, "
            "covariant=True)\n"
            f"\n\nclass {chapter.cls}(_Wrapper[_{chapter.cls}]):\n"
            f'    """The blocking twin of :class:`tango_aio.families.{chapter.cls}` '
            f'(manual chapter {number}): each method blocks until the driver\'s thread has '
            'run it."""\n\n')
        body.extend(chapter.twins)
        body.extend(f"\n{method}" for method in chapter.twin_methods)
        body.append("\n")
    text = "".join(body)
    enums = sorted((name for name in writer.enum_names if re.search(rf"\b{name}\b", text)),
                   key=str.lower)
    imports = "".join(f"    {name},\n" for name in enums)
    names = "".join(f"    {name!r},\n" for name in sorted(c.cls for _, c in chapters))
    return (TWINS_HEADER + (f"from ..families import (\n{imports})\n" if enums else "")
            + "from ._blocking import _Blocking, _Wrapper\n" + text
            + f"\n__all__ = [\n{names}]\n")


TWINS_HEADER = '''"""The blocking twins of the typed access of the manual's family chapters.
GENERATED by tools/gen_families.py with ``tango_aio/families/_generated.py``: edit the
generator, not this file.

Each class is generic in the async family it wraps, so that a family built on an accessor
class (``tango_aio.families.Joystick`` on ``JoystickAccess``) has a blocking twin built on
this one (:mod:`tango_aio.sync`). A per-axis read's overloads are written out: a blocking
descriptor would keep only the first.
"""

# ruff: noqa: E501

from __future__ import annotations

from typing import TypeVar, overload

from .. import families as _f
'''


HEADER = '''"""Typed access to every instruction of the manual's family chapters. GENERATED by
tools/gen_families.py from the instruction catalog and reference/instructions.json: edit
the generator, not this file.

Each chapter is a :class:`~tango_aio.families.Family` class (``JoystickAccess``...) with a
read method named after each readable instruction (``joy()``) and ``set_<name>(...)`` for
each settable one; per-axis reads give a dict by axis, or one value with ``axis=``.
Values are checked against the catalog's ranges before a byte is written
(:class:`~tango_aio.errors.InvalidCommandError`, a ``ValueError``).
"""

# ruff: noqa: E501

from __future__ import annotations

from typing import Any, ClassVar, Literal, overload

from ..catalog import DetInfo, VersionInfo
from ._access import ManualEnum, read, read_axes, to_bool, write, write_axes
from ._base import Family


def _floats(value: Any) -> list[float]:
    return [float(item) for item in value]


def _ints(value: Any) -> list[int]:
    return [int(item) for item in value]


def _texts(value: Any) -> list[str]:
    return [str(item) for item in value]


def _same(value: Any) -> Any:
    return value
'''


def main() -> None:
    source = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_JSON
    refs = load(source)
    OUTPUT.write_text(render(refs), encoding="utf-8")
    TWINS_OUTPUT.write_text(render_twins(refs), encoding="utf-8")
    print(f"wrote {OUTPUT.relative_to(ROOT)} and {TWINS_OUTPUT.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
