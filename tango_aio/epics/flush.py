"""A caproto asyncio server that can wait until queued monitor updates are on the wire.

caproto sends a put's response from the put's own task as soon as the put handler
returns, while monitor updates travel through two queues (the server's, then each
circuit's) and a batching loop. A monitor published by the handler just before it
returns can therefore reach the client *after* the put response: a client that reads
RBV right after its ``caput(..., wait=True)`` sees a value from the middle of the move.

:meth:`FlushingContext.flush` puts a marker behind everything published so far. The
server's subscription loop hands the marker on to every circuit's subscription queue, and
each circuit releases it once every update queued ahead of it was written to its socket
(the circuit's loop asks for its next update only after it has sent the batch before).
So a put handler that publishes RBV, DMOV and MOVN and then awaits ``flush()`` returns
only when those updates are out to every subscribed client, and the put response
follows them on the same TCP stream.

A flush with nothing to flush returns at once, without a marker: when the server's queue
is empty and no update is being handed on, and every circuit waits for its next update
with nothing collected and nothing queued (it has sent all it was given). Updates of
fields no client subscribes to are never queued, so a put whose client monitors only VAL
(pyepics' ``caput``) does not wait three loop turns for a marker.

The circuits also send each open channel's access rights again when the client reports
another host or user name (caproto decides them only when a channel is created; writes
are checked with the names of the moment either way).
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
from typing import Any

import caproto as ca
from caproto.asyncio.server import Context, VirtualCircuit

__all__ = ["FlushingContext"]


#: Seconds a circuit that has caught up with its updates waits for more before it sends
#: what it collected (caproto's own wait is its high-load timeout, 10 ms, doubled after
#: every batch sent that way). A put's VAL and DMOV=0 were held for the whole of a short
#: move and then sent on the put's own path, by its flush; now they go out while the move
#: runs. A flush sends at once whatever is held; a flood is still batched.
HOLD = 0.001


class _Marker:
    """A flush request travelling through the subscription queues."""

    def __init__(self) -> None:
        self.pending = 0
        self.done: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def release(self) -> None:
        """One circuit has sent everything queued ahead of this marker."""
        self.pending -= 1
        if self.pending <= 0 and not self.done.done():
            self.done.set_result(None)


class _CircuitMarker:
    """The marker's stand-in in one circuit's queue (caproto's own items there are weak
    references to updates; this one never reaches caproto's loop)."""

    def __init__(self, marker: _Marker) -> None:
        self.marker = marker


class _FlushingCircuit(VirtualCircuit):  # type: ignore[misc]
    """A circuit whose subscription queue passes flush markers, and which decides every
    channel's access rights again when the client reports a new host or user name."""

    async def _process_command(self, command: Any) -> Any:
        response = await super()._process_command(command)
        if isinstance(command, (ca.HostNameRequest, ca.ClientNameRequest)):
            response = [*(response or []), *self._rights()]
        return response

    def _rights(self) -> list[Any]:
        """The access rights of every open channel, for the names reported now."""
        rights = []
        for channel in list(self.circuit.channels.values()):
            try:
                entry = self.context[channel.name]
            except KeyError:
                continue
            access = entry.check_access(self.client_hostname, self.client_username)
            rights.append(ca.AccessRightsResponse(cid=channel.cid, access_rights=access))
        return rights

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._released: list[_Marker] = []
        self._idle = False  # waiting for the next update, with nothing collected
        self._no_delay()

    def flushed(self) -> bool:
        """Whether everything queued to this circuit was sent: its loop waits for the next
        update with nothing collected, and nothing is queued or awaits release."""
        return self._idle and self.subscription_queue.empty() and not self._released

    def _no_delay(self) -> None:
        """Send small writes at once (TCP_NODELAY): a put response written right after a
        monitor update otherwise waits for the client's delayed ACK of the update
        (Nagle), about 40 ms on Linux, for every put a monitored client makes."""
        writer = getattr(self.client, "writer", None)
        sock = writer.get_extra_info("socket") if writer is not None else None
        if sock is not None and sock.family in (socket.AF_INET, socket.AF_INET6):
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    async def get_from_sub_queue(self, timeout: float | None = None) -> Any:
        # caproto's loop calls this only after it has sent the batch it had collected
        # (or with nothing collected): markers taken before are then flushed.
        self._release()
        while True:
            if timeout is None:  # nothing collected: wait for the next update
                self._idle = True
                try:
                    item = await self.subscription_queue.get()
                finally:
                    self._idle = False
            elif not self.subscription_queue.empty():
                item = self.subscription_queue.get_nowait()
            else:  # caught up: wait HOLD for more, then the loop sends what it collected
                # (asyncio.timeout, not caproto's wait_for: that runs the get in a task of
                # its own, three loop turns from a put to this loop instead of one; an
                # item put as the wait times out stays in the queue for the next call)
                try:
                    async with asyncio.timeout(min(timeout, HOLD)):
                        item = await self.subscription_queue.get()
                except TimeoutError:
                    return None
            if not isinstance(item, _CircuitMarker):
                return item
            if timeout is None:  # the loop has nothing collected: all before is sent
                item.marker.release()
                continue
            self._released.append(item.marker)
            # "No more updates for now": the loop sends what it collected, then asks again.
            return None

    def _release(self) -> None:
        markers, self._released = self._released, []
        for marker in markers:
            marker.release()

    async def _on_disconnect(self) -> None:
        await super()._on_disconnect()
        self._release()
        while not self.subscription_queue.empty():
            item = self.subscription_queue.get_nowait()
            if isinstance(item, _CircuitMarker):
                item.marker.release()


class FlushingContext(Context):  # type: ignore[misc]
    """caproto's asyncio server :class:`~caproto.asyncio.server.Context` with
    :meth:`flush`."""

    CircuitClass = _FlushingCircuit

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._handing_on = 0  # updates taken from the queue, not yet in every circuit's

    def _flushed(self) -> bool:
        """Whether every update published so far was written to every client's socket."""
        if self._handing_on or not self.subscription_queue.empty():
            return False
        return all(circuit.flushed() for circuit in self.circuits
                   if isinstance(circuit, _FlushingCircuit) and circuit.connected)

    async def flush(self) -> None:
        """Return once every monitor update published before this call was written to
        the socket of every connected client (at once if nothing is on its way)."""
        if self._flushed():
            return
        marker = _Marker()
        await self.subscription_queue.put((marker, None, None, 0, None))
        await marker.done

    async def _subscription_queue_iteration(self, sub_specs: Any, *args: Any) -> None:
        if not isinstance(sub_specs, _Marker):
            self._handing_on += 1
            try:
                await super()._subscription_queue_iteration(sub_specs, *args)
            finally:
                self._handing_on -= 1
            return
        marker = sub_specs
        circuits = [c for c in self.circuits
                    if isinstance(c, _FlushingCircuit) and c.connected]
        marker.pending = len(circuits)
        if not circuits:
            marker.done.set_result(None)
            return
        for circuit in circuits:
            try:
                circuit.subscription_queue.put_nowait(_CircuitMarker(marker))
            except asyncio.QueueFull:  # caproto drops that circuit's backlog anyway
                marker.release()
