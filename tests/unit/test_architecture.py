"""ARCHITECTURE.md names every module of the package (issue 18: "matches the tree")."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "ARCHITECTURE.md"


def named_in_page() -> set[str]:
    """Every ``name.py`` and ``package/`` the page mentions."""
    text = PAGE.read_text(encoding="utf-8")
    return set(re.findall(r"\b([A-Za-z_][A-Za-z0-9_]*\.py)\b", text)) | {
        f"{name}/" for name in re.findall(r"\b([a-z_]+)/(?=[\s`,)])", text)}


def test_every_module_of_the_package_is_in_the_page() -> None:
    names = named_in_page()
    package = ROOT / "tango_aio"
    modules = {path.name for path in package.glob("*.py")}
    packages = {f"{path.parent.name}/" for path in package.glob("*/__init__.py")}
    assert modules, "no modules found: wrong root"
    missing = sorted((modules | packages) - names)
    assert not missing, f"ARCHITECTURE.md does not name {missing}"


def test_every_emulator_module_is_in_the_page() -> None:
    names = named_in_page()
    sim = {path.name for path in (ROOT / "tango_aio" / "sim").glob("*.py")
           if path.name != "__init__.py"}
    missing = sorted(sim - names)
    assert not missing, f"ARCHITECTURE.md does not name sim/{missing}"


def test_the_page_is_one_page() -> None:
    # A short read: the diagram, the module table, the rules, a reply and a move walked.
    assert len(PAGE.read_text(encoding="utf-8").splitlines()) < 145
