"""A package's names, imported at their first use (PEP 562): `import jaxsocial` then costs nothing until a
name is read, so what needs no JAX (the training command's refusals of bad input) answers at once."""

from __future__ import annotations

import importlib
import importlib.util
import sys
from collections.abc import Callable
from typing import Any


def exports(package: str, sources: dict[str, str]) -> Callable[[str], Any]:
    """The module `__getattr__` of `package`: each name of `sources` is that of the module it maps to, any
    other name the package's submodule of that name (as an eager import of them made it); kept in the
    package once read."""

    def __getattr__(name: str) -> Any:
        if name in sources:
            value = getattr(importlib.import_module(sources[name]), name)
        elif importlib.util.find_spec(f"{package}.{name}") is not None:
            value = importlib.import_module(f"{package}.{name}")
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        setattr(sys.modules[package], name, value)
        return value

    return __getattr__
