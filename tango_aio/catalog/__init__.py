"""The instruction catalog: one table of the manual's instructions, and its parsing.

Every instruction is data (``_table.py``, generated from the reference by
``tools/gen_catalog.py``): its forms, parameters, ranges, per-axis shape and reply rule.
``_instructions.py`` parses command lines against it, ``_encode.py`` builds them before a
byte is written and ``_replies.py`` parses their replies; the driver and the emulator both
read it, each on its own.
"""

from __future__ import annotations

from ._encode import (
    Value,
    build,
    build_axes,
    build_rows,
    check_axis_word,
    check_framing,
    check_rows,
    check_rows_framing,
    encode_rows,
)
from ._instructions import (
    INSTRUCTIONS,
    MAX_SNAPSHOTS,
    MAX_TRIGGERS,
    AxisRule,
    Command,
    Completion,
    Context,
    Form,
    Instruction,
    Kind,
    LineRule,
    ModeEffect,
    Param,
    Shape,
    Signature,
    encode,
    lookup,
    parse,
    similar_names,
    upper_bound,
    wire_number,
)
from ._replies import (
    DetInfo,
    VersionInfo,
    parse_reply,
    reply_group,
    reply_rule,
)
from ._schema import (
    AXES,
)

__all__ = [
    "AXES",
    "INSTRUCTIONS",
    "MAX_SNAPSHOTS",
    "MAX_TRIGGERS",
    "AxisRule",
    "Command",
    "Completion",
    "Context",
    "DetInfo",
    "Form",
    "Instruction",
    "Kind",
    "LineRule",
    "ModeEffect",
    "Param",
    "Shape",
    "Signature",
    "Value",
    "VersionInfo",
    "build",
    "build_axes",
    "build_rows",
    "check_axis_word",
    "check_framing",
    "check_rows",
    "check_rows_framing",
    "encode",
    "encode_rows",
    "lookup",
    "parse",
    "parse_reply",
    "reply_group",
    "reply_rule",
    "similar_names",
    "upper_bound",
    "wire_number",
]
