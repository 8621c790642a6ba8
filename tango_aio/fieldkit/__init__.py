"""The field kit: probing an unknown unit, recording its wire traffic, replaying it.

``probe`` asks a unit the questions whose answers the manual leaves open and writes a
fingerprint; ``record_trace`` and the ``tango_aio.wire`` log record a session's lines;
``replay`` plays a trace back on loopback and checks a client's lines against it.
"""

from __future__ import annotations

from ..errors import ProbeError
from ._decide import (
    FINGERPRINT_FORMAT,
    MOVE_SWITCHES,
    SAVE_SWITCHES,
    SWITCH_NAMES,
    TRIGGER_SWITCHES,
    Exchange,
    Observation,
)
from ._probe import (
    ProbeOptions,
    ProbeResult,
    comparable,
    probe,
    write_fingerprint,
)
from ._probecmd import (
    add_probe_command,
)
from ._replay import (
    Replay,
    ReplayMismatch,
    replay,
)
from ._trace import (
    TraceRecord,
    format_record,
    parse_trace,
    read_trace,
    record_trace,
    trace_header,
)

__all__ = [
    "FINGERPRINT_FORMAT",
    "MOVE_SWITCHES",
    "SAVE_SWITCHES",
    "SWITCH_NAMES",
    "TRIGGER_SWITCHES",
    "Exchange",
    "Observation",
    "ProbeError",
    "ProbeOptions",
    "ProbeResult",
    "Replay",
    "ReplayMismatch",
    "TraceRecord",
    "add_probe_command",
    "comparable",
    "format_record",
    "parse_trace",
    "probe",
    "read_trace",
    "record_trace",
    "replay",
    "trace_header",
    "write_fingerprint",
]
