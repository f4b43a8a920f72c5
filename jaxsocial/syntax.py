"""The two text syntaxes of the command line and config.json, each read by one parser here:

* ``NAME[:ARGS]`` (`split_name`): an environment, a slot, an expert, a stage's WHEN;
* ``key=value,...`` (`parse_assignments`, `format_assignments`): EnvParams overrides, an expert's own
  arguments, per-layer `conv_impl`, each caller giving the values their type (`literal` for Python literals).

Lists are split on a separator by `split_entries`. Nothing here knows what the names and keys mean.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Iterable, Mapping
from typing import Any


def split_entries(text: str, sep: str = ",") -> list[str]:
    """The non-empty entries of `text` split on `sep`, stripped: ' a, ,b ' -> ['a', 'b']."""
    return [entry for entry in (part.strip() for part in text.split(sep)) if entry]


def split_name(text: str) -> tuple[str, str]:
    """``NAME[:ARGS]`` -> (NAME, ARGS), split at the first ':' (ARGS may hold more, as paths and an expert's
    own arguments do; '' when there is no ':'). Whitespace is kept: callers strip where it is not meant."""
    name, _, args = text.partition(":")
    return name, args


def literal(text: str) -> Any:
    """`text` as a Python literal where it reads as one ('1' -> 1, "'x'" -> 'x', 'True' -> True), else
    itself ('x' -> 'x'): the values of EnvParams overrides, the inverse of `repr`."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def parse_assignments(
    text: str, value: Callable[[str], Any] = str, *, bare: bool = False
) -> list[tuple[str | None, Any]]:
    """'a=1, b = x=y' -> [('a', value('1')), ('b', value('x=y'))], in order, repeats kept: entries split on
    ',' (empty ones skipped), each at its first '=', key and value stripped. With `bare` an entry without
    '=' (an empty one too) is a value alone, key None ('xla,conv2=auto' -> [(None, 'xla'), ('conv2',
    'auto')]); without, ValueError naming the entry."""
    pairs = []
    for entry in text.split(",") if bare else split_entries(text):
        key, sep, raw = entry.partition("=")
        if not (sep or bare):
            raise ValueError(f"entry {entry!r} is not field=value")
        pairs.append((key.strip(), value(raw.strip())) if sep else (None, value(entry.strip())))
    return pairs


def format_assignments(
    values: Mapping[str, Any] | Iterable[tuple[str, Any]], value: Callable[[Any], str] = str
) -> str:
    """The inverse of `parse_assignments` (given the inverse of its `value`, as `repr` is `literal`'s): a
    key given twice is written once, with its last value."""
    return ",".join(f"{key}={value(v)}" for key, v in dict(values).items())
