"""How to add an optional extra to this installation of tango-aio, in the words that work
from where the user stands: the checkout it was installed from (editable), the wheel or
folder it came from, or the package index."""

from __future__ import annotations

import json
import urllib.parse
import urllib.request
from importlib import metadata
from pathlib import Path

#: The distribution's name on an index and in ``pip`` commands.
DISTRIBUTION = "tango-aio"


def install_hint(extra: str) -> str:
    """The ``pip`` command that adds ``extra`` to this installation."""
    origin = _origin()
    if origin is None:
        return f"pip install '{DISTRIBUTION}[{extra}]'"
    path, editable = origin
    return f"pip install {'-e ' if editable else ''}'{path}[{extra}]'"


def _origin() -> tuple[str, bool] | None:
    """Where this installation came from (local path, editable), ``None`` for an index."""
    checkout = Path(__file__).resolve().parent.parent
    try:
        project = (checkout / "pyproject.toml").read_text(encoding="utf-8")
    except OSError:
        project = ""
    if f'name = "{DISTRIBUTION}"' in project:  # imported from a checkout
        return str(checkout), True
    try:
        text = metadata.distribution(DISTRIBUTION).read_text("direct_url.json")
    except metadata.PackageNotFoundError:
        return None
    if not text:
        return None
    try:
        record = json.loads(text)
    except ValueError:
        return None
    url = record.get("url", "") if isinstance(record, dict) else ""
    if not isinstance(url, str) or not url.startswith("file:"):
        return None
    path = urllib.request.url2pathname(urllib.parse.urlsplit(url).path)
    dir_info = record.get("dir_info") or {}
    return path, bool(isinstance(dir_info, dict) and dir_info.get("editable"))
