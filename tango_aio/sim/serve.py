"""Serve an emulated controller in real time: over a pty, over TCP, or in-process.

A :class:`WireRunner` drives one sans-IO :class:`~tango_aio.sim.wire.Wire` against the
event loop's clock (``loop.time()``, monotonic, but not ``time.monotonic()`` under
uvloop): it feeds arriving bytes in, writes the wire's output out, and sleeps until the
wire's next deadline or new input. Everything runs on the event loop thread; nothing here
is thread-safe.

* :func:`serve_pty`: a pseudo-terminal whose slave path a host opens with pyserial
  POSIX only, so it lives in :mod:`tango_aio.sim.ptyserve` (also importable as
  ``tango_aio.sim.serve_pty``); this module works on every platform.
* :func:`serve_tcp`: a loopback TCP server, usable as ``socket://127.0.0.1:PORT``.
* :func:`create_sim_connection`: an in-process :class:`asyncio.Transport` for ``sim://``.

A disconnect fault (:meth:`Wire.disconnect`) ends the runner; the serving layer then closes
the pty master, the TCP connection, or reports ``connection_lost`` to the protocol.

Every serving function takes ``speed``: the controller logic then runs on emulator time,
``speed`` times as fast as the host's clock, while the wire keeps its timing
(:mod:`tango_aio.sim.clock`).

A served emulator may run for days, so the servers hold bounded memory whatever a client
does: a host that writes faster than the baud rate carries is no longer read from once
:data:`INPUT_QUEUE_LIMIT` bytes wait for the line (it then waits, as on a real port: a
full TCP window, a blocking pty write), a host that does not read its replies is no longer
read from either, and a closed TCP connection leaves nothing behind.
"""

from __future__ import annotations

import asyncio
import socket
from collections import deque
from collections.abc import Callable
from typing import TypeVar, cast

from tango_aio.sim.clock import host_now, scaled_factory
from tango_aio.sim.wire import Emit, HandlerFactory, LineHandler, Wire, WireConfig

__all__ = [
    "CONNECTION_BACKLOG",
    "INPUT_QUEUE_LIMIT",
    "INPUT_QUEUE_RESUME",
    "OUTPUT_QUEUE_LIMIT",
    "SharedController",
    "SimTransport",
    "TcpServer",
    "WireRunner",
    "create_sim_connection",
    "serve_tcp",
]

_READ_SIZE = 4096

INPUT_QUEUE_LIMIT = 4096
"""Bytes from the host that may wait for the line (the baud rate) before the serving layer
stops reading from the host, like the 4 KiB transmit buffer of a serial driver. Reading
resumes when :data:`INPUT_QUEUE_RESUME` bytes are left. The controller's own 256-byte input
buffer, and the bytes it loses, are the wire's (:mod:`tango_aio.sim.wire`)."""
INPUT_QUEUE_RESUME = 1024
"""Waiting input bytes below which reading from the host resumes."""
OUTPUT_QUEUE_LIMIT = 65536
"""Reply bytes a pty holds for a host that does not read before it stops reading input
(a TCP connection uses its transport's write buffer limits the same way)."""
CONNECTION_BACKLOG = 16
"""Wires of accepted connections a :class:`TcpServer` keeps for :meth:`TcpServer.next_connection`
until they are taken; older ones are forgotten, so untaken ones cannot pile up."""

DRAIN_GRACE = 0.5
"""Seconds a pty waits for the host to read pending output before a disconnect closes it."""
_DRAIN_POLL = 0.001
_DRAIN_QUIET = 20

_P = TypeVar("_P", bound=asyncio.Protocol)


async def _wait_task(task: asyncio.Task[None]) -> None:
    """Wait for ``task`` to end without cancelling it; re-raise its exception, if any."""
    await asyncio.wait([task])
    exc = None if task.cancelled() else task.exception()
    if exc is not None:
        raise exc


class WireRunner:
    """Drives a :class:`Wire` in real time and passes its output to ``write``.

    Must be created on a running event loop. :meth:`run` returns when the wire is cut
    (disconnect fault) and runs forever otherwise; cancel it to stop.

    ``throttle`` (optional) is called with True when more than :data:`INPUT_QUEUE_LIMIT`
    input bytes wait for the line, and with False once they are down to
    :data:`INPUT_QUEUE_RESUME`: the serving layer stops and resumes reading from the host.

    Parameters
    ----------
    wire
        The wire to drive.
    write
        Where the wire's output goes.
    throttle
        Called to stop (True) and resume (False) reading from the host.
    """

    def __init__(self, wire: Wire, write: Callable[[bytes], None],
                 throttle: Callable[[bool], None] | None = None) -> None:
        self.wire = wire
        """The driven wire (fault injection goes here)."""
        self._write = write
        self._throttle = throttle
        self.input_paused = False
        """True while the host is not read from because input waits for the line."""
        self._loop = asyncio.get_running_loop()
        self._wake = asyncio.Event()
        wire.notify = self._wake.set
        wire.clock = self._loop.time

    def feed(self, data: bytes) -> None:
        """Bytes arrived from the host now.

        Parameters
        ----------
        data
            The bytes.
        """
        self.wire.feed(data, self._loop.time())
        self._wake.set()
        if self._throttle is not None and not self.input_paused \
                and self.wire.rx_pending > INPUT_QUEUE_LIMIT:
            self.input_paused = True
            self._throttle(True)

    async def run(self) -> None:
        """Deliver output on time until the wire is cut."""
        while True:
            self._wake.clear()
            for chunk in self.wire.poll_chunks(self._loop.time()):
                self._write(chunk)
            if self.wire.closed:
                return
            # Not next_deadline(): waking for every input byte made a busy link cost a
            # core per few controllers; input that only fills the buffer is taken, at its
            # exact times, on the next wake-up (benchmarks/scaling.py).
            await self._sleep(self._next_wakeup())

    def _next_wakeup(self) -> float | None:
        """The wire's next wake-up, or earlier when paused input will be down to the
        resume level (the bytes reach the controller one byte time apart)."""
        wakeup = self.wire.next_wakeup()
        if not self.input_paused:
            return wakeup
        excess = self.wire.rx_pending - INPUT_QUEUE_RESUME
        if excess <= 0:
            self.input_paused = False
            assert self._throttle is not None
            self._throttle(False)
            return wakeup
        resume = self.wire.now + excess * self.wire.config.byte_time
        return resume if wakeup is None else min(wakeup, resume)

    async def _sleep(self, deadline: float | None) -> None:
        """Sleep until ``deadline`` (None: indefinitely) or until woken by input or a fault."""
        if deadline is None:
            await self._wake.wait()
            return
        if deadline <= self._loop.time():
            await asyncio.sleep(0)
            return
        # A plain timer rather than asyncio.timeout(): this runs hundreds of times per
        # second per served controller, and the timeout machinery showed in profiles.
        timer = self._loop.call_at(deadline, self._wake.set)
        try:
            await self._wake.wait()
        finally:
            timer.cancel()


# ---------------------------------------------------------------------------------- tcp


class SharedController:
    """One controller logic for a server's whole life, attached to one wire at a time.

    A controller behind a serial-to-TCP adapter keeps its position, calibration and
    settings when a client reconnects; so does this one. Each connection still has a wire
    of its own (the link: bytes in flight, the 256-byte input buffer, faults), so what a
    new connection finds is defined by what a cut link loses (:meth:`Wire.disconnect`):

    * Choice: a new connection starts with an empty input buffer. A half-received line of
      the previous connection is dropped with that connection's wire, as are bytes still
      in flight and replies not yet sent. What the interpreter has executed stays done
      (a line is executed when its processing starts). A real adapter may instead keep the
      partial line in the controller's buffer, so a careful host still starts with a bare
      CR, which this emulator answers with nothing.
    * While no connection is attached, the controller runs on (moves finish, timeouts
      expire); whatever it sends meanwhile is lost, as with no host listening. It is
      advanced to the present when the next connection attaches.

    Parameters
    ----------
    factory
        Makes the controller logic.
    """

    def __init__(self, factory: HandlerFactory) -> None:
        self._target: Emit | None = None
        self.handler: LineHandler = factory(self._emit)
        """The controller logic (a model, or a ScaledHandler around one)."""

    def attach(self, emit: Emit, now: float) -> LineHandler:
        """Catch up to ``now`` with output going nowhere, then send output to ``emit``.

        Returns the handler for the new wire (use as ``Wire(lambda e: shared.attach(e,
        now))``).

        Parameters
        ----------
        emit
            Where the new wire takes output.
        now
            The time of the attach.

        Returns
        -------
        LineHandler
            The handler for the new wire.
        """
        self._target = None
        self.handler.poll(now)
        self._target = emit
        return self.handler

    def detach(self, emit: Emit) -> None:
        """The wire whose :meth:`Wire.emit` is ``emit`` is gone; later output is lost.

        Parameters
        ----------
        emit
            The gone wire's ``emit``.
        """
        if self._target == emit:
            self._target = None

    def _emit(self, data: bytes) -> None:
        if self._target is not None:
            self._target(data)


class _TcpSession(asyncio.BufferedProtocol):
    """One TCP connection: its own wire, and the shared or its own controller logic."""

    def __init__(self, server: TcpServer) -> None:
        self._server = server
        self._buffer = memoryview(bytearray(_READ_SIZE))
        self._transport: asyncio.Transport | None = None
        self._runner: WireRunner | None = None
        self._writing = True
        self.task: asyncio.Task[None] | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # A read-write transport; not an isinstance check: uvloop's TCPTransport does not
        # derive from asyncio.Transport.
        self._transport = cast(asyncio.Transport, transport)
        sock = transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        loop = asyncio.get_running_loop()
        try:
            wire = self._server._new_wire(self)
        except Exception as exc:  # e.g. a factory that cannot build a controller
            loop.call_exception_handler({
                "message": "emulator: cannot serve a new connection", "exception": exc,
                "transport": transport, "protocol": self})
            self._transport.abort()  # the client sees the connection end at once, not a hang
            return
        self._runner = WireRunner(wire, self._write, throttle=self._throttle)
        self.task = loop.create_task(self._serve())
        self._server._opened(self, wire)

    def get_buffer(self, sizehint: int) -> memoryview:
        """Where the transport puts the next bytes read (at most :data:`_READ_SIZE`)."""
        return self._buffer

    def buffer_updated(self, nbytes: int) -> None:
        """``nbytes`` arrived in the buffer."""
        if self._runner is not None:
            self._runner.feed(bytes(self._buffer[:nbytes]))

    def connection_lost(self, exc: Exception | None) -> None:
        self.close()
        self._server._closed(self)

    def pause_writing(self) -> None:
        """The client does not read its replies: stop reading its input meanwhile."""
        self._writing = False
        self._update_reading()

    def resume_writing(self) -> None:
        """The client reads again."""
        self._writing = True
        self._update_reading()

    def close(self) -> None:
        """Stop the controller and close the connection."""
        if self.task is not None:
            self.task.cancel()
        if self._transport is not None:
            self._transport.close()

    def _write(self, chunk: bytes) -> None:
        assert self._transport is not None
        if not self._transport.is_closing():  # the client has gone: nothing to send to
            self._transport.write(chunk)

    def _throttle(self, paused: bool) -> None:
        self._update_reading()

    def _update_reading(self) -> None:
        """Read only while input waiting for the line and unread output are bounded; the
        client's writes then wait for the TCP window, as with a serial-to-TCP adapter."""
        transport = self._transport
        if transport is None or transport.is_closing():
            return
        paused = self._runner is not None and self._runner.input_paused
        if self._writing and not paused:
            transport.resume_reading()
        else:
            transport.pause_reading()

    async def _serve(self) -> None:
        assert self._runner is not None and self._transport is not None
        await self._runner.run()
        # run() only returns when the wire was cut: close() still flushes what was written,
        # so a mid-reply disconnect delivers the partial reply before the FIN.
        self._transport.close()


class TcpServer:
    """A loopback TCP server of an emulated controller. Use :func:`serve_tcp`.

    With ``shared`` (the default) one controller, built from the factory when the server
    starts, serves every connection for the server's whole life (see
    :class:`SharedController`). Choice: one connection at a time, and a new connection
    takes over: the previous one is closed. A host that vanished without closing its end
    (a crash, a pulled cable) cannot lock the controller away from its next attempt.

    With ``shared=False`` every connection gets a fresh power-on controller, and several
    connections may be open at once.

    Parameters
    ----------
    factory
        Makes the controller logic.
    config
        The wire configuration; ``None`` for the default.
    speed
        How many times as fast as the host's clock the controller runs.
    shared
        One controller for every connection, or a fresh one per connection.
    """

    def __init__(self, factory: HandlerFactory, config: WireConfig | None = None, *,
                 speed: float = 1.0, shared: bool = True) -> None:
        self.factory = scaled_factory(factory, speed)
        """Builds the controller logic (on emulator time when ``speed`` is not 1)."""
        self.config = config
        """Wire configuration shared by all connections (not mutated by wires)."""
        self.shared: SharedController | None = None
        """The controller all connections share (set by :meth:`start`); None per connection."""
        self._share = shared
        self.host = ""
        """Bound address."""
        self.port = 0
        """Bound port."""
        self._server: asyncio.Server | None = None
        self._sessions: dict[_TcpSession, Wire] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        self._new: deque[Wire] = deque(maxlen=CONNECTION_BACKLOG)
        self._arrived = asyncio.Event()

    @property
    def wires(self) -> list[Wire]:
        """Wires of the connections currently open, oldest first."""
        return list(self._sessions.values())

    async def next_connection(self) -> Wire:
        """The wire of the oldest accepted connection not yet taken (of the last
        :data:`CONNECTION_BACKLOG`); waits for the next one if there is none.

        Returns
        -------
        Wire
            The connection's wire.
        """
        while not self._new:
            self._arrived.clear()
            await self._arrived.wait()
        return self._new.popleft()

    async def start(self, host: str, port: int) -> None:
        """Build the shared controller, bind and start accepting (called by :func:`serve_tcp`).

        A factory that cannot build a controller (e.g. a bad state file) raises here.

        Parameters
        ----------
        host
            The address to bind.
        port
            The port; 0 for any free one.
        """
        if self._share and self.shared is None:
            self.shared = SharedController(self.factory)
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: _TcpSession(self), host, port)
        self.host, self.port = self._server.sockets[0].getsockname()[:2]

    def close(self) -> None:
        """Stop accepting and close every open connection."""
        if self._server is not None:
            self._server.close()
        for session in list(self._sessions):
            session.close()

    async def wait_closed(self) -> None:
        """Wait until the listener and all connection tasks have ended."""
        if self._server is not None:
            await self._server.wait_closed()
        if self._tasks:
            await asyncio.wait(list(self._tasks))

    async def __aenter__(self) -> TcpServer:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        self.close()
        await self.wait_closed()

    def _new_wire(self, session: _TcpSession) -> Wire:
        shared = self.shared
        if shared is None:
            return Wire(self.factory, self.config)
        for other in list(self._sessions):  # the new connection takes over
            other.close()
            self._closed(other)
        now = host_now()
        return Wire(lambda emit: shared.attach(emit, now), self.config)

    def _opened(self, session: _TcpSession, wire: Wire) -> None:
        self._sessions[session] = wire
        if session.task is not None:
            self._tasks.add(session.task)
            session.task.add_done_callback(self._tasks.discard)
        self._new.append(wire)
        self._arrived.set()

    def _closed(self, session: _TcpSession) -> None:
        wire = self._sessions.pop(session, None)
        if wire is not None and self.shared is not None:
            self.shared.detach(wire.emit)


async def serve_tcp(
    factory: HandlerFactory,
    host: str = "127.0.0.1",
    port: int = 0,
    config: WireConfig | None = None,
    *,
    speed: float = 1.0,
    shared: bool = True,
) -> TcpServer:
    """Start a TCP server (loopback by default, port 0 = any free one); see ``.port``.

    ``shared``: one controller for the server's life (default) or a fresh one per
    connection (:class:`TcpServer`). ``speed``: the controller runs that many times as
    fast as the host's clock (:mod:`tango_aio.sim.clock`); the wire keeps its timing.

    Parameters
    ----------
    factory
        Makes the controller logic.
    host
        The address to bind.
    port
        The port; 0 for any free one.
    config
        The wire's configuration; ``None`` for the default.
    speed
        How many times as fast as the host's clock the controller runs.
    shared
        One controller for the server's life, or a fresh one per connection.

    Returns
    -------
    TcpServer
        The running server.
    """
    server = TcpServer(factory, config, speed=speed, shared=shared)
    await server.start(host, port)
    return server


# ---------------------------------------------------------------------------- in-process


class SimTransport(asyncio.Transport):
    """An in-process transport between an :class:`asyncio.Protocol` and an emulator.

    ``write()`` feeds the wire; the wire's output reaches ``protocol.data_received`` on
    the loop, one call per chunk (so fragmentation is visible). ``close()`` reports
    ``connection_lost(None)``; a disconnect fault reports
    ``connection_lost(ConnectionResetError)``. Extra info: ``"wire"`` and ``"peername"``.

    Parameters
    ----------
    protocol
        The protocol the output goes to.
    wire
        The emulated link.
    """

    def __init__(self, protocol: asyncio.Protocol, wire: Wire) -> None:
        super().__init__({"wire": wire, "peername": "sim"})
        self._loop = asyncio.get_running_loop()
        self._protocol = protocol
        self.wire = wire
        """The emulated link (fault injection, counters)."""
        self._closing = False
        self._reading = True
        self._paused: list[bytes] = []
        self._runner = WireRunner(wire, self._deliver)
        self._task = self._loop.create_task(self._serve())

    def write(self, data: bytes | bytearray | memoryview) -> None:
        """Send bytes to the controller (ignored once closing, like asyncio's transports).

        Parameters
        ----------
        data
            The bytes.
        """
        if not self._closing:
            self._runner.feed(bytes(data))

    def close(self) -> None:
        """Close the connection; the protocol gets ``connection_lost(None)`` soon."""
        self._lose(None)

    def abort(self) -> None:
        """Same as :meth:`close` (nothing is buffered on the host side)."""
        self._lose(None)

    def is_closing(self) -> bool:
        """True once closed or disconnected.

        Returns
        -------
        bool
            Whether it is closed.
        """
        return self._closing

    def pause_reading(self) -> None:
        """Hold controller output until :meth:`resume_reading`."""
        self._reading = False

    def resume_reading(self) -> None:
        """Deliver held output and resume."""
        self._reading = True
        held, self._paused = self._paused, []
        for chunk in held:
            self._deliver(chunk)

    def is_reading(self) -> bool:
        """False while reading is paused.

        Returns
        -------
        bool
            Whether it reads.
        """
        return self._reading

    def get_write_buffer_size(self) -> int:
        """Always 0: writes go straight into the wire's unbounded queue.

        Returns
        -------
        int
            0.
        """
        return 0

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        """Accepted and ignored (the write buffer is always empty).

        Parameters
        ----------
        high, low
            Ignored.
        """

    def can_write_eof(self) -> bool:
        """False: a serial line has no EOF.

        Returns
        -------
        bool
            False.
        """
        return False

    async def wait_closed(self) -> None:
        """Wait until the emulator task has ended."""
        await _wait_task(self._task)

    async def _serve(self) -> None:
        await self._runner.run()
        self._lose(ConnectionResetError("emulated controller disconnected"))

    def _deliver(self, chunk: bytes) -> None:
        if self._closing:
            return
        if not self._reading:
            self._paused.append(chunk)
            return
        try:
            self._protocol.data_received(chunk)
        except Exception as exc:  # mirror asyncio: report and close the transport
            self._loop.call_exception_handler(
                {"message": "protocol.data_received() failed", "exception": exc,
                 "transport": self, "protocol": self._protocol})
            self.close()

    def _lose(self, exc: Exception | None) -> None:
        if self._closing:
            return
        self._closing = True
        if asyncio.current_task() is not self._task:
            self._task.cancel()
        self._loop.call_soon(self._protocol.connection_lost, exc)


async def create_sim_connection(
    protocol_factory: Callable[[], _P],
    handler_factory: HandlerFactory,
    config: WireConfig | None = None,
    *,
    speed: float = 1.0,
) -> tuple[SimTransport, _P]:
    """Connect a new protocol to a fresh emulated controller, like ``create_connection``.

    ``speed``: the controller runs that many times as fast as the host's clock
    (:mod:`tango_aio.sim.clock`); the wire keeps its timing. Input is not bounded here:
    the bytes come from this process, which holds them anyway.

    Parameters
    ----------
    protocol_factory
        Makes the protocol to connect.
    handler_factory
        Makes the controller logic.
    config
        The wire's configuration; ``None`` for the default.
    speed
        How many times as fast as the host's clock the controller runs.

    Returns
    -------
    tuple[SimTransport, _P]
        The transport and the connected protocol.
    """
    protocol = protocol_factory()
    transport = SimTransport(protocol, Wire(scaled_factory(handler_factory, speed), config))
    protocol.connection_made(transport)
    await asyncio.sleep(0)
    return transport, protocol

