"""Coming into step with a controller: ``setup`` (the autostatus mode, the local-echo
check, the identity and the settings read), reading the settings again and waiting
for a restart; a base of :class:`~tango_aio.controller._controller.Controller`."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from ..catalog import (
    Context,
    DetInfo,
    Form,
    VersionInfo,
    build,
    parse_reply,
)
from ..errors import (
    ConnectError,
    ControllerError,
    ControllerTimeoutError,
    ProtocolError,
    TangoError,
)
from ..families import (
    RESTART_QUIET,
)
from ..link import (
    Reconnector,
)
from ..sansio import (
    CACHED_SETTINGS,
    LOCAL_ECHO,
)
from ._exchanges import _Exchanges
from ._reads import Identity, _read_command
from ._restart import (
    settings_of,
)

log = logging.getLogger("tango_aio")

#: Autostatus modes in which a read's own text coming back need not show local echo:
#: mode 4 may echo reads (old L723), mode 2 may acknowledge them before their data
#: (L2099-2103). Setup checks the link in mode 1 first (:meth:`Controller.setup`).
_ECHO_BLIND = frozenset({2, 4})


class _Setup(_Exchanges):
    """Setting a controller up and reading its identity and settings."""

    _reconnector: Reconnector[Any] | None

    async def setup(self, *, autostatus: int | None = 1, identify: bool = True) -> None:
        """Bring the controller into a known state (called by :func:`connect`)."""
        self._forget_power_state()
        try:
            try:
                await self._come_into_step(autostatus, identify)
            except ProtocolError:
                if self._protocol.core.local_echo:
                    raise
                # A controller still answering an earlier program's lines, one of which
                # came late (a quiet gap longer than the resync's): in step again, once.
                log.debug("connect: a reply out of step; resynchronising once more")
                await self._come_into_step(autostatus, identify)
        except TangoError as exc:
            if self._protocol.core.local_echo:
                raise ConnectError(LOCAL_ECHO) from exc
            raise
        if self._reconnector is not None:
            self._reconnector.arm()

    async def _come_into_step(self, autostatus: int | None, identify: bool) -> None:
        """Resync, read the mode in force, select ``autostatus``, identify, read settings."""
        await self._protocol.resync(timeout=self.reply_timeout)
        current = await self._protocol.read_autostatus(timeout=self.reply_timeout,
                                                       status=True)
        # A unit whose ?statusaxis ends like a completion report (@@@-.) is read
        # axis by axis ('sa x' answers its letter alone, L2725).
        self._letters_by_axis = \
            self._protocol.detected.get("status_tail") == "dot"
        wanted = current if autostatus is None else autostatus
        if wanted in _ECHO_BLIND:
            current = await self._check_local_echo(current)
        if wanted != current:
            await self.command(f"!autostatus {wanted}")
        if identify:
            self._identity = await self.identify()
        await self.refresh_settings()

    async def _check_local_echo(self, current: int) -> int:
        """Before autostatus 2 or 4 is kept or selected (:data:`_ECHO_BLIND`): one read in
        a mode that answers a read with its data alone, so that a link echoing every byte
        sent (local echo of an adapter) shows as the read answered by itself
        (:data:`~tango_aio.sansio._core.LOCAL_ECHO`; setup refuses it).

        Modes 2 and 4 cannot tell. Mode 4 echoes set and move lines (L2117, L2165-2168)
        and, by the older edition, all input (old L723), so an adapter's copy of a read
        looks like the controller's echo, while the controller's own echo of a read may be
        missing or come after its reply (switches ``echo_all``, ``echo``, ``echo_text``).
        Mode 2 may acknowledge reads before their data (switch ``ack_reads``; L2099-2103
        names ``!`` lines only), and a line where an acknowledgement is owed is passed over.
        Modes 0, 1 and 3 neither echo nor acknowledge a read (L2060-2113), so a unit in
        mode 2 or 4 is taken to mode 1 (the power-on mode, L2062) for the read; the caller
        selects its mode again."""
        if current in _ECHO_BLIND:
            await self.command("!autostatus 1")
            current = 1
        await self.query("?err")
        return current

    async def identify(self) -> Identity:
        """Read ``?version`` and ``?det`` (model, firmware, number of axes) and record
        which firmware family and behaviours were detected (:class:`Identity`)."""
        command = build("version", form=Form.READ)
        raw = await self._request(command)
        version = parse_reply(command, raw.lines)
        det = await self.get("det")
        assert isinstance(version, VersionInfo) and isinstance(det, DetInfo)
        axes = det.axes or 4
        context = self._protocol.context
        self._protocol.context = Context(context.dims, axes, context.extmode)
        detected = dict(getattr(self._protocol, "detected", None) or {})
        # Whether per-axis reads answer one value per axis found by ?det (the 1.71
        # manual, L2711-2721) or leave absent/disabled axes out: then every per-axis read
        # whose count differs is read again axis by axis (see get()).
        positions = await self._request(_read_command("pos", None, self.context))
        count = len(" ".join(positions.lines).split())
        # The 1.71 manual prints a blank before the comma of the build time (L1067,
        # L1105), the older edition none (old L426).
        detected["version_format"] = "new" if " , " in " ".join(raw.lines) else "old"
        detected["per_axis_replies"] = "exact" if count == axes else f"{count} of {axes}"
        # help_number "none": help takes no number, as in the older edition (old L805-819).
        older = detected.get("help_number") == "none" \
            or detected["version_format"] == "old"
        return Identity(version.model, version.firmware, axes, version, det,
                        family="older" if older else "1.71", detected=detected)

    async def refresh_settings(self) -> None:
        """Re-read what move timeouts depend on: dim, pitch, vel, accel, secvel, extmode,
        delay and pause (L6845-6899) and the closed-loop timeout ctrt (L11616-11631)."""
        settings = self._settings
        older = self._identity is not None and self._identity.family == "older"
        for entry in CACHED_SETTINGS:  # the catalog's cached settings, in manual order
            if entry.per_axis:
                settings.load(entry, await self.get(entry.name))
                continue
            # A global setting the firmware does not know counts as 0: a read it does not
            # know is answered by error 4 (the older edition lacks e.g. extmode, which then
            # is 0, its behaviour; delay, pause and ctrt: nothing to wait for).
            try:
                known = not older or entry.in_older_manual
                value = await self._read_or_absent(entry.name) if known else 0
                settings.load(entry, value)
            except (ControllerError, ProtocolError, ValueError, TypeError):
                settings.load(entry, 0)
        self._update_context()

    async def _read_or_absent(self, name: str) -> Any:
        """Read the global setting ``name``, which a unit may lack (an optional module,
        a smaller model: no reply at all, error 4, L970): a separator goes right behind
        the read in the same write, so a missing reply shows at once, as the separator's
        reply in its place (:class:`ProtocolError`), and not after the reply timeout."""
        command = _read_command(name, None, self.context)
        (submission,) = self._protocol.submit_together((command,), separate_after=True)
        response = await self._protocol.wait_reply(submission, self.reply_timeout)
        return parse_reply(command, response.lines)

    async def _reload_settings(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """Read the cached settings again (after a restart); their values before and
        after (:func:`~tango_aio.controller._restart.settings_of`)."""
        before = settings_of(self._settings)
        self._forget_power_state()
        await self.refresh_settings()
        return before, settings_of(self._settings)

    async def wait_restarted(self, *, quiet: float = RESTART_QUIET) -> None:
        """After a line that restarts the controller (``reset``, ``restore -1``): wait
        ``quiet`` seconds while it reboots ("more than 1 second, where the controller is
        not responding", manual L1837-1838), poll until it answers (L1845-1860), select
        the driver's autostatus mode again (it restarts in mode 1, L2062) and read the
        cached settings again."""
        await asyncio.sleep(quiet)
        for attempt in range(2):  # the link counts as dead after two unanswered polls
            try:
                await self._protocol.resync(timeout=self.reply_timeout)
                break
            except ControllerTimeoutError:
                if attempt:
                    raise
        await self._protocol.verify_autostatus(timeout=self.reply_timeout)
        await self._reload_settings()
