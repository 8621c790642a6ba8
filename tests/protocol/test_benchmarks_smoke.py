"""The benchmark harness still runs: every module imports, the canned-transport cases run
their tiniest size and produce numbers (no timing is asserted), the table renders."""

from __future__ import annotations

import argparse
import cProfile
import importlib
import math

import pytest

from benchmarks import canned, profiles, sets
from benchmarks.__main__ import CASES, RUNNERS, Row, table

MODULES = ["benchmarks.__main__", "benchmarks.bluesky", "benchmarks.canned", "benchmarks.moves",
           "benchmarks.profiles", "benchmarks.scaling", "benchmarks.sets",
           "benchmarks.transports",
           "benchmarks.upload", "benchmarks.watch"]


@pytest.mark.parametrize("name", MODULES)
def test_module_imports(name: str) -> None:
    module = importlib.import_module(name)
    assert module.__doc__


def test_every_case_has_a_runner() -> None:
    assert set(RUNNERS) == set(CASES)


def _measured(cost: canned.Cost) -> bool:
    return all(math.isfinite(value) and value >= 0 for value in cost.cpu_seconds) and \
        bool(cost.cpu_seconds)


async def test_canned_requests_produce_numbers() -> None:
    pairs = await canned.requests(calls=3, rounds=1)
    assert [driver.name for driver, _ in pairs] == [
        "driver ?pos", "driver checked set", "driver ?pos, no separators",
        "driver checked set, no separators"]
    for driver, raw in pairs:
        assert _measured(driver) and _measured(raw)


async def test_proven_sets_beside_today_s() -> None:
    results = await sets.main(calls=2, rounds=1, mode=1)
    for figures in results.values():
        assert figures["today ms/set"] > 0 and figures["proven ms/set"] > 0
        # The read-back (and the separator before it) reached the controller.
        assert figures["proven lines/set"] == figures["today lines/set"] + 2


async def test_canned_moves_produce_latencies() -> None:
    driver, raw = await canned.moves(count=3, rounds=1)
    assert _measured(driver) and _measured(raw)
    assert len(driver.latencies) == len(raw.latencies) == 3
    assert all(latency > 0 for latency in driver.latencies + raw.latencies)


async def test_canned_transport_replays_what_it_recorded() -> None:
    tango, link = await canned.canned_driver()
    try:
        first = await tango.position()
        link.recording = False
        link.model = None  # type: ignore[assignment]  # a replayed line must not need it
        assert await tango.position() == first
    finally:
        await tango.aclose()


def test_runner_case_rows() -> None:
    rows = RUNNERS["requests"](None, argparse.Namespace(quick=True))
    assert [row.unit for row in rows] == ["µs"] * 4
    assert all(row.ratio is not None and row.ratio > 0 for row in rows)


def test_table_renders_loops_side_by_side() -> None:
    asyncio_rows = [Row("moves", "tiny moves", "moves/s", 80.0, 160.0, True, "≥ 0.95"),
                    Row("compat", "socket://", "works", 1.0)]
    uvloop_rows = [Row("moves", "tiny moves", "moves/s", 100.0, 160.0, True, "≥ 0.95"),
                   Row("compat", "socket://", "works", 0.0, note="AssertionError")]
    text = table({"asyncio": asyncio_rows, "uvloop": uvloop_rows})
    assert "| tiny moves | moves/s | 80.0 | 160 | **0.50** | ≥ 0.95 | 100 | 160 | **0.62** | " \
        "1.25 |" in text
    assert "**no**" in text and "uvloop: AssertionError" in text


async def test_profile_summary_of_a_canned_query() -> None:
    profile = cProfile.Profile()
    await profiles._profile_canned("query", 5, profile)
    text = profiles.summary(profile, 5, "?pos")
    assert "tango_aio/" in text and "µs/op" in text
