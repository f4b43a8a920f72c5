"""$XLA_FLAGS strings as the runs use them: checked word by word before a process starts, and read back from
a run's provenance."""

from __future__ import annotations


def normalised(flags: str, source: str) -> str:
    """`flags` with single spaces; ValueError naming `source` if a word of them is not a `--flag` (XLA would
    ignore it and, silently, every flag after it)."""
    stray = [word for word in flags.split() if not word.startswith("--")]
    if stray:
        raise ValueError(
            f"{source}: {stray[0]!r} is not an XLA flag (--name=value); XLA would ignore the rest"
        )
    return " ".join(flags.split())


def hold(process_flags: str | None, wanted: str) -> bool:
    """Whether a process's $XLA_FLAGS end in `wanted` (later flags override earlier ones, so a flag of
    `wanted` followed by another value of it would not hold)."""
    words, tail = (process_flags or "").split(), wanted.split()
    return words[len(words) - len(tail) :] == tail
