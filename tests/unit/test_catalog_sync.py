"""The committed ``tango_aio/catalog/_table.py`` is exactly what ``tools/gen_catalog.py`` makes."""

from __future__ import annotations

import ast
from pathlib import Path
from types import ModuleType

import pytest
from helpers import load_tool

ROOT = Path(__file__).resolve().parents[2]
CATALOG = ROOT / "tango_aio" / "catalog" / "_table.py"
REFERENCE = ROOT / "reference" / "instructions.json"



@pytest.fixture(scope="module")
def generator() -> ModuleType:
    return load_tool("gen_catalog")


@pytest.fixture(scope="module")
def entries(generator: ModuleType) -> list[dict[str, object]]:
    loaded: list[dict[str, object]] = generator.load(REFERENCE)
    return loaded


def test_generator_reads_the_shared_reference(generator: ModuleType) -> None:
    assert generator.DEFAULT_JSON.resolve() == REFERENCE.resolve()


def test_committed_catalog_is_the_generated_one(
    generator: ModuleType, entries: list[dict[str, object]]
) -> None:
    expected = generator.render(entries).encode("utf-8")
    actual = CATALOG.read_bytes()
    assert actual == expected, (
        "tango_aio/catalog/_table.py is out of date or was edited by hand: "
        "run `.venv/bin/python tools/gen_catalog.py`"
    )


def test_render_is_deterministic(generator: ModuleType, entries: list[dict[str, object]]) -> None:
    assert generator.render(entries) == generator.render(entries)


def test_override_tables_name_real_instructions(
    generator: ModuleType, entries: list[dict[str, object]]
) -> None:
    # A misspelt key would be silently ignored by the generator.
    names = {entry["name"] for entry in entries}
    tables = ["READ_ONLY_PARAMS", "READ_LEAD", "BIT_FIELDS", "WRITE_OVERRIDES",
              "READ_OVERRIDES", "REPLY", "EXEC_REPLY", "LINES", "COMPLETION",
              "BARE_EXECUTES", "OPTION_GROUPS", "DIGIT_VALUES", "CACHED", "DEFAULTS",
              "INDEXED", "DIGITS", "POSITION_VALUED"]
    for table in tables:
        unknown = set(getattr(generator, table)) - names
        assert not unknown, f"{table} names unknown instructions {sorted(unknown)}"


def test_reply_table_uses_real_shapes(generator: ModuleType) -> None:
    from tango_aio.catalog._instructions import Shape

    for name, shape in {**generator.REPLY, **generator.EXEC_REPLY}.items():
        assert shape in Shape.__members__, (name, shape)


def test_catalog_is_pure_data() -> None:
    # Only a docstring, imports and one assignment of constructor calls of schema types:
    # no function definitions, lambdas, comprehensions or control flow.
    tree = ast.parse(CATALOG.read_text(encoding="utf-8"))
    import tango_aio.catalog._schema as schema

    kinds = [type(node) for node in tree.body]
    assert kinds[0] is ast.Expr  # the docstring
    assert set(kinds[1:-1]) <= {ast.ImportFrom}
    assert kinds[-1] is ast.AnnAssign
    allowed = {ast.Call, ast.Name, ast.Attribute, ast.Constant, ast.Tuple, ast.Set,
               ast.keyword, ast.Load, ast.UnaryOp, ast.USub, ast.Subscript}
    for node in ast.walk(tree.body[-1]):
        assert type(node) in allowed | {ast.AnnAssign, ast.Store}, ast.dump(node)
        if isinstance(node, ast.Call):
            assert isinstance(node.func, ast.Name), ast.dump(node)
            assert node.func.id == "frozenset" or isinstance(
                getattr(schema, node.func.id, None), type), node.func.id
        if isinstance(node, ast.Attribute):  # Kind.FLOAT, replyrules.mrt_lines
            assert isinstance(node.value, ast.Name), ast.dump(node)
    imported = {node.module for node in tree.body if isinstance(node, ast.ImportFrom)}
    assert imported <= {"__future__", "_schema", None}  # None: the reply rules
