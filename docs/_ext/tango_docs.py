"""Documentation generated from the code, so that it cannot drift from it.

* ``{tango-error-table}``: the controller's error numbers, their exception classes, their
  categories and the manual's texts, from :mod:`tango_aio.errors`.
* ``{tango-cli-help}``: the ``--help`` text of every ``tango-aio`` command, from the
  argument parser of :mod:`tango_aio.cli`.
"""

from __future__ import annotations

import argparse
import os
from typing import Any

from docutils import nodes
from docutils.parsers.rst import Directive


def _table(header: list[str], rows: list[list[nodes.Node | str]],
           widths: list[int]) -> nodes.table:
    table = nodes.table()
    group = nodes.tgroup(cols=len(header))
    table += group
    for width in widths:
        group += nodes.colspec(colwidth=width)

    def row_of(cells: list[nodes.Node | str]) -> nodes.row:
        row = nodes.row()
        for cell in cells:
            entry = nodes.entry()
            entry += nodes.paragraph("", "", cell if isinstance(cell, nodes.Node)
                                     else nodes.Text(cell))
            row += entry
        return row

    head = nodes.thead()
    head += row_of(list(header))
    group += head
    body = nodes.tbody()
    for cells in rows:
        body += row_of(cells)
    group += body
    return table


class ErrorTable(Directive):
    """Error number, exception class and meaning of every documented controller error."""

    def run(self) -> list[nodes.Node]:
        from tango_aio.errors import CATEGORIES, ERROR_DESCRIPTIONS, error_class

        rows: list[list[nodes.Node | str]] = []
        for number in sorted(ERROR_DESCRIPTIONS):
            cls = error_class(number)
            category = next((c.__name__ for c in CATEGORIES if issubclass(cls, c)), "")
            rows.append([str(number), nodes.literal("", f"tango_aio.errors.{cls.__name__}"),
                         category, cls.text])
        return [_table(["number", "exception class", "category", "text"], rows,
                       [8, 40, 24, 60])]


class CliHelp(Directive):
    """The ``--help`` output of ``tango-aio`` and of each of its commands."""

    def run(self) -> list[nodes.Node]:
        from tango_aio.cli._main import _parser

        previous = os.environ.get("COLUMNS")
        os.environ["COLUMNS"] = "88"  # argparse wraps at the terminal width
        try:
            parser = _parser()
            result: list[nodes.Node] = [nodes.literal_block(text=parser.format_help())]
            for name, sub in _commands(parser).items():
                section = nodes.section(ids=[f"cli-{name}"], names=[f"tango-aio {name}"])
                section += nodes.title(text=f"tango-aio {name}")
                section += nodes.literal_block(text=sub.format_help())
                result.append(section)
        finally:
            if previous is None:
                os.environ.pop("COLUMNS", None)
            else:
                os.environ["COLUMNS"] = previous
        return result


def _commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _drop_sourceless_modules(app: Any) -> list[Any]:
    """viewcode lists, on its "module code" index, modules whose source it could not read
    (``builtins``, of an object defined in C), linking to pages it never writes: forget
    them before its pages are collected (tools/check_links.py finds such links)."""
    modules = getattr(app.env, "_viewcode_modules", None)
    if modules:
        for name in [name for name, entry in modules.items() if not entry]:
            del modules[name]
    return []


def setup(app: Any) -> dict[str, Any]:
    app.add_directive("tango-error-table", ErrorTable)
    app.add_directive("tango-cli-help", CliHelp)
    app.connect("html-collect-pages", _drop_sourceless_modules, priority=400)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
