"""Every function and method of the package reads on one screen: at most `MAX_LINES` lines from its `def`
to its last line, docstring included (argument parsers too: a long parser is a typed config)."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jaxsocial"
MAX_LINES = 60


def function_lengths() -> dict[str, int]:
    """'path:line name' -> the function's length in lines, for every function of the package (nested too)."""
    lengths = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                where = f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {node.name}"
                lengths[where] = node.end_lineno - node.lineno + 1
    return lengths


def test_no_function_is_over_sixty_lines():
    lengths = function_lengths()
    assert len(lengths) > 500  # the walk found the package's functions
    long = {where: n for where, n in lengths.items() if n > MAX_LINES}
    assert not long, f"functions over {MAX_LINES} lines: {long}"
