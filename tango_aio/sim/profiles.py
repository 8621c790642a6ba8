"""Firmware profiles: every plausible behaviour where the manual is silent, as switches.

The manual (firmware 1.71, ``L<n>``) and its older edition (``old L<n>``) leave many
details of the protocol open or contradict each other. The emulator gives each open point
one *switch* with every plausible value; a :class:`Firmware` is one choice for every
switch, and a *profile* is a named :class:`Firmware`:

* ``manual`` - firmware 1.71 as documented, the emulator's default;
* ``legacy`` - where the older edition differs: ``help`` takes no parameter and
  instructions it does not know answer error 4, ``a`` is answered like a move and aborted
  axes report ``@``, mode 4 echoes all input, no ``END_SERVICE_PRINT.``, the old
  ``?version`` format.

Select one in a URL (``sim://?profile=legacy&echo=after``), on the command line
(``tango-aio sim --profile legacy --switch echo=after``) or in Python::

    SimConfig(firmware=Firmware.from_options("legacy", echo="after"))

:data:`SWITCHES` documents every switch (values, the ``manual`` default, the manual lines
it comes from, what it changes); the switch table of the firmware-profiles page of the
docs is generated from it.
:func:`variants` lists the firmwares a client's test matrix should run against.

This module imports nothing of the driver: it is part of the emulator's own reading of
the manual.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

__all__ = ["PROFILES", "SWITCHES", "Firmware", "SwitchDoc", "fingerprint_lacks",
           "switch_table", "variants"]


@dataclass(frozen=True)
class SwitchDoc:
    """What one switch does, for documentation and for validating options."""

    #: The switch's name (a :class:`Firmware` field, a URL option).
    name: str
    #: Every allowed value; the first is the ``manual`` profile's choice.
    values: tuple[str, ...]
    #: Where the manual says something about it (``L<n>`` of the 1.71 manual, ``old L<n>``
    #: of the older edition).
    lines: str
    #: What each value changes.
    effect: str
    #: Values the driver does not serve yet: the emulator offers them so that
    #: the probe (``tango-aio probe``) can recognise such a unit, and :func:`variants`
    #: leaves them out of a client's test matrix unless asked.
    unsupported: tuple[str, ...] = ()

    @property
    def default(self) -> str:
        """The value under the ``manual`` profile."""
        return self.values[0]


_DOCS: tuple[SwitchDoc, ...] = (
    # -- mode 4 (echo) -----------------------------------------------------------------------
    SwitchDoc("echo", ("before", "after", "completion"), "L2117, L2168",
              "Mode 4 echoes a line before executing it, or after. So `before`: "
              "`!autostatus 1` sent in mode 4 is echoed and `!autostatus 4` sent in mode 1 "
              "is not; `after`: the reverse. `completion`: like `before`, but a move line "
              "that starts a move is echoed only when it completes, just before its "
              "report (L2117 does not say when the echo comes)."),
    SwitchDoc("echo_report", ("yes", "no"), "L2117, L2168",
              "A move in mode 4 also sends its completion report after the echo (`yes`), "
              "or the echo is all it gets (`no`)."),
    SwitchDoc("echo_all", ("no", "yes"), "L2117, old L723",
              "Mode 4 echoes only set and move lines (`no`), or all input: reads and "
              "lines without `!` too (`yes`, old L723: \"echoes all input\")."),
    SwitchDoc("echo_text", ("exact", "normalized", "nobang"), "L2117, L2168",
              "The echo is the exact text received, or the line re-printed: lower case, "
              "single spaces, numbers re-formatted (`!MOA  1.50` -> `!moa 1.5`), or the "
              "exact text without its leading `!` (`nobang`: `!moa 1` -> `moa 1`; L2117 "
              "only says \"echoes the instruction\")."),
    # -- mode 2 (acknowledge) ------------------------------------------------------------------
    SwitchDoc("ack_reads", ("no", "before", "after"), "L2099-2103",
              "Mode 2 acknowledges `!` lines only (`no`), or `?` reads too, with `OK...` "
              "before or after their data."),
    SwitchDoc("err_number", ("yes", "no"), "L2099, L2150-2152",
              "A refused line in mode 2 is acknowledged `ERR 5` (`yes`) or a bare `ERR`."),
    SwitchDoc("ack_mode_change", ("new", "old"), "L2060-2103",
              "`!autostatus n` is acknowledged by the mode in force after it (`new`: "
              "`!autostatus 2` gets `OK...`) or before it (`old`: `!autostatus 1` sent in "
              "mode 2 gets `OK...`)."),
    SwitchDoc("move_ok", ("immediate", "completion"), "L2099-2103",
              "A move's `OK...` in mode 2 comes at once (`immediate`), or only when it "
              "completes, just before its report (`completion`)."),
    SwitchDoc("ack_case", ("upper", "lower", "title"), "L2099-2103, L2150-2152",
              "Mode 2 acknowledgements as the manual prints them, `OK...` and `ERR 5` "
              "(`upper`), or in another case: `ok...`/`err 5` (`lower`), `Ok...`/`Err 5` "
              "(`title`). Replies that are the data of a line (`save`, `?status`) keep "
              "the manual's case."),
    SwitchDoc("save_ack", ("once", "twice"), "L1738-1762, L2081, L2099-2103",
              "`!save` (and `!restore`) answer `OK...` in every mode (L2081); in mode 2 "
              "that answer is the acknowledgement (`once`), or the line is acknowledged "
              "again after it (`twice`: `OK...` `OK...`)."),
    # -- moves -----------------------------------------------------------------------------------
    SwitchDoc("refused_move_report", ("no", "yes"), "L2705, L6337-6343",
              "A refused move (e.g. outside the limits) only sets the error (`no`), or "
              "also sends a completion report with `E` for its axes (`yes`, L2705: "
              "\"E ... not executed\")."),
    SwitchDoc("move_during_move", ("refuse", "queue", "retarget"), "L6606, L6254-6260",
              "A move line for axes that are still moving is refused with error 2, waits "
              "until they stop (`queue`, then reports on its own), or takes over their "
              "target (`retarget`: the first move sends no report of its own)."),
    SwitchDoc("disable_during_move", ("continue", "stop", "refuse"), "L3919-3960",
              "`!axis x 0` (disable) or `-1` (power stage off) while X moves: the manual "
              "says only that a disabled axis keeps its motor current and a switched-off "
              "one loses its torque. The move goes on to its target (`continue`), X "
              "stops as by `a x` (`stop`: letter `E`), or the line is refused with "
              "error 2 (`refuse`)."),
    SwitchDoc("zero_move_report", ("yes", "no"), "L2087-2089",
              "A move to where the axes already are sends a report (`yes`) or nothing."),
    # -- snapshot steps (snsm 1 and 5) ----------------------------------------------------------
    SwitchDoc("snapshot_pointer", ("next", "advance"), "L14520-14526, L15171-15190",
              "A snapshot step (`snsm 1` on F2 or `snse 2`, `snsm 5` on the snapshot "
              "input) moves to the entry `snsi` points at and then moves the pointer on "
              "(`next`: `snsi` is \"the array index where move target positions are read "
              "from\", L15182-15185), or first moves the pointer on and then moves to the "
              "entry it points at (`advance`); either wraps at the end of the array."),
    SwitchDoc("snapshot_step_report", ("no", "yes"), "L2087-2089, L14520-14526",
              "A snapshot step sends no completion report (`no`: autostatus reports follow "
              "\"an automatic move (!moa,!mor,m,!moc,!mol)\", L2087, and no line started "
              "it), or reports like a `moa` (`yes`)."),
    SwitchDoc("snapshot_while_moving", ("move", "ignore"), "L14520-14526, L6606",
              "A snapshot step while an axis still moves is a move like a `moa` "
              "line then (`move`: the switch `move_during_move` decides; refused, the "
              "axes show `E`), or the event is ignored and the pointer stays (`ignore`)."),
    # -- reports and status ------------------------------------------------------------------
    SwitchDoc("report_width", ("four", "axes"), "L2089, L2141, L5404",
              "Completion reports carry letters for X Y Z A always, absent axes `-` "
              "(`four`: `@@--.` on 2 axes), or only as many as the unit has (`axes`: `@@.`)."),
    SwitchDoc("status_tail", ("yes", "no", "dot"), "L2662-2725",
              "`?statusaxis` (all axes) ends with `.-` like every example of the manual "
              "(`@@@-.-`, `yes`), with the axis letters only (`no`: `@@@-`), or with the "
              "dot but not the `-` that L2668-2670 adds to the completion report's shape "
              "(`dot`: `@@@-.`, a line that reads like a completion report)."),
    SwitchDoc("absent_axes", ("dash", "omit"), "L2711, L2721",
              "`sa`/`?statusaxis` shows absent and disabled axes as `-` (`dash`: "
              "`JM--.-`), or leaves them out (`omit`: `JM.-`, L2711 prints no character)."),
    SwitchDoc("joystick_letter", ("@", "J"), "L2697, L2715-2721, L6341",
              "An idle axis, and an axis that completed a move, shows `@` (`@@@-.-`, "
              "L2715), or `J` while the joystick is enabled (`J`: `JM--.-`, L2721; \"a '@' "
              "or 'J' after successfully completing the move\", L6341), in `sa` and in "
              "completion reports."),
    SwitchDoc("abort_letter", ("E", "@"), "L6832-6834, old L1917",
              "Letter of the axes stopped by `a` or Ctrl+C: `E` (1.71) or `@` (older "
              "edition: \"each configured axis responds an @\")."),
    SwitchDoc("abort_report", ("no", "yes"), "L6832-6834, old L725, old L1917",
              "`a` sends nothing itself (`no`), or a report of its own once the axes "
              "stand, like a move (`yes`), in addition to the report of the move it stopped."),
    SwitchDoc("ctrl_c", ("stop", "ignore", "stop_report"), "L6808-6814, old L1915",
              "Ctrl+C (0x03) stops all axes and clears the input buffer silently (`stop`); "
              "is not supported and reaches the parser as a byte (`ignore`); or stops and "
              "sends a report of its own once the axes stand (`stop_report`)."),
    # -- firmware replies ----------------------------------------------------------------------
    SwitchDoc("help_number", ("yes", "no"), "L2915-2919, old L805-819",
              "`?help N` answers `ERROR N,text` (`yes`) or the text only (`no`)."),
    SwitchDoc("help_case", ("upper", "lower"), "L2915-2919",
              "`help` answers as the manual prints it, `ERROR 5,number outside range` "
              "(`upper`), or in lower case: `error 5,number outside range` (`lower`)."),
    SwitchDoc("service_end", ("yes", "no"), "L2937-2943",
              "`service` ends with `END_SERVICE_PRINT.` (firmware 1.60C/1.61 on) or "
              "without an end marker (`no`)."),
    SwitchDoc("lim_cr_bug", ("extmode0", "none", "both"), "L2196-2232, L4559-4621",
              "`?lim` for all axes prints an extra CR after the X pair in extmode 0 only "
              "(`extmode0`), never (`none`), or in both extmodes (`both`)."),
    SwitchDoc("version_format", ("new", "old"), "L1063-1107, old L414-426",
              "`?version` as `TANGO-DT, Version 1.71, Jun  4 2019 , 12:00:00` (`new`) or "
              "`TANGO-DT, Version 1.71, Jun  4 2019, 12:00:00` (`old`, no space before "
              "the last comma)."),
    SwitchDoc("version_value", ("number", "line"), "L1046-1059, L1107, old L414-418",
              "`?version 1` answers the version number only (`number`, L1057-1059, "
              "L1107; refused with error 4 under `instruction_set=older`, whose `version` "
              "takes no value, old L416-418), or ignores the value and answers the whole "
              "`?version` line (`line`: firmware whose `version` takes no value, in either "
              "instruction set)."),
    SwitchDoc("line_end", ("cr", "crlf"), "L82",
              "Replies end with CR (`cr`) or CR LF (`crlf`)."),
    SwitchDoc("numbers", ("plain", "plus", "negzero"), "L66-70, L94-96",
              "Numbers in read replies as `1.0000` (`plain`), `+1.0000` for positive "
              "values (`plus`), or `-0.0000` for values that round to zero from below "
              "(`negzero`)."),
    SwitchDoc("instruction_set", ("full", "older"), "old L414, old L805-819",
              "Every instruction of the 1.71 manual (`full`), or only those of the older "
              "edition: the others, and values for `help`/`version` (which took none "
              "there), answer error 4."),
    # -- the trigger outputs -------------------------------------------------------------
    SwitchDoc("trigf_round", ("nearest", "down"), "L13234-13278",
              "`trigf`'s period is a whole number of 40 µs ticks and `?trigf` reads \"the "
              "true value\": the tick count is the nearest to the frequency asked "
              "(`nearest`: `!trigf 2600` runs and reads 2500) or rounded down (`down`: "
              "2777.78)."),
    SwitchDoc("periodic_first", ("enable", "period"), "L12565-12594, L12754-12770",
              "In the periodic modes 100 and 101 the first pulse comes as the trigger is "
              "enabled (`enable`) or one period later (`period`)."),
    SwitchDoc("bidirectional_next", ("reach", "neighbours"), "L12595-12836",
              "In the bidirectional distance modes (1, 4, 7, 10) every level the axis "
              "reaches fires, from either side (`reach`: going back and forth across one "
              "fires it each time), or only the levels one distance either side of the "
              "last that fired (`neighbours`)."),
    SwitchDoc("trigcomp_read", ("written", "step"), "L13057-13167",
              "`trigcomp` works in steps of 10 µs (L13060); `?trigcomp` reads the value as "
              "written (`written`), or the step it works with, the nearest, halves up "
              "(`step`: `!trigcomp 15` reads 20)."),
    # -- the link ------------------------------------------------------------------------
    SwitchDoc("local_echo", ("no", "yes"), "L8-10, L2117",
              "The link returns only the controller's replies (`no`), or, like a serial "
              "adapter or an RS-485 converter with local echo, also every byte the host "
              "sends, at once (`yes`; the manual knows only mode 4's echo, L2117). The "
              "driver refuses `yes` at connect with a `ConnectError` naming local echo.",
              unsupported=("yes",)),
)

#: Every switch by name, in documentation order.
SWITCHES: Mapping[str, SwitchDoc] = MappingProxyType({doc.name: doc for doc in _DOCS})


@dataclass(frozen=True)
class Firmware:
    """One choice for every switch (see :data:`SWITCHES` for what each one does).

    The defaults are the ``manual`` profile. Build one with :meth:`from_options` or
    :meth:`with_`, which check names and values; the constructor checks values too.
    """

    #: Mode 4: echo ``before`` or ``after`` executing the line.
    echo: str = "before"
    #: Mode 4: a move also sends its completion report (``yes``/``no``).
    echo_report: str = "yes"
    #: Mode 4: reads and lines without ``!`` are echoed too (``no``/``yes``).
    echo_all: str = "no"
    #: Mode 4: the echo is the ``exact`` text or ``normalized``.
    echo_text: str = "exact"
    #: Mode 2: reads acknowledged (``no``/``before``/``after`` their data).
    ack_reads: str = "no"
    #: Mode 2: ``ERR 5`` (``yes``) or bare ``ERR`` (``no``).
    err_number: str = "yes"
    #: Mode 2: ``!autostatus n`` acknowledged per the ``new`` or the ``old`` mode.
    ack_mode_change: str = "new"
    #: Mode 2: a move's ``OK...`` ``immediate`` or at ``completion``.
    move_ok: str = "immediate"
    #: Mode 2: acknowledgements in ``upper`` (``OK...``), ``lower`` or ``title`` case.
    ack_case: str = "upper"
    #: Mode 2: ``!save`` acknowledged ``once`` (its own ``OK...``) or ``twice``.
    save_ack: str = "once"
    #: A refused move also sends a report with ``E`` (``no``/``yes``).
    refused_move_report: str = "no"
    #: A move for moving axes: ``refuse``, ``queue`` or ``retarget``.
    move_during_move: str = "refuse"
    #: ``!axis`` 0 or -1 for a moving axis: ``continue``, ``stop`` or ``refuse``.
    disable_during_move: str = "continue"
    #: A move to where the axes are sends a report (``yes``/``no``).
    zero_move_report: str = "yes"
    #: A snapshot step reads the entry at the pointer first (``next``) or moves the
    #: pointer first (``advance``).
    snapshot_pointer: str = "next"
    #: A snapshot step sends a completion report (``no``/``yes``).
    snapshot_step_report: str = "no"
    #: A snapshot event while an axis moves: ``move`` or ``ignore``.
    snapshot_while_moving: str = "move"
    #: Report letters for ``four`` axes always or as many as the unit has (``axes``).
    report_width: str = "four"
    #: ``?statusaxis`` ends with ``.-`` (``yes``), nothing (``no``) or ``.`` (``dot``).
    status_tail: str = "yes"
    #: ``sa`` shows absent/disabled axes as ``dash`` or leaves them out (``omit``).
    absent_axes: str = "dash"
    #: Idle/completed axes while the joystick is enabled: ``@`` or ``J``.
    joystick_letter: str = "@"
    #: Letter of aborted axes: ``E`` or ``@``.
    abort_letter: str = "E"
    #: ``a`` sends a report of its own (``no``/``yes``).
    abort_report: str = "no"
    #: Ctrl+C: ``stop``, ``ignore`` or ``stop_report``.
    ctrl_c: str = "stop"
    #: ``?help N`` repeats N (``yes``/``no``).
    help_number: str = "yes"
    #: ``help`` answers in ``upper`` (``ERROR 5,...``) or ``lower`` case.
    help_case: str = "upper"
    #: ``service`` ends with ``END_SERVICE_PRINT.`` (``yes``/``no``).
    service_end: str = "yes"
    #: Extra CR in ``?lim``: ``extmode0``, ``none`` or ``both``.
    lim_cr_bug: str = "extmode0"
    #: ``?version`` format: ``new`` or ``old``.
    version_format: str = "new"
    #: ``?version 1``: the ``number`` only, or the whole ``line`` (the value ignored).
    version_value: str = "number"
    #: Reply line end: ``cr`` or ``crlf``.
    line_end: str = "cr"
    #: Number format: ``plain``, ``plus`` or ``negzero``.
    numbers: str = "plain"
    #: Instructions known: ``full`` (1.71) or ``older`` (the older edition's).
    instruction_set: str = "full"
    #: ``trigf``'s 40 µs tick count: ``nearest`` or rounded ``down``.
    trigf_round: str = "nearest"
    #: The periodic modes' first pulse: at ``!trig 1`` (``enable``) or a ``period`` later.
    periodic_first: str = "enable"
    #: Bidirectional modes: each level reached fires (``reach``), or the ``neighbours``.
    bidirectional_next: str = "reach"
    #: ``?trigcomp``: the value as ``written`` or on its 10 µs ``step``.
    trigcomp_read: str = "written"
    #: The link echoes every byte sent (``no``/``yes``: an adapter with local echo).
    local_echo: str = "no"

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            _check(field.name, getattr(self, field.name))

    @classmethod
    def from_options(cls, profile: str = "manual", **switches: str) -> Firmware:
        """The named profile with single switches on top.

        Raises ValueError naming the option and its allowed values for an unknown
        profile, switch or value.

        Parameters
        ----------
        profile
            The profile's name.
        **switches
            Switch values, by switch name.

        Returns
        -------
        Firmware
            The firmware.

        Raises
        ------
        ValueError
            An unknown profile, switch or value.
        """
        base = PROFILES.get(profile)
        if base is None:
            raise ValueError(f"unknown firmware profile {profile!r}; "
                             f"allowed: {', '.join(PROFILES)}")
        return base.with_(**switches)

    def with_(self, **switches: str) -> Firmware:
        """A copy with ``switches`` overridden (names and values checked).

        Parameters
        ----------
        **switches
            Switch values, by switch name.

        Returns
        -------
        Firmware
            The copy.

        Raises
        ------
        ValueError
            An unknown switch or value.
        """
        for name, value in switches.items():
            if name not in SWITCHES:
                raise ValueError(f"unknown firmware switch {name!r}; "
                                 f"allowed: {', '.join(SWITCHES)}")
            _check(name, value)
        return dataclasses.replace(self, **switches)

    @classmethod
    def from_fingerprint(cls, fingerprint: Mapping[str, object] | str | os.PathLike[str]
                         ) -> Firmware:
        """The firmware a fingerprint describes (a file written by ``tango-aio probe``, or
        its JSON already loaded).

        The firmware is the fingerprint's ``switches`` mapping on top of the ``manual``
        profile (the instructions the unit lacks are :func:`fingerprint_lacks`'s). A
        switch the probe could not observe (absent, or ``null``: e.g. the move switches of
        a probe without ``--moves``) keeps the ``manual`` value; what it recorded as
        unknown is not a switch value and is left out. Raises ValueError for a file that
        is not a fingerprint or holds a switch name or value the emulator does not know.

        Parameters
        ----------
        fingerprint
            The fingerprint's file, or its JSON data.

        Returns
        -------
        Firmware
            The firmware.

        Raises
        ------
        ValueError
            Not a fingerprint, or an unknown switch name or value.
        """
        fingerprint = _fingerprint_data(fingerprint)
        switches = fingerprint.get("switches")
        if not isinstance(switches, Mapping):
            raise ValueError("not a fingerprint: no 'switches' object")
        chosen = {str(name): value for name, value in switches.items() if value is not None}
        for name, value in chosen.items():
            if not isinstance(value, str):
                raise ValueError(f"fingerprint switch {name}={value!r} is not a string")
        return cls().with_(**chosen)

    def changed(self) -> dict[str, str]:
        """The switches whose value differs from the ``manual`` profile.

        Returns
        -------
        dict[str, str]
            Their values, by switch name.
        """
        return {name: getattr(self, name) for name, doc in SWITCHES.items()
                if getattr(self, name) != doc.default}


def fingerprint_lacks(fingerprint: Mapping[str, object] | str | os.PathLike[str]
                      ) -> frozenset[str]:
    """The instructions a fingerprint says its unit lacks (its ``lacks`` list: no reply,
    error 4, L970), for :attr:`~tango_aio.sim.model.SimConfig.lacks`; none when it has no
    such list.

    Parameters
    ----------
    fingerprint
        The fingerprint's file, or its JSON data.

    Returns
    -------
    frozenset[str]
        The instruction names, in lower case.

    Raises
    ------
    ValueError
        Not a fingerprint, or a ``lacks`` that is not a list of names.
    """
    lacks = _fingerprint_data(fingerprint).get("lacks", [])
    if not isinstance(lacks, list) or not all(isinstance(name, str) and name.strip()
                                              for name in lacks):
        raise ValueError(f"fingerprint lacks={lacks!r} is not a list of instruction names")
    return frozenset(name.strip().lower() for name in lacks)


def _fingerprint_data(fingerprint: Mapping[str, object] | str | os.PathLike[str]
                      ) -> Mapping[str, object]:
    """A fingerprint's JSON object (read from its file); ValueError if it is none."""
    if not isinstance(fingerprint, Mapping):
        path = Path(fingerprint)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"cannot read fingerprint {str(path)!r}: {exc}") from None
        if not isinstance(data, Mapping):
            raise ValueError(f"{str(path)!r} is not a fingerprint (no JSON object)")
        fingerprint = data
    kind = fingerprint.get("format", "tango_aio.fingerprint/")
    if not str(kind).startswith("tango_aio.fingerprint/"):
        raise ValueError(f"not a fingerprint: format {kind!r}")
    return fingerprint


def _check(name: str, value: object) -> None:
    doc = SWITCHES[name]
    if value not in doc.values:
        raise ValueError(f"firmware switch {name}={value!r} is not allowed; "
                         f"allowed: {', '.join(doc.values)}")


#: The named profiles.
PROFILES: Mapping[str, Firmware] = MappingProxyType({
    "manual": Firmware(),
    # The older edition where it differs from 1.71: help takes no parameter
    # (old L805-819), 'a' is answered like a move (old L725) and its axes report '@'
    # (old L1917), mode 4 echoes all input (old L723), no END_SERVICE_PRINT. (added with
    # 1.60C/1.61, L2941-2943), the old ?version format (old L426), only its instructions.
    "legacy": Firmware(help_number="no", abort_letter="@", abort_report="yes",
                       echo_all="yes", service_end="no", version_format="old",
                       instruction_set="older"),
})


def variants(*, unsupported: bool = False) -> list[tuple[str, Firmware]]:
    """``manual``, ``legacy``, then ``manual`` with each single non-default switch value
    (named ``switch=value``): the firmwares a client's test matrix runs against.

    Values the driver does not serve yet (:attr:`SwitchDoc.unsupported`) are left out
    unless ``unsupported`` is true (the probe's tests take every value).

    Parameters
    ----------
    unsupported
        Include the values the driver does not serve yet.

    Returns
    -------
    list[tuple[str, Firmware]]
        The name and the firmware of each variant.
    """
    out: list[tuple[str, Firmware]] = list(PROFILES.items())
    manual = PROFILES["manual"]
    for name, doc in SWITCHES.items():
        for value in doc.values[1:]:
            if unsupported or value not in doc.unsupported:
                out.append((f"{name}={value}", manual.with_(**{name: value})))
    return out


def switch_table() -> str:
    """The Markdown table of every switch (the firmware-profiles page's, checked by a test).

    Returns
    -------
    str
        The table.
    """
    rows = ["| switch | values (* not served by the driver yet) | `manual` | `legacy` "
            "| manual lines |",
            "|---|---|---|---|---|"]
    legacy = PROFILES["legacy"]
    for name, doc in SWITCHES.items():
        values = " \\| ".join(f"`{v}`" + ("*" if v in doc.unsupported else "")
                               for v in doc.values)
        rows.append(f"| `{name}` | {values} | `{doc.default}` | `{getattr(legacy, name)}` "
                    f"| {doc.lines} |")
    return "\n".join(rows)
