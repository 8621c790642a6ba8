"""moves.acceptance_shown (the tracker): what proves a move line whose acceptance was deferred
(its autostatus-2 OK... or autostatus-4 echo did not come where owed) arrived."""

from __future__ import annotations

import pytest

from tango_aio.moves import acceptance_shown


@pytest.mark.parametrize(("reported", "letters", "moved", "shown"), [
    (True, {"x": "@", "y": "@"}, ("x",), True),  # its report came
    (False, {"x": "M", "y": "@"}, ("x",), True),  # a moved axis moves
    (False, {"x": "M", "y": "@"}, ("x", "y"), True),
    (False, {"x": "@", "y": "@"}, ("x",), False),  # standing, no report: unproven
    (False, {"x": "@", "y": "M"}, ("x",), False),  # another axis moving proves nothing
    (False, {"x": "E"}, ("x",), False),
    (False, {}, ("x",), False),  # the axis not in the reply
])
def test_acceptance_shown(reported: bool, letters: dict[str, str], moved: tuple[str, ...],
                          shown: bool) -> None:
    assert acceptance_shown(reported, letters, moved) is shown
