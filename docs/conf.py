"""Sphinx configuration of the tango_aio documentation.

Build (warnings are errors): ``python -m sphinx -W --keep-going -b html docs docs/_build/html``
after ``pip install -e '.[docs]'``.
"""

from __future__ import annotations

import contextlib
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))

import tango_aio  # noqa: E402

# pymmcore-plus turns the root logger to DEBUG when first imported, and Sphinx's source
# reader imports it for real while documenting tango_aio.mm: import it now through
# tango_aio.mm, which keeps the root logger's level (else every library's debug lines
# fill the build's output).
with contextlib.suppress(ImportError):  # without the mm extra nothing imports it
    import tango_aio.mm  # noqa: F401

project = "tango_aio"
author = "tango_aio developers"
copyright = "tango_aio developers"
release = tango_aio.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "tango_docs",  # docs/_ext: tables generated from the code (errors, CLI help)
    "tango_pictures",  # docs/_ext: pictures drawn from a run of the emulator
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# API reference: one page per public module, generated at build time (reference/api/,
# ignored by git). Optional extras (bluesky, caproto, ophyd_async) need not be installed: their
# imports are mocked, so autodoc never fails for a missing extra.
autodoc_mock_imports = ["bluesky", "ophyd", "ophyd_async", "caproto", "numpy", "IPython",
                        "pymmcore_plus", "useq", "tango", "sardana"]
# "ignore-module-all": a module's page documents what the module defines; what a public
# package exports from its private modules is listed by _module_page below, each object
# once (an object documented twice gets its source page's back-link pointed at the wrong
# page: broken anchors, tools/check_links.py).
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



#: The public API: the modules and packages a program imports. This list is the one home of
#: that fact (tests/unit/test_docstrings.py reads it): each gets a page of the reference
#: that documents the names it exports, and nothing else of the package is documented (the
#: layers' private modules are described in ARCHITECTURE.md, for contributors).
PUBLIC_API = [
    "tango_aio", "tango_aio.sync", "tango_aio.errors", "tango_aio.events", "tango_aio.status",
    "tango_aio.units", "tango_aio.families", "tango_aio.catalog", "tango_aio.fieldkit",
    "tango_aio.testing", "tango_aio.bluesky", "tango_aio.epics", "tango_aio.mm",
    "tango_aio.tango_controls", "tango_aio.sardana", "tango_aio.sim",
    "tango_aio.sim.inprocess", "tango_aio.sim.serve", "tango_aio.sim.model",
    "tango_aio.sim.profiles", "tango_aio.sim.wire",
]


_DOCUMENTED: set[int] = set()


def _documented_by_hand() -> set[int]:
    """The objects a hand-written page documents (an ``auto*`` directive without
    ``:no-index:``, such as the family pages): the generated pages leave them out."""
    import importlib
    import re

    from sphinx.ext.autodoc.mock import mock

    pattern = re.compile(r"^\.\. auto(?:class|function|exception|data):: (\S+)\n"
                         r"((?:   :.*\n)*)", re.MULTILINE)
    found: set[int] = set()
    with mock(autodoc_mock_imports):
        for page in HERE.rglob("*.md"):
            for match in pattern.finditer(page.read_text(encoding="utf-8")):
                if ":no-index:" in match.group(2):
                    continue
                module, _, name = match.group(1).rpartition(".")
                found.add(id(getattr(importlib.import_module(module), name)))
    return found


def _exported(module_name: str) -> list[tuple[str, str]]:
    """(directive, dotted name) for each name ``module_name`` exports but defines in a
    private module: a name defined in another public module is documented there, and one
    that two public modules re-export, in the first of them."""
    import importlib
    import inspect

    from sphinx.ext.autodoc.mock import mock

    with mock(autodoc_mock_imports):
        module = importlib.import_module(module_name)
        found = []
        for name in getattr(module, "__all__", ()):
            value = getattr(module, name)
            home = getattr(value, "__module__", None) or module_name
            if home == module_name or home in PUBLIC_API or not home.startswith("tango_aio") \
                    or id(value) in _DOCUMENTED:
                continue
            _DOCUMENTED.add(id(value))
            kind = ("autoexception" if inspect.isclass(value) and issubclass(value, BaseException)
                    else "autoclass" if inspect.isclass(value)
                    else "autofunction" if callable(value) else "autodata")
            found.append((kind, f"{module_name}.{name}"))
    return found


def _module_page(name: str) -> str:
    lines = [name, "=" * len(name), "", f".. automodule:: {name}", ""]
    for kind, target in _exported(name):
        lines += [f".. {kind}:: {target}"]
        lines += ["   :members:", "   :show-inheritance:"] if kind != "autofunction" \
            and kind != "autodata" else []
        lines += [""]
    return "\n".join(lines)


def _write_if_changed(target: Path, text: str) -> None:
    if not target.exists() or target.read_text() != text:
        target.write_text(text)


def _write_reference() -> None:
    """reference/modules.rst and one page per public module under reference/api/ (both
    generated, ignored by git)."""
    pages = HERE / "reference" / "api"
    pages.mkdir(exist_ok=True)
    _DOCUMENTED.update(_documented_by_hand())
    for name in PUBLIC_API:
        _write_if_changed(pages / f"{name}.rst", _module_page(name))
    for stale in pages.glob("*.rst"):
        if stale.stem not in PUBLIC_API:
            stale.unlink()
    lines = ["Modules", "=======", "",
             "What programs use: connecting, moving, the families of settings, events, "
             "errors, units, the emulator and the integrations. Everything else in the "
             "package is a private layer of the driver (ARCHITECTURE.md in the "
             "repository).", "", ".. toctree::", "   :maxdepth: 1", "",
             *(f"   api/{name}" for name in PUBLIC_API), ""]
    _write_if_changed(HERE / "reference" / "modules.rst", "\n".join(lines))


_write_reference()

# furo: made for API references (an "On this page" contents beside every long page, code
# blocks that scroll instead of being clipped, a light and a dark scheme).
html_theme = "furo"
html_title = f"tango_aio {release}"
html_static_path: list[str] = []
# viewcode shows the source of the public modules that define what they document; the
# objects a package re-exports from its private modules go without a source link (followed
# into private modules, its back-links named anchors that no page has).
viewcode_follow_imported_members = False
