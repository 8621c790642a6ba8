"""How the emulated controller styles what it sends: echoes, mode-2 acknowledgements and
the numbers of data replies, per the firmware's switches."""

from __future__ import annotations

import re
from decimal import Decimal

from ..catalog import (
    Command,
    Form,
    Shape,
)
from .profiles import Firmware

#: A number that printed as minus zero (``-0.0000``), as its own token.
_NEG_ZERO = re.compile(r"(?<![\w.])-(0(?:\.0+)?)(?![\w.])")
#: A positive decimal number with a fraction, as its own token.
_POSITIVE = re.compile(r"(?<![\w.+-])(\d+\.\d+)(?![\w.])")
_NUMBER_TOKEN = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)")


def _plus(match: re.Match[str]) -> str:
    text = match.group(1)
    return "+" + text if float(text) != 0.0 else text


def _reprint(token: str) -> str:
    """A token as a re-formatting firmware prints it: numbers shortest (``1.50`` -> ``1.5``,
    ``+2.0`` -> ``2``), other words as they are."""
    if not _NUMBER_TOKEN.fullmatch(token):
        return token
    text = format(Decimal(token).normalize(), "f")
    return "0" if text in ("-0", "+0") else text


class ReplyStyle:
    """The text of echoes, acknowledgements and data replies, per :attr:`firmware`."""

    firmware: Firmware

    def _echoes(self, command: Command, mode: int) -> bool:
        """Mode 4 echoes "the instruction that was sent, in case of set or move
        instruction" (L2117): executing lines, ``!`` or bare (``moa 1``); with
        ``echo_all`` every line, reads included (old L723: "echoes all input")."""
        return mode == 4 and (command.executes or self.firmware.echo_all == "yes")

    def _echo_text(self, text: str) -> str:
        """The echo: the exact text, or (``echo_text=normalized``) re-printed."""
        if self.firmware.echo_text == "exact":
            return text
        if self.firmware.echo_text == "nobang":
            return text[1:] if text.startswith("!") else text
        return " ".join(_reprint(token) for token in text.lower().split())

    def _ack(self, command: Command, code: int, before: int, after: int) -> str | None:
        """The mode-2 acknowledgement a line owes, if any.

        Only ``!`` lines are acknowledged (L2099-2103; ``vel 10`` without ``!`` gets
        nothing, L2154), reads with ``ack_reads``. A line that answers ``OK...`` itself
        (``save``) is not acknowledged twice. A line that changes the mode is judged by
        the mode after it (``ack_mode_change=new``) or before it (``old``)."""
        mode = after if self.firmware.ack_mode_change == "new" else before
        if mode != 2:
            return None
        if command.form is Form.SET and not command.is_read:
            if command.instruction.exec_reply is Shape.ACK and self.firmware.save_ack == "once":
                return None  # save_ack=twice: acknowledged after its own OK... as well
        elif not (command.form is Form.READ and self.firmware.ack_reads != "no"):
            return None
        return self._ack_text("OK..." if code == 0 else self._err_text(code))

    def _ack_text(self, text: str) -> str:
        """A mode-2 acknowledgement in the case of switch ``ack_case``."""
        case = self.firmware.ack_case
        if case == "lower":
            return text.lower()
        if case == "title":
            return text.capitalize()
        return text

    def _err_text(self, code: int) -> str:
        """``ERR 5`` (L2152), or bare ``ERR`` with ``err_number=no`` (L2099)."""
        return f"ERR {code}" if self.firmware.err_number == "yes" else "ERR"

    def _restyle(self, reply: str, numeric: bool) -> str:
        """Numbers of a data reply per switch ``numbers``: a value that rounds to zero from
        below prints ``0.0000`` (``plain``) or ``-0.0000`` (``negzero``); ``plus`` puts
        ``+`` before positive values of ``numeric`` replies (not in ``?version`` text)."""
        style = self.firmware.numbers
        if style == "negzero":
            return reply
        if "-0" in reply:
            reply = _NEG_ZERO.sub(r"\1", reply)
        if style == "plus" and numeric:
            reply = _POSITIVE.sub(_plus, reply)
        return reply
