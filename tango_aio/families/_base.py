"""What every family object stands on: the port it reaches the controller through.

A family (settings, joystick, I/O, encoders, closed loop, triggers, snapshots, ...) groups
the instructions of one chapter of the manual behind named, typed methods. It holds no
link of its own: it speaks in intents (read a setting, write a proven setting, send a
line) through a :class:`FamilyPort`, which the controller fills with its own methods, so a
family never imports the controller and the controller stays a thin facade.
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol

from ..catalog import Context, Value


class FamilyPort(Protocol):
    """The intents a family sends to its controller."""

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
