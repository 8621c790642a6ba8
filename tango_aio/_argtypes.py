"""argparse types of the command line's options and URLs, shared by every command
(``cli``, ``probe``, ``epics.command``): each checks a value before anything is opened,
so a bad one is a usage error (exit code 2) that names the option."""

from __future__ import annotations

import argparse
import math
import os
import urllib.parse
from collections.abc import Callable
from typing import TypeVar

from .catalog import AXES
from .controller import check_url

_T = TypeVar("_T")


class UsageError(ValueError):
    """A command line that cannot work as given: exit code 2, like argparse's errors."""


def number_type(kind: Callable[[str], _T], what: str, *, minimum: float = 0.0,
                 allow_minimum: bool = False) -> Callable[[str], _T]:
    """argparse type of a finite number above ``minimum`` (or equal, if allowed)."""
    def convert(text: str) -> _T:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {what}: {text!r}") from None
        number = float(value)  # type: ignore[arg-type]
        if not math.isfinite(number) or number < minimum or (
                number == minimum and not allow_minimum):
            bound = f"{'at least' if allow_minimum else 'above'} {minimum:g}"
            raise argparse.ArgumentTypeError(f"must be {bound}: {text!r}")
        return value
    return convert


count_type = number_type(int, "a whole number", minimum=1, allow_minimum=True)
baud_type = number_type(int, "a whole number of baud", allow_minimum=True)
seconds_type = number_type(float, "a number of seconds")
delay_type = number_type(float, "a number of seconds", allow_minimum=True)


def existing_path(text: str) -> str:
    """argparse type of a file to read: it must exist (checked before anything opens)."""
    if not os.path.exists(text):
        raise argparse.ArgumentTypeError(f"no such file: {text!r} (check the path)")
    return text


def axes_type(text: str) -> int:
    """argparse type of an axis count, 1-4 (the controller's axes X, Y, Z, A)."""
    count = count_type(text)
    if count > len(AXES):
        raise argparse.ArgumentTypeError(f"must be 1-{len(AXES)}: {text!r}")
    return count


def writable_path(text: str) -> str:
    """argparse type of a file to write: its folder exists (checked before a long run)."""
    folder = os.path.dirname(os.path.abspath(text))
    if not os.path.isdir(folder):
        raise argparse.ArgumentTypeError(f"no folder {folder!r} to write {text!r} in "
                                         f"(create it first, or name another file)")
    if os.path.isdir(text):
        raise argparse.ArgumentTypeError(f"{text!r} is a folder: name a file")
    return text


def url_type(text: str) -> str:
    """argparse type of a controller URL: ``SIM://`` and ``SOCKET://`` in any case; a
    ``sim://`` URL is checked here, so that a bad option is named and nothing opens."""
    scheme, sep, rest = text.partition("://")
    if sep and scheme.lower() in ("sim", "socket"):
        text = f"{scheme.lower()}://{rest}"
    try:
        check_url(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if text.startswith("sim://"):
        try:
            check_sim_url(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def check_sim_url(url: str) -> None:
    """Raise ValueError, naming the option, if the ``sim://`` URL's query is invalid:
    an option given twice, an unknown option or a value the emulator refuses."""
    from .sim.inprocess import configs_from_url

    pairs = urllib.parse.parse_qsl(urllib.parse.urlsplit(url).query, keep_blank_values=True)
    keys = [key for key, _ in pairs]
    twice = sorted({key for key in keys if keys.count(key) > 1})
    if twice:
        raise ValueError(f"sim:// option(s) given more than once: {', '.join(twice)}")
    for key, value in pairs:
        try:
            number = float(value)
        except ValueError:
            continue  # a word (profile=legacy): the emulator checks it below
        if not math.isfinite(number):
            raise ValueError(f"sim:// option {key}={value!r} is not a finite number")
    try:
        configs_from_url(url)
    except ValueError:
        for key, value in pairs:  # find the option the emulator refuses
            try:
                configs_from_url("sim://?" + urllib.parse.urlencode({key: value}))
            except ValueError as exc:
                raise ValueError(f"sim:// option {key}={value!r} is not valid: "
                                 f"{_in_words(exc)}") from None
        raise


def _in_words(exc: ValueError) -> str:
    """Python's conversion errors in the user's words; any other message as it is."""
    text = str(exc)
    if text.startswith("invalid literal for int()"):
        return "expected a whole number"
    if text.startswith("could not convert string to float"):
        return "expected a number"
    return text
