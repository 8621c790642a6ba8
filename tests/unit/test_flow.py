"""Sans-IO tests of the write-credit window (tango_aio.sansio._flow)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.sansio._flow import MARKER, CreditWindow


def test_reply_confirms_its_line_and_everything_before() -> None:
    window = CreditWindow(limit=255, chunk=120)
    window.wrote(18, None)
    window.wrote(5, "q1")
    window.wrote(18, None)
    assert window.outstanding == 41
    window.confirm("q1")
    assert window.outstanding == 18
    assert window.unmarked == 18


def test_echo_confirms_only_what_came_before() -> None:
    window = CreditWindow()
    window.wrote(10, None)
    window.wrote(8, "set")
    window.confirm("set", inclusive=False)
    assert window.outstanding == 8


def test_unknown_tag_confirms_nothing() -> None:
    window = CreditWindow()
    window.wrote(10, "a")
    window.confirm("zzz")
    assert window.outstanding == 10


def test_replyless_lines_keep_room_for_a_marker() -> None:
    window = CreditWindow(limit=255, chunk=120)
    window.wrote(240, "big")
    assert window.fits(15, has_reply=True)
    assert not window.fits(16, has_reply=True)
    assert window.fits(15 - len(MARKER), has_reply=False)
    assert not window.fits(16 - len(MARKER), has_reply=False)


def test_marker_due_after_a_chunk_of_replyless_bytes() -> None:
    window = CreditWindow(limit=255, chunk=40)
    window.wrote(18, None)
    assert not window.marker_due(18, next_has_reply=False)
    window.wrote(18, None)
    assert window.marker_due(18, next_has_reply=False)  # 36 + 18 > 40
    assert not window.marker_due(5, next_has_reply=True)
    window.wrote(len(MARKER), "m")
    assert window.unmarked == 0
    assert not window.marker_due(18, next_has_reply=False)


def test_marker_due_when_blocked_with_an_unconfirmable_tail() -> None:
    window = CreditWindow(limit=100, chunk=90)
    window.wrote(60, None)
    # A 50-byte query does not fit, and nothing in flight would ever confirm the tail.
    assert window.marker_due(50, next_has_reply=True)


def test_ctrl_c_clears_everything() -> None:
    window = CreditWindow()
    window.wrote(100, None)
    window.cleared()
    assert window.outstanding == 0 and window.unmarked == 0


def test_overlong_replyless_line_only_when_idle() -> None:
    window = CreditWindow(limit=255)
    assert window.fits(254, has_reply=False)
    window.wrote(1, "x")
    assert not window.fits(254, has_reply=False)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 60), st.booleans()), max_size=200),
       st.integers(20, 255))
def test_simulated_stream_never_exceeds_the_limit(lines: list[tuple[int, bool]],
                                                  limit: int) -> None:
    """Drive the window like the protocol does, with replies arriving in order."""
    window = CreditWindow(limit=limit, chunk=limit // 2)
    lines = [(min(size, limit), has_reply) for size, has_reply in lines]  # a line <= limit
    queue = list(lines)
    in_flight: list[str] = []
    tags = iter(range(10**9))
    while queue or in_flight:
        progressed = False
        while queue:
            size, has_reply = queue[0]
            if window.marker_due(size, has_reply) and window.marker_fits():
                tag = f"m{next(tags)}"
                window.wrote(len(MARKER), tag)
                in_flight.append(tag)
                progressed = True
                continue
            if not window.fits(size, has_reply):
                break
            reply_tag = f"r{next(tags)}" if has_reply else None
            window.wrote(size, reply_tag)
            if reply_tag is not None:
                in_flight.append(reply_tag)
            queue.pop(0)
            progressed = True
            assert window.outstanding <= limit or window.outstanding == size
        if not queue and window.marker_due(None, False) and window.marker_fits():
            tag = f"m{next(tags)}"
            window.wrote(len(MARKER), tag)
            in_flight.append(tag)
        if in_flight:
            window.confirm(in_flight.pop(0))
        elif not progressed:
            # Nothing in flight and nothing writable would be a deadlock.
            assert not queue
        oversized = any(size + len(MARKER) > limit for size, _ in lines)
        assert window.peak <= limit or (oversized and window.peak <= limit + len(MARKER))


def _line_by_line(window: CreditWindow, ends: list[int], first: int) -> int:
    """What the scheduler did before wrote_run: one wrote() per line, checked."""
    start = ends[first - 1] if first else 0
    window.wrote(ends[first] - start, None)
    index = first + 1
    while index < len(ends):
        size = ends[index] - ends[index - 1]
        if window.marker_due(size, False) or not window.fits(size, False):
            break
        window.wrote(size, None)
        index += 1
    return index


def _state(window: CreditWindow) -> tuple[object, ...]:
    return (window.outstanding, window.unmarked, window.peak,
            [(item.size, item.tag) for item in window._written])


@settings(max_examples=200, deadline=None)
@given(limit=st.integers(8, 300), chunk=st.integers(1, 300),
       before=st.lists(st.tuples(st.integers(1, 80), st.sampled_from([None, "a", "b"])),
                       max_size=6),
       sizes=st.lists(st.integers(1, 120), min_size=1, max_size=40), data=st.data())
def test_wrote_run_counts_what_line_by_line_writes_count(
        limit: int, chunk: int, before: list[tuple[int, str | None]], sizes: list[int],
        data: st.DataObject) -> None:
    ends = [sum(sizes[: i + 1]) for i in range(len(sizes))]
    first = data.draw(st.integers(0, len(ends) - 1))
    windows = [CreditWindow(limit=limit, chunk=chunk) for _ in range(2)]
    for window in windows:
        for size, tag in before:
            window.wrote(size, tag)
    assert windows[0].wrote_run(ends, first) == _line_by_line(windows[1], ends, first)
    assert _state(windows[0]) == _state(windows[1])


def test_a_reserve_cuts_the_chunk_so_a_line_and_the_marker_fit_behind_it() -> None:
    assert CreditWindow(limit=255, chunk=160, reserve=9).chunk == 160  # fits: not cut
    assert CreditWindow(limit=40, chunk=160).chunk == 36
    assert CreditWindow(limit=40, chunk=160, reserve=9).chunk == 27  # 27 + 9 + 4 = 40
    assert CreditWindow(limit=10, chunk=160, reserve=9).chunk == 1  # never below a byte
