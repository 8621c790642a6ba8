"""The events the core yields: a reply, an acknowledgement, an echo, a completion report,
an unsolicited, dropped or mismatched line, a lost request."""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

from ._patterns import (
    ReplyPattern,
)


@dataclass(frozen=True, slots=True)
class Replied:
    """The data reply of request ``tag``. ``done``: the request owes nothing more."""

    tag: Hashable
    lines: tuple[str, ...]
    done: bool = True


@dataclass(frozen=True, slots=True)
class Acknowledged:
    """``OK...`` (``code == 0``) or ``ERR n`` for request ``tag`` (``code`` None: no number).

    ``deferred``: the verdict is the reply of the ``?err`` written behind a mode-2 move,
    which arrived where the move's own ``OK...`` was owed (``line`` is that reply). It
    shows that no error was reported, not that the move line arrived: firmware that
    sends the ``OK...`` only with the completion report (switch ``move_ok``) and a lost
    move line look the same here (L2099-2103 do not say when the ``OK...`` comes).
    """

    tag: Hashable
    code: int | None
    line: str
    done: bool = True
    deferred: bool = False


@dataclass(frozen=True, slots=True)
class Echoed:
    """The autostatus-4 echo of request ``tag``.

    ``deferred``: no echo came where the move's was owed (``line`` is empty), the reply
    of the ``?err`` behind it came instead: the echo may come with the completion report
    (switch ``echo=completion``; L2115-2117 do not say when), or the line was lost.
    """

    tag: Hashable
    line: str
    done: bool = True
    deferred: bool = False


@dataclass(frozen=True, slots=True)
class Completed:
    """A completion report. ``tag`` is the move it belongs to, ``None`` if unsolicited."""

    tag: Hashable | None
    letters: dict[str, str] | None
    line: str


@dataclass(frozen=True, slots=True)
class Unsolicited:
    """A line that no request was waiting for."""

    line: str


@dataclass(frozen=True, slots=True)
class Dropped:
    """A line discarded while resynchronising."""

    line: str


@dataclass(frozen=True, slots=True)
class Mismatched:
    """A line arrived for request ``tag`` that cannot be its reply (see
    :mod:`tango_aio.sansio._patterns`): a reply went missing or a line was added. ``tag`` is
    ``None`` for the core's own follow-up query. The core drops every line (completion
    reports excepted) until :meth:`ProtocolCore.resync` is called.
    """

    tag: Hashable | None
    line: str
    expected: ReplyPattern
    #: Why, when the line itself would fit (a reply grown past its cap).
    reason: str = ""


@dataclass(frozen=True, slots=True)
class RequestLost:
    """Request ``tag`` will get no reply: its line was discarded, or the stream resynced."""

    tag: Hashable


Event = (Replied | Acknowledged | Echoed | Completed | Unsolicited | Dropped | RequestLost
         | Mismatched)
