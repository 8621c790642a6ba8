"""The core's cache of what a read line owes (``ProtocolCore._line_facts``) against the
plain computation: on random lines, modes and read acknowledgements, the same bytes and
the same expectations registered."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import parse
from tango_aio.sansio._core import AckReads, ProtocolCore, owed_edge
from tango_aio.sansio._expect import expectation

LINES = ["?pos", "?pos x", "?vel", "?vel x", "?err", "?statusaxis", "?dim", "?lim x",
         "?version", "?trigc", "?autostatus", "?help", "!vel x 3", "!moa x 1", "sa x",
         "?detext", "?snsa 1", "err"]


class _NoCache(dict[Any, Any]):
    """Remembers nothing: every line takes the plain path."""

    def __setitem__(self, key: Any, value: Any) -> None:
        pass


def _registered(core: ProtocolCore) -> list[tuple[object, ...]]:
    return [(tuple(p.items), p.echo, p.rule, p.pattern, p.internal, p.rear)
            for p in core._pending]  # the two paths' registered state


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(LINES), st.sampled_from([0, 1, 2, 3, 4]),
                          st.sampled_from([None, *AckReads]), st.booleans()),
                min_size=1, max_size=20))
def test_cached_and_plain_paths_register_the_same(
        steps: list[tuple[str, int, AckReads | None, bool]]) -> None:
    cached, plain = ProtocolCore(marker_seed=0), ProtocolCore(marker_seed=0)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(plain, "_facts", _NoCache())
        for tag, (text, mode, ack_reads, known) in enumerate(steps):
            command = parse(text)
            results = []
            for core in (cached, plain):
                core.autostatus, core.ack_reads = mode, ack_reads
                hint = (mode, expectation(command, mode, core.context)) if known else None
                results.append((core.send(command, tag, hint), _registered(core)))
            assert results[0] == results[1], text


def test_a_read_is_computed_once_per_mode() -> None:
    core = ProtocolCore()
    for _ in range(3):
        core.send(parse("?pos"), object())
    assert len([key for key in core._facts if key[0] == "?pos"]) == 1


def test_each_core_keeps_its_own_facts() -> None:
    one, other = ProtocolCore(), ProtocolCore()
    one.send(parse("?pos"), object())
    assert any(key[0] == "?pos" for key in one._facts)
    assert not other._facts


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(LINES), st.sampled_from([0, 1, 2, 3, 4]),
                          st.sampled_from([None, *AckReads])),
                min_size=1, max_size=20))
def test_owed_is_owed_edge(steps: list[tuple[str, int, AckReads | None]]) -> None:
    core = ProtocolCore()
    for text, mode, ack_reads in steps:
        command = parse(text)
        core.ack_reads = ack_reads
        expect = expectation(command, mode, core.context)
        assert core.owed(command, expect, mode) == owed_edge(command, expect, mode,
                                                             core.context, ack_reads)
