"""Turn a JUnit XML report of tests/e2e/test_matrix.py into RELIABILITY.md's table.

Usage::

    python -m pytest -q -m "slow or not slow" tests/e2e/test_matrix.py \\
        --junitxml=/tmp/matrix.xml
    python tools/matrix_report.py /tmp/matrix.xml [more.xml ...]

One row per firmware variant, one column per invariant: each cell counts the scenario runs
(both baud rates) that check the invariant and how many passed; ``xfail`` runs are
counted apart (they are known failures, kept strict).
"""

from __future__ import annotations

import re
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict

#: Which invariants each scenario asserts (see the test module's docstring).
INVARIANTS: dict[str, tuple[str, ...]] = {
    "test_connect_and_identify": ("own replies", "typed and bounded"),
    "test_each_autostatus_mode_and_changes": ("arrived", "own replies", "typed and bounded"),
    "test_move_to_move_by_and_subsets": ("arrived", "typed and bounded"),
    "test_queued_moves_keep_their_own_timeout": ("arrived", "typed and bounded"),
    "test_cal_and_rm": ("arrived", "typed and bounded"),
    "test_queries_while_moving_get_their_own_reply": ("arrived", "own replies"),
    "test_abort_never_succeeds": ("no false success", "typed and bounded"),
    "test_cancelled_moves": ("no false success", "arrived", "typed and bounded"),
    "test_joystick_off_during_a_move_does_not_end_it": ("no false success", "arrived"),
    "test_pause_and_delay_count_in_the_move": ("no false success", "arrived"),
    "test_internal_error_is_not_blamed_on_the_command": ("typed and bounded",),
    "test_events_follow_confirmed_moves": ("no false success", "typed and bounded"),
    "test_a_refused_move_is_an_error": ("no false success", "typed and bounded"),
    "test_absent_axis_letters_are_not_credited_to_another": ("no false success",),
    "test_list_upload": ("own replies", "typed and bounded"),
}
#: A case id: scenario[extra parameter-]variant-baud.
_CASE = re.compile(r"(test_\w+)\[(?:a-|ctrl_c-|[01]-)?(.+)-(0|57600)\]$")
COLUMNS = ("arrived", "no false success", "own replies", "typed and bounded")


def main(*paths: str) -> None:
    """Print the Markdown table for the reports at ``paths``."""
    cells: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(lambda: [0, 0, 0]))
    failed: dict[str, set[str]] = defaultdict(set)
    order: list[str] = []
    cases = [case for path in paths for case in ET.parse(path).getroot().iter("testcase")]
    for case in cases:
        match = _CASE.match(case.get("name", ""))
        if match is None:
            continue
        scenario, variant = match.group(1), match.group(2)
        if variant not in order:
            order.append(variant)
        skipped = case.find("skipped")
        xfail = skipped is not None and "xfail" in (skipped.get("type", "") +
                                                    skipped.get("message", ""))
        if skipped is not None and not xfail:
            continue
        ok = case.find("failure") is None and case.find("error") is None and not xfail
        for invariant in INVARIANTS.get(scenario, ()):
            cell = cells[variant][invariant]
            cell[0] += 1
            cell[1] += ok
            cell[2] += xfail
        if not ok:
            failed[variant].add(scenario.removeprefix("test_"))
    print("| variant | " + " | ".join(COLUMNS) + " | not passing |")
    print("|---|" + "---|" * (len(COLUMNS) + 1))
    for variant in order:
        row = []
        for column in COLUMNS:
            runs, passed, xfails = cells[variant][column]
            text = f"{passed}/{runs}"
            row.append(text + (f" ({xfails} xfail)" if xfails else ""))
        print(f"| `{variant}` | " + " | ".join(row) + " | "
              + (", ".join(sorted(failed[variant])) or "-") + " |")


if __name__ == "__main__":
    main(*sys.argv[1:])
