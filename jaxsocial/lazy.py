"""Names imported at their first use: a package's (PEP 562, `exports`), so `import jaxsocial` costs nothing
until a name is read, and a module's (`module`), so what needs no JAX or scipy (the commands' refusals of bad
input) answers at once."""

from __future__ import annotations

import importlib
import importlib.util
import sys
from collections.abc import Callable
from types import ModuleType
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


def module(name: str) -> ModuleType:
    """A stand-in for the module `name` that imports it at its first attribute read (and nothing before:
    not even its parent packages), then answers from it."""

    class Deferred(ModuleType):
        def __getattr__(self, attribute: str) -> Any:
            return getattr(importlib.import_module(name), attribute)

    return Deferred(name)
