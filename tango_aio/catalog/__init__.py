"""The instruction catalog: one table of the manual's instructions, and its parsing.

Every instruction is data (``_table.py``, generated from the reference by
``tools/gen_catalog.py``): its forms, parameters, ranges, per-axis shape and reply rule.
``_instructions.py`` checks and builds command lines against it before a byte is written
and parses their replies; the driver and the emulator both read it, each on its own.
"""

from __future__ import annotations

from ._instructions import (
    INSTRUCTIONS,
    MAX_SNAPSHOTS,
    MAX_TRIGGERS,
    AxisRule,
    Command,
    Completion,
    Context,
    DetInfo,
    Form,
    Instruction,
    Kind,
    LineRule,
    ModeEffect,
    Param,
    Shape,
    Signature,
    Value,
    VersionInfo,
    build,
    build_axes,
    build_rows,
    check_axis_word,
    check_framing,
    check_rows,
    check_rows_framing,
    encode,
    encode_rows,
    lookup,
    parse,
    parse_reply,
    reply_group,
    reply_rule,
    similar_names,
    upper_bound,
    wire_number,
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
