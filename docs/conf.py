"""Sphinx configuration of the tango_aio documentation.

Build (warnings are errors): ``python -m sphinx -W --keep-going -b html docs docs/_build/html``
after ``pip install -e '.[docs]'``.
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))

import tango_aio  # noqa: E402

project = "tango_aio"
author = "tango_aio developers"
copyright = "tango_aio developers"
release = tango_aio.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "tango_docs",  # docs/_ext: tables generated from the code (errors, CLI help)
    "tango_pictures",  # docs/_ext: pictures drawn from a run of the emulator
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# API reference: one page per module, generated at build time (reference/api/, ignored by
# git). Optional extras (bluesky, caproto, ophyd_async, sardana) need not be installed: their
# imports are mocked, so autodoc never fails for a missing extra.
autosummary_generate = True
autosummary_imported_members = False
autodoc_mock_imports = ["bluesky", "ophyd", "ophyd_async", "caproto", "numpy", "IPython",
                        "sardana"]
# "ignore-module-all": a module's page documents what the module defines, not what it
# re-exports (tango_aio.sim re-exports tango_aio.sim.model's classes, tango_aio.instructions
# tango_aio.schema's): an object documented twice gets its source page's back-link
# pointed at the wrong page (broken anchors, tools/check_links.py).
autodoc_default_options = {"members": True, "show-inheritance": True,
                           "ignore-module-all": True}
autodoc_member_order = "bysource"
# Docstrings use numpydoc sections only (Parameters, Returns, Raises, Yields; ruff's
# pydocstyle "numpy" convention and tests/unit/test_docstrings.py keep them so).
napoleon_numpy_docstring = True
napoleon_google_docstring = False
autodoc_typehints = "description"
# False: tango_aio.sync.connect takes its signature from tango_aio.connect (__signature__),
# which the source-based default preservation cannot follow.
autodoc_preserve_defaults = False
# "ref.python": a short name such as ``Controller`` or ``Wire`` names two documented
# objects (tango_aio.Controller and tango_aio.sync.Controller; tango_aio.sim.Wire, which
# re-exports tango_aio.sim.wire.Wire); Sphinx links the first, which is right for both.
suppress_warnings = ["myst.xref_missing", "ref.python"]



def _public_modules() -> list[str]:
    """Every public module of the package, found in its files (nothing is imported, so
    a module that needs a missing extra is still listed; autodoc mocks the extra)."""
    package = HERE.parent / "tango_aio"
    names = []
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(package.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if len(parts) > 1 and not any(part.startswith("_") for part in parts):
            names.append(".".join(parts))
    return names


#: The modules a program uses (imports, or gets objects of); every other module is one of
#: the driver's inner layers and is listed apart, under "Internals".
PUBLIC_API = [
    "tango_aio.connection", "tango_aio.controller", "tango_aio.sync", "tango_aio.errors",
    "tango_aio.events", "tango_aio.status", "tango_aio.units", "tango_aio.group",
    "tango_aio.discovery", "tango_aio.bulk", "tango_aio.reconnect", "tango_aio.instructions",
    "tango_aio.testing", "tango_aio.bluesky", "tango_aio.epics", "tango_aio.sardana",
    "tango_aio.sim",
    "tango_aio.sim.inprocess", "tango_aio.sim.serve", "tango_aio.sim.model",
    "tango_aio.sim.profiles", "tango_aio.sim.wire",
]


def _autosummary(names: list[str]) -> list[str]:
    return [".. autosummary::", "   :toctree: api", "", *(f"   {name}" for name in names), ""]


def _write_module_index() -> None:
    """reference/modules.rst: an autosummary of every module (generated, ignored by git),
    the public API first and the internals apart, so that a module added to the package
    is documented without editing here (as an internal one until listed in PUBLIC_API)."""
    modules = _public_modules()
    public = [name for name in PUBLIC_API if name in modules]
    internal = [name for name in modules if name not in PUBLIC_API]
    lines = ["Modules", "=======", "", "Public API", "----------", "",
             "What programs use: connecting, moving, settings, lists, events, errors, "
             "units, the emulator and the integrations.", "", *_autosummary(public),
             "Internals", "---------", "",
             "The driver's inner layers (the sans-IO core, the scheduler, the reply rules, "
             "the transports, the emulator's parts), for contributors; see "
             "ARCHITECTURE.md in the repository. They may change without notice.", "",
             *_autosummary(internal)]
    text = "\n".join(lines) + "\n"
    target = HERE / "reference" / "modules.rst"
    if not target.exists() or target.read_text() != text:
        target.write_text(text)
    names = set(_public_modules())
    for stale in (HERE / "reference" / "api").glob("*.rst"):  # of a module now gone
        if stale.stem not in names:
            stale.unlink()


_write_module_index()

# furo: made for API references (an "On this page" contents beside every long page, code
# blocks that scroll instead of being clipped, a light and a dark scheme).
html_theme = "furo"
html_title = f"tango_aio {release}"
html_static_path: list[str] = []
