"""What every family object stands on: the port it reaches the controller through."""

from __future__ import annotations

from typing import Any, ClassVar, Protocol

from ..catalog import Context, Value


class Identified(Protocol):
    """What a family needs of the controller's identity."""

    @property
    def model(self) -> str:
        """The model (``TANGO-DT``)."""
        ...

    @property
    def firmware(self) -> str:
        """The firmware version (``1.71``)."""
        ...

    @property
    def axes(self) -> int:
        """The number of axes."""
        ...

    @property
    def family(self) -> str:
        """``"1.71"``, or ``"older"`` for firmware of the manual's older edition."""
        ...


class FamilyPort(Protocol):
    """The intents a family sends to its controller."""

    #: The connection's default unit of length (``None``: the controller's dim unit).
    units: str | None

    @property
    def identity(self) -> Identified:
        """The controller's identity, read at connect."""
        ...

    @property
    def context(self) -> Context:
        """The axes and settings a line is checked against."""
        ...

    async def get(self, name: str, *args: Value, axis: str | None = None,
                  timeout: float | None = None) -> Any:
        """Read instruction ``name`` and return its parsed reply.

        Parameters
        ----------
        name
            The instruction (``"vel"``).
        *args
            Extra read arguments (``get("trigp", 3)``).
        axis
            One axis (``"x"``); ``None``: every axis of a per-axis instruction.
        timeout
            Seconds to wait for the reply; ``None``: the connection's default.

        Returns
        -------
        Any
            The parsed reply: a value, or ``{axis: value}``.
        """
        ...

    async def set(self, name: str, /, *args: Value, axis: str | None = None,
                  check: bool = True, **axes: Any) -> None:
        """Write instruction ``name``, proven by the controller's answer or a read-back.

        Parameters
        ----------
        name
            The instruction (``"vel"``).
        *args
            The values, in the manual's order.
        axis
            One axis for a per-axis instruction.
        check
            Read the controller's error state after the line.
        **axes
            Per-axis values (``x=10, y=5``).
        """
        ...

    async def query(self, line: str, timeout: float | None = None) -> str:
        """Send a read line and return its reply text.

        Parameters
        ----------
        line
            The read line (``"?vel x"``).
        timeout
            Seconds to wait for the reply; ``None``: the connection's default.

        Returns
        -------
        str
            The reply's lines, joined by ``"\\n"``.
        """
        ...

    async def command(self, line: str, *, check: bool = True,
                      timeout: float | None = None) -> None:
        """Send a set or execute line, its error state checked.

        Parameters
        ----------
        line
            The line (``"!vel x 5"``).
        check
            Read the controller's error state after the line.
        timeout
            Seconds to wait for the answer; ``None``: the connection's default.
        """
        ...

    async def refresh_settings(self) -> None:
        """Read the settings the driver caches again."""
        ...

    async def wait_restarted(self, *, quiet: float = ...) -> None:
        """After a line that restarts the controller: wait until it answers again, then
        select the driver's mode and read the cached settings again.

        Parameters
        ----------
        quiet
            Seconds to wait before the first line, while the controller starts.
        """
        ...


class Family:
    """The base of every family object: its port, and nothing else.

    Parameters
    ----------
    port
        The controller, as the intents the family sends it.
    """

    __slots__ = ("_port",)

    #: The manual's instructions this family reaches, and the methods that reach each.
    ROUTES: ClassVar[dict[str, tuple[str, ...]]] = {}

    def __init__(self, port: FamilyPort) -> None:
        self._port = port

    def __repr__(self) -> str:
        return f"<{type(self).__name__}>"
