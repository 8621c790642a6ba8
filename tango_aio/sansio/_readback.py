"""The read-back that proves a set line: which read shows that the controller holds what
the line wrote, and whether its reply does.

In autostatus 0, 1 and 3 a set line owes no answer of its own (L2079-2161), and the
``?err`` written behind it proves nothing about a line that never arrived: each
instruction overwrites the error state (L2853), so a lost line leaves the answer of the
line before, usually 0. Only a read of the setting shows what the controller holds. In
autostatus 2 (``OK...``, L2099-2103) and 4 (the echo, L2115-2117) the line's own answer
proves that it arrived, and the ``?err`` behind it that it was accepted.

:func:`read_back` gives the read for a set line (``!vel x 55.5`` → ``?vel x``), from the
catalog's facts (its forms, signatures and reply shape) alone; :func:`mismatch` compares
the reply with what was written at the precision the controller prints (``?vel x``
answers ``55.500`` for 55.5, or for 55.4999), and with the rounding the manual documents
(``!trigs``: multiples of 40 µs, L12965-12967; ``!trigf``: whole 40 µs periods,
L13234-13278). Sans-IO: the protocol writes the read and
hands its reply here.

What no read-back proves, each with its reason in :data:`NO_READ_BACK`: instructions
without a ``?`` form (actions: ``!save`` answers ``OK...`` itself in every mode, L1723-1736;
``!reset`` restarts the controller, which the driver notices by its mode, L1837-1857;
``!zero``, ``!clearhwcount``, ``!trigger``, ``!snse``, ``!brakepos``, ``!vrm`` and
``!go`` change what only a position or an output shows), lines without values
(``!posclr``, ``!encerr x``), settings whose read form shows something else (counters,
latches and measurements that change on their own, ``!pos`` that moves with the axis),
lines that change the link itself (``!baud``, ``!cts``, ``!ipreter``), and list entries
(``!trigp``, ``!snsa``, ``!snsv``, whose uploads count their entries, see
:mod:`tango_aio.families._bulk`). Motion lines (moves, ``cal``, ``rm``, ``!speed``) are proven by
their completion and the axes' state (:mod:`tango_aio.controller._motion`). ``!autostatus`` is
proven by the mode exchange that reads the mode behind it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from typing import Final

from ..catalog import AxisRule, Command, Context, Form, Kind, Shape, build, reply_group

__all__ = ["NO_READ_BACK", "ReadBack", "mismatch", "read_back"]

#: Instructions with a ``?`` form whose read does not prove their set line, and why.
NO_READ_BACK: Final[dict[str, str]] = {
    "autostatus": "proven by the mode exchange that reads the mode behind it (L2060-2168)",
    "baud": "changes the link's baud rate: a read-back would go out at the old rate "
            "(L1624)",
    "cts": "changes the link's handshake (L1685)",
    "ipreter": "switches the controller to another instruction set (L1986)",
    "restore": "reloads the saved settings, an action without a value to read (L1768-1813)",
    "err": "'!err' clears the error state that '?err' reads (L2824-2881)",
    "pa": "'?pa' reads the amplifiers' state (1 ok, 0 error or off), not the value "
          "written ('!pa 2': on, for closed loop) (L1870-1915)",
    "speed": "a constant-speed run: motion, proven by the axes' state (L6713)",
    "pos": "the position counter moves with the axis and, in closed loop, with its "
           "encoder (L6900)",
    "keyl": "reading clears the latched buttons (L7638)",
    "zwpos": "the wheel's counter changes as it turns (L8007)",
    "stop": "'!stop' releases a stop condition; '?stop' reads the stop input (L9800)",
    "drop": "dispenses drops, an action (L10199)",
    "encerr": "'!encerr' clears an encoder error; '?encerr' reads the state (L11116)",
    "encpos": "'?encpos' reads one value for every axis' source (L11193)",
    "mrp": "'!mrp' restarts a measurement whose result '?mrp' reads (L11435)",
    "calpos": "'?calpos' reads where the last cal released its switch (L5921)",
    "trigcount": "the trigger counter counts on while triggers fire (L13387)",
    "trigi": "the list index moves as triggers fire (L14133)",
    "trigp": "a list entry: an upload counts its entries (L13767)",
    "snsc": "the snapshot count grows with each snapshot (L15136)",
    "snsi": "the snapshot index moves with each snapshot (L15171)",
    "snsp": "'?snsp' reads the last captured position (L15277)",
    "snsa": "a list entry: an upload counts its entries (L15324)",
    "snsv": "'?snsv' reads a captured voltage (L15441)",
    "clim": "'!clim r' centres the circle on the position where it runs and '!clim 0' "
            "disables it: '?clim' shows neither line as written (L4622-4650)",
    "anaout": "two set forms, not paired with their reads by the driver (L9453)",
    "adiginfunc": "three set forms, not paired with their reads by the driver (L9170)",
}

#: Values the controller rounds to a documented step, by instruction (``!trigs 90``
#: holds 80, ``!trigs 100`` holds 120, read back corrected: L12965-12967). The step of
#: the secondary output's delay and width too (L12976-12981), and ``trigcomp``'s
#: "smallest step is 10µs" (L13060). A value equal to the one written is accepted as
#: well (a firmware that keeps it as written).
STEPS: Final[dict[str, int]] = {"trigs": 40, "trigcomp": 10}

#: Frequencies the controller runs at a whole number of ticks of its clock and reads back
#: so: the tick in seconds, by instruction (``trigf``: 40 µs, ``!trigf 2600`` reads the
#: true value, 2500 or 2777.78, L13234-13278). Both neighbours of the value written are
#: accepted, and the value itself.
TICKS: Final[dict[str, Decimal]] = {"trigf": Decimal("40e-6")}

#: Instructions whose read shows only the first value of their set line, by instruction
#: (``!trigs 120 40 80``: "The 2nd and 3rd parameter cannot be read back by ?trigs",
#: L13001-13003); the others are not proven.
FIRST_ONLY: Final[frozenset[str]] = frozenset({"trigs"})

_PER_AXIS_REPLIES: Final = frozenset({Shape.AXES_FLOAT, Shape.AXES_INT, Shape.AXES_TEXT})
_GLOBAL_REPLIES: Final = frozenset({Shape.INT, Shape.FLOAT, Shape.TEXT, Shape.INTS,
                                    Shape.NUMBERS, Shape.FLAGS})


@dataclass(frozen=True, slots=True)
class ReadBack:
    """The read that proves the set line :attr:`command`, and what its reply must hold."""

    #: The set line.
    command: Command
    #: The read written behind it (and behind its ``?err``).
    read: Command
    #: The values written, as sent, that the reply must start with.
    expected: tuple[str, ...]
    #: One value group applied to every axis (``!swtyp 1 0 1``): each group of the reply
    #: must hold it.
    every_group: bool = False
    #: The value is a string of flag characters whose first ones the line wrote
    #: (``!lock 0101``), compared as characters.
    flags: bool = False


def read_back(command: Command, context: Context) -> ReadBack | None:
    """The read that proves the set line ``command``, or ``None`` where none does (see
    :data:`NO_READ_BACK` and the module's text)."""
    entry = command.instruction
    if command.form is not Form.SET or not entry.allows(Form.READ) or not command.tokens \
            or entry.completion is not None or entry.name in NO_READ_BACK \
            or not entry.write or not entry.read:
        return None
    if len(entry.write) == 2 and entry.write[0].lead \
            and entry.write[0].lead[0].kind is Kind.BITS:
        return _flags(command, context)
    if len(entry.write) != 1:
        return None
    sig, read_sig = entry.write[0], entry.read[0]
    if any(not param.optional for param in read_sig.lead):
        return None
    if sig.per_axis:
        if sig.lead or entry.reply not in _PER_AXIS_REPLIES:
            return None
        read = build(entry.name, form=Form.READ, axis=command.axis, context=context)
        if reply_group(read) != len(sig.per_axis):
            return None
        every = sig.axis is AxisRule.ALL and command.axis is None
        expected = command.tokens if command.axis or every \
            else command.tokens[: context.axes * len(sig.per_axis)]
        return ReadBack(command, read, tuple(expected), every_group=every)
    if entry.reply not in _GLOBAL_REPLIES:
        return None
    if entry.indexed:
        # '!joyspeed 2 25' is read as '?joyspeed 2' (one index, its value).
        if len(read_sig.lead) != 1 or len(command.tokens) < 2:
            return None
        read = build(entry.name, command.values[0], form=Form.READ, context=context)
        return ReadBack(command, read, command.tokens[1:])
    # '!trigr x 5 10 6' makes X the trigger axis; '?trigr' takes none and answers the
    # values in force (L13496-13580).
    axis = command.axis if read_sig.axis is not AxisRule.NONE else None
    read = build(entry.name, form=Form.READ, axis=axis, context=context)
    tokens = command.tokens[:1] if entry.name in FIRST_ONLY else command.tokens
    return ReadBack(command, read, tokens, flags=entry.reply is Shape.FLAGS)


def _flags(command: Command, context: Context) -> ReadBack:
    # '!lock 0101' (the first flags) is read as '?lock', '!lock 2 1' (one flag by its
    # index) as '?lock 2' (L4222, L8579).
    name = command.name
    if len(command.tokens) == 2:
        read = build(name, command.values[0], form=Form.READ, context=context)
        return ReadBack(command, read, command.tokens[1:], flags=True)
    return ReadBack(command, build(name, form=Form.READ, context=context), command.tokens,
                    flags=True)


def mismatch(proof: ReadBack, lines: Sequence[str]) -> str | None:
    """Compare the read-back's reply with what the set line wrote.

    A number matches when the reply, at the digits it prints, is the value written
    rounded (``55.500`` for 55.5 or 55.4999; ``2`` for a factor the controller prints as
    an integer, L11904-11908), the documented step's multiple nearest to it
    (:data:`STEPS`), or the frequency of a whole number of ticks next to it
    (:data:`TICKS`); a word matches ignoring case; flags match character by character."""
    text = " ".join(line.strip() for line in lines)
    expected = proof.expected
    if proof.flags:
        held = "".join(text.split())
        wanted = "".join(expected)
        return None if held.lower().startswith(wanted.lower()) else text
    tokens = _tokens(proof, text)
    rounding = (STEPS.get(proof.command.name), TICKS.get(proof.command.name))
    size = len(expected)
    if proof.every_group:
        groups = [tokens[i:i + size] for i in range(0, len(tokens), size)]
        complete = [group for group in groups if len(group) == size]
        ok = bool(complete) and len(complete) == len(groups) and all(
            _same(group, expected, rounding) for group in complete)
    else:
        ok = len(tokens) >= size and _same(tokens[:size], expected, rounding)
    return None if ok else text


def _tokens(proof: ReadBack, text: str) -> list[str]:
    tokens = text.replace(",", " ").split()  # '?lim' in extmode 0 adds commas (L4559)
    if proof.read.instruction.digit_values:
        # '1 1 11 1 11 1 1' is three groups of one digit each, printed without a space.
        tokens = [digit for token in tokens
                  for digit in (list(token) if token.isdigit() else [token])]
    return tokens


_Rounding = tuple[int | None, Decimal | None]


def _same(held: list[str], sent: tuple[str, ...], rounding: _Rounding) -> bool:
    return all(_one(h, s, rounding) for h, s in zip(held, sent, strict=True))


def _one(held: str, sent: str, rounding: _Rounding) -> bool:
    value, written = _decimal(held), _decimal(sent)
    if value is None or written is None:
        return held.lower() == sent.lower()
    exponent = value.as_tuple().exponent
    digits = -exponent if isinstance(exponent, int) and exponent < 0 else 0
    half = Decimal(5).scaleb(-digits - 1)
    candidates = [written]
    step, tick = rounding
    if tick is not None and written > 0:
        ticks = 1 / (written * tick)
        candidates += [1 / (max(Decimal(1), ticks.to_integral_value(rounding=way)) * tick)
                       for way in ("ROUND_FLOOR", "ROUND_CEILING")]
    if step is not None:
        candidates.append((written / step + Decimal("0.5")).to_integral_value(
            rounding="ROUND_FLOOR") * step)
    return any(abs(value - candidate) <= half for candidate in candidates)


def _decimal(text: str) -> Decimal | None:
    try:
        number = Decimal(text)
    except InvalidOperation:
        return None
    return number if number.is_finite() else None
