"""The controllers' servers, their pollers, the access guard and the IOC that serves them."""

from __future__ import annotations

import asyncio
import logging
import os
from collections.abc import Awaitable, Callable, Mapping, Sequence
from typing import Any

from caproto import AccessRights, AlarmSeverity, AlarmStatus, CAStatus, Forbidden

from ..catalog import AXES
from ..controller import Controller
from ..errors import ConnectionLostError, ControllerError, MoveStoppedError, TangoError
from ..group import MoveCoalescer
from ..status import AxisStatus
from ..units import DEFAULT_USTEPS
from .access import AccessPolicy
from .autosave import Autosave
from .axis import AxisServer
from .fields import _FAILED, WRITABLE, ControllerPVs
from .flush import FlushingContext
from .record import AxisUnits

log = logging.getLogger("tango_aio.epics")

#: How many polls of ``?pos``/``?statusaxis`` per read of switches and counters.
SLOW_EVERY = 5

#: How many polls per read of the unit settings (five reads, pipelined).
UNITS_EVERY = 5 * SLOW_EVERY


class ControllerServer:
    """The PVs of one controller: its axes and controller PVs, and the poller."""

    def __init__(self, controller: Controller, prefix: str, *, poll: float = 0.1,
                 window: float = 0.02, merge: str = "turn",
                 autosave: Autosave | None = None,
                 group: ControllerPVs | None = None) -> None:
        self.controller = controller
        self.autosave = autosave
        self._restored = autosave is None
        self.prefix = prefix
        self.poll = poll
        # merge="turn": no fixed wait. VAL puts announce themselves as they start, and a
        # merged move waits only for the puts already on their way (those that arrived
        # together, e.g. in one TCP read), ``window`` bounding that wait; a lone put
        # waits for nothing. merge="window": every move waits ``window`` seconds for
        # puts to other axes (a client that writes them one by one, each flushed).
        if merge not in ("turn", "window"):
            raise ValueError(f"merge must be 'turn' or 'window', got {merge!r}")
        self.coalescer = MoveCoalescer(controller, window=window,
                                       collect="announced" if merge == "turn" else "window")
        self.group = group if group is not None else ControllerPVs(prefix)
        self.link_up = controller.connected
        self._lacking: set[str] = set()  # settings this controller refused
        self.context: FlushingContext | None = None
        # The context's axis count: set by identification, or the connect() default when
        # the controller was connected with identify=False (the identity is not read).
        count = controller.context.axes
        self.axes = [AxisServer(self, letter) for letter in AXES[:count]]

    @property
    def pvdb(self) -> dict[str, Any]:
        """Every PV of this controller, by name."""
        pvdb: dict[str, Any] = dict(self.group.pvdb)
        for axis in self.axes:
            pvdb.update(axis.group.pvdb)
        return pvdb

    async def start(self) -> None:
        """Read the settings and publish the first values (with the controller down, the
        PVs start INVALID and the poller connects them when it comes)."""
        try:
            await self._set_link(self.controller.connected, force=True)
        except ConnectionLostError:
            await self._set_link(False, force=True)

    async def read_units(self) -> tuple[dict[str, AxisUnits], int]:
        """Read every axis's unit settings (``dim``, ``pitch``, ``gear``, ``usteps``) and
        the decimals of printed positions (``resolution``), pipelined."""
        c = self.controller
        dims, pitch, gear, usteps, decimals = await asyncio.gather(
            c.get("dim"), c.get("pitch"), self._optional("gear", None),
            self._optional("usteps", DEFAULT_USTEPS), self._optional("resolution", 4))
        units = {axis.letter: AxisUnits(
            int(dims[axis.letter]), float(pitch[axis.letter]),
            float(gear[axis.letter]) if isinstance(gear, Mapping) else 1.0, int(usteps))
            for axis in self.axes}
        return units, int(decimals)

    async def _optional(self, name: str, default: Any) -> Any:
        """Read ``name``; a controller that refuses it (older firmware may lack gear,
        usteps or resolution) gives ``default``, with one warning, and is not asked again."""
        if name in self._lacking:
            return default
        try:
            return await self.controller.get(name)
        except ControllerError as exc:
            self._lacking.add(name)
            log.warning("%s: ?%s refused (%s); assuming %s", self.prefix, name, exc,
                        default)
            return default

    async def flush(self) -> None:
        """Wait until the monitor updates published so far are on the wire to every
        client (no-op before the server runs)."""
        if self.context is not None:
            await self.context.flush()

    async def link_lost(self) -> None:
        """A request saw the link down: every PV but CONNECTED goes INVALID now."""
        await self._set_link(False)

    async def report_error(self, exc: BaseException) -> None:
        """Publish ``exc`` as the last error (``P:ERROR``, ``P:ERROR:TEXT``)."""
        number = exc.number if isinstance(exc, ControllerError) else -1
        await self.group.error.write(number, verify_value=False)
        await self.group.error_text.write(str(exc)[:255], verify_value=False)
        if not self.link_up:  # the failed put's WRITE alarm must not hide the link state
            for axis in self.axes:
                await axis.assert_invalid()

    async def _set_link(self, up: bool, *, force: bool = False) -> None:
        if up == self.link_up and not force:
            return
        group = self.group
        if not up:
            self.link_up = False
            log.warning("%s: link to %s lost", self.prefix, self.controller.url)
            await self.report_error(ConnectionLostError(f"link to {self.controller.url} lost"))
        for axis in self.axes:
            await axis.link_changed(up)
        severity = AlarmSeverity.NO_ALARM if up else AlarmSeverity.INVALID_ALARM
        status = AlarmStatus.NO_ALARM if up else AlarmStatus.COMM
        for pv in (group.autostatus, group.trigcount, group.error, group.error_text):
            await pv.alarm.write(status=status, severity=severity)
        await group.connected.write(int(up), verify_value=False)
        if up:
            await group.autostatus.write(self.controller.autostatus, verify_value=False)
            log.info("%s: connected to %s", self.prefix, self.controller.url)
            if not self._restored and self.autosave is not None:
                for axis in self.axes:
                    saved = self.autosave.values.get(axis.record.pvname)
                    if saved:
                        await axis.restore(saved)
                self._restored = True
        # Up only once every setting was read: a failed read is tried again next poll.
        self.link_up = up

    async def run(self) -> None:
        """Poll until cancelled; follows the link down and up again."""
        count = 0
        while True:
            try:
                await self._poll_once(slow=count % SLOW_EVERY == 0,
                                      units=count % UNITS_EVERY == 0)
            except ConnectionLostError:
                pass  # seen as link down by the next round
            except TangoError as exc:  # a timeout, a garbled reply: try again later
                log.warning("%s: poll failed: %s", self.prefix, exc)
            count += 1
            await asyncio.sleep(self.poll)

    async def _poll_once(self, *, slow: bool, units: bool = False) -> None:
        c = self.controller
        if not c.connected:
            await self._set_link(False)
            for axis in self.axes:
                await axis.assert_invalid()
            return
        await self._set_link(True)
        seen = [axis.finished for axis in self.axes]
        positions = await c.position()
        letters = await c.status()
        for axis, finished in zip(self.axes, seen, strict=True):
            if axis.finished != finished:
                # A request of this axis ended while the poll read: what it published
                # (its RBV, MOVN=0, DMOV=1, maybe already sent as a put's completion) is
                # newer than this poll's letters and position, which may show it moving.
                continue
            await axis.poll_update(positions.get(axis.letter, 0.0),
                                   letters.get(axis.letter, AxisStatus.READY.value))
        if slow:
            readsw = await c.query("?readsw")
            statuslimit = await c.query("?statuslimit")
            settings = await self.read_units() if units else None
            for axis in self.axes:
                await axis.slow_update(readsw, statuslimit)
                # Settings changed through another path (the driver, another program on
                # this link, the IOC's own puts) show here.
                if settings is not None:
                    await axis.units_read(settings[0][axis.letter], settings[1])
                await axis.follow_limits()
            await self.group.trigcount.write(int(await c.get("trigcount")), verify_value=False)
            await self.group.autostatus.write(c.autostatus, verify_value=False)

    async def aclose(self) -> None:
        """Stop what the coalescer is moving."""
        await self.coalescer.aclose()


# --------------------------------------------------------------------------------- the IOC


def _guard(pv: Any, policy: AccessPolicy,
           on_error: Callable[[BaseException], Awaitable[None]], *,
           writable: bool = True) -> None:
    """Make ``pv`` refuse writes to clients the policy does not allow (status
    ECA_NOWTACCESS), and answer a put whose handler failed with the status ECA_PUTFAIL."""
    own_check, own_write = pv.check_access, pv.auth_write

    def check_access(hostname: str, username: str) -> AccessRights:
        rights = own_check(hostname, username)
        if not writable or not policy.may_write(hostname, username):
            rights &= ~AccessRights.WRITE
        return rights

    async def auth_write(hostname: str, username: str, *args: Any, **kwargs: Any) -> Any:
        _FAILED.set(None)
        try:
            status = await own_write(hostname, username, *args, **kwargs)
            failed = _FAILED.get()
            if isinstance(failed, MoveStoppedError):
                log.info("%s: put by %s@%s ended short: %s", pv.pvname, username,
                         hostname, failed)
                return CAStatus.ECA_PUTFAIL
            if failed is not None:
                raise failed
            return status
        except Forbidden:
            log.warning("%s: write refused to %s@%s", pv.pvname, username, hostname)
            return CAStatus.ECA_NOWTACCESS
        except Exception as exc:
            log.warning("%s: put by %s@%s failed: %s", pv.pvname, username, hostname, exc)
            await on_error(exc)
            return CAStatus.ECA_PUTFAIL

    pv.check_access = check_access
    pv.auth_write = auth_write


class WaitingServer:
    """A controller that could not be reached when the IOC started."""

    def __init__(self, open_controller: Callable[[], Awaitable[Controller]], prefix: str,
                 *, poll: float, window: float, autosave: Autosave | None,
                 retry: float = 2.0, merge: str = "turn") -> None:
        self.open_controller = open_controller
        self.prefix = prefix
        self.retry = retry
        self.group = ControllerPVs(prefix)
        self._options = {"poll": poll, "window": window, "merge": merge,
                         "autosave": autosave}
        self.server: ControllerServer | None = None

    @property
    def pvdb(self) -> dict[str, Any]:
        """The controller PVs, served while waiting."""
        return dict(self.group.pvdb)

    async def start(self) -> None:
        """Publish the waiting state: CONNECTED=0, every other PV INVALID."""
        for pv in (self.group.autostatus, self.group.trigcount, self.group.error,
                   self.group.error_text):
            await pv.alarm.write(status=AlarmStatus.COMM,
                                 severity=AlarmSeverity.INVALID_ALARM)
        await self.group.error_text.write(f"waiting for the controller at {self.prefix}",
                                          verify_value=False)

    async def connect(self) -> ControllerServer:
        """Try until the controller answers; return its server (started)."""
        while True:
            try:
                controller = await self.open_controller()
            except (TangoError, OSError) as exc:
                log.info("%s: controller not reachable yet: %s", self.prefix, exc)
                await asyncio.sleep(self.retry)
                continue
            if _unidentified(controller):
                await controller.identify()
            server = ControllerServer(controller, self.prefix, group=self.group,
                                      **self._options)  # type: ignore[arg-type]
            await server.start()
            self.server = server
            return server


class TangoIoc:
    """An IOC serving one or more controllers. Build it with :func:`build_ioc`."""

    def __init__(self, servers: Sequence[ControllerServer], policy: AccessPolicy,
                 waiting: Sequence[WaitingServer] = ()) -> None:
        self.servers = list(servers)
        self.waiting = list(waiting)
        self.policy = policy
        self.pvdb: dict[str, Any] = {}
        self._context: FlushingContext | None = None
        for server in self.servers:
            self._add(server.pvdb, server.report_error)
        for pending in self.waiting:  # read-only controller PVs: nothing to report
            self._add(pending.pvdb, _ignore)

    def _add(self, pvdb: Mapping[str, Any],
             on_error: Callable[[BaseException], Awaitable[None]]) -> None:
        """Serve ``pvdb`` too, each PV guarded by the access policy."""
        overlap = set(self.pvdb) & set(pvdb)
        if overlap:
            raise ValueError(f"PV names used twice: {sorted(overlap)[:3]}")
        for pv in pvdb.values():
            _guard(pv, self.policy, on_error)
            for name, field in getattr(pv, "fields", {}).items():  # "P:X.VELO"
                _guard(field, self.policy, on_error, writable=name in WRITABLE)
        self.pvdb.update(pvdb)

    async def start(self) -> None:
        """Read every controller's settings and publish the first values."""
        for server in self.servers:
            await server.start()
        for waiting in self.waiting:
            await waiting.start()

    async def _serve_when_connected(self, waiting: WaitingServer) -> None:
        server = await waiting.connect()
        server.context = self._context
        self.servers.append(server)
        self._add({name: pv for name, pv in server.pvdb.items()
                   if name not in self.pvdb}, server.report_error)
        log.info("%s: controller connected; serving its axes", waiting.prefix)
        await server.run()

    async def run(self, interfaces: Sequence[str] = ("127.0.0.1",)) -> None:
        """Serve on ``interfaces`` until cancelled; stops the moves this IOC started."""
        context = self._context = FlushingContext(self.pvdb, list(interfaces))
        for server in self.servers:
            server.context = context
        tasks = [asyncio.ensure_future(server.run()) for server in self.servers]
        tasks += [asyncio.ensure_future(self._serve_when_connected(waiting))
                  for waiting in self.waiting]
        tasks.append(asyncio.ensure_future(context.run()))
        try:
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
            for task in done:
                task.result()  # a poller or the server died: report why
            raise RuntimeError("the Channel Access server stopped")
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            for server in self.servers:
                await server.aclose()
            for waiting in self.waiting:
                if waiting.server is not None:
                    await waiting.server.controller.aclose()


async def _ignore(exc: BaseException) -> None:
    """No controller to report a failed put to yet."""


def _unidentified(controller: Controller) -> bool:
    """Whether ``controller`` was connected without reading its identity."""
    try:
        _ = controller.identity
    except RuntimeError:
        return True
    return False


async def build_ioc(controllers: Mapping[str, Controller], prefix: str, *,
                    policy: AccessPolicy | None = None, poll: float = 0.1,
                    window: float = 0.02, merge: str = "turn",
                    autosave: str | os.PathLike[str] | None = None,
                    waiting: Mapping[str, Callable[[], Awaitable[Controller]]] | None = None,
                    retry: float = 2.0) -> TangoIoc:
    """Build (and :meth:`~TangoIoc.start`) an IOC for ``controllers``."""
    saved = Autosave(autosave) if autosave is not None else None
    if saved is not None:
        saved.load()
    for controller in controllers.values():
        if controller.connected and controller.context.axes and _unidentified(controller):
            await controller.identify()  # connected with identify=False: axes unknown
    servers = [ControllerServer(controller, f"{prefix}{name}:" if name else prefix,
                                poll=poll, window=window, merge=merge, autosave=saved)
               for name, controller in controllers.items()]
    pending = [WaitingServer(opener, f"{prefix}{name}:" if name else prefix, poll=poll,
                             window=window, merge=merge, autosave=saved, retry=retry)
               for name, opener in (waiting or {}).items()]
    ioc = TangoIoc(servers, policy or AccessPolicy(), pending)
    await ioc.start()
    return ioc
