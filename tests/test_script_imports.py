"""Every `from jaxsocial... import ...` in the benchmarks, notebooks, CI script and docs names a module and
names that exist today, so a module moved by a refactor leaves no script behind it (the GPU block's
`prepare` once imported a module from where it had been). The fallbacks for older trees, the lines right
after an `except ImportError:`, are the exception."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
IMPORT = re.compile(r"from (jaxsocial[\w.]*) import ([\w, ]+)")
FILES = sorted(
    p.relative_to(REPO)
    for pattern in ("benchmarks/**/*.py", "benchmarks/**/*.sh", "notebooks/*.ipynb", "docs/*.md", ".ci/*")
    for p in REPO.glob(pattern)
) + [Path("README.md")]


def imports(text: str) -> list[tuple[str, list[str]]]:
    """Each (module, names) a text imports from jaxsocial (not after an `except ImportError` line)."""
    lines = text.splitlines()
    found = []
    for i, line in enumerate(lines):
        for match in IMPORT.finditer(line):
            if i and "except ImportError" in lines[i - 1]:
                continue
            found.append((match.group(1), [n.strip() for n in match.group(2).split(",") if n.strip()]))
    return found


def missing(module_name: str, names: list[str]) -> list[str]:
    """The names that neither module `module_name` holds nor are submodules of it."""
    module = importlib.import_module(module_name)
    absent = []
    for name in names:
        if hasattr(module, name):
            continue
        try:
            importlib.import_module(f"{module_name}.{name}")
        except ModuleNotFoundError:
            absent.append(name)
    return absent


@pytest.mark.parametrize("path", FILES, ids=str)
def test_every_import_of_a_script_or_document_resolves(path):
    for module_name, names in imports((REPO / path).read_text()):
        assert not missing(module_name, names), f"{path}: from {module_name} import {names}"


def test_a_moved_module_is_caught_and_an_old_tree_s_fallback_is_not():
    text = "from jaxsocial.experiments import prereg\ntry:\n    x\nexcept ImportError:\n"
    text += "    from jaxsocial import loop\n"
    assert imports(text) == [("jaxsocial.experiments", ["prereg"])]
    assert missing("jaxsocial.experiments", ["prereg"]) == ["prereg"]
    assert missing("jaxsocial.experiments.plan", ["prereg", "catalogue"]) == []
