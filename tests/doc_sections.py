"""The sections of a markdown file (README.md, docs/*.md), for the tests that read the docs."""

from __future__ import annotations

import re
from pathlib import Path

HEADING = re.compile(r"#+ (.*)$")


def sections(path: Path) -> list[tuple[str, str]]:
    """(heading, text up to the next heading) of a markdown file; '#' lines inside code fences are not
    headings, and the text before the first heading is left out."""
    out: list[tuple[str, str]] = []
    fenced = False
    for line in path.read_text().splitlines(keepends=True):
        fenced ^= line.startswith("```")
        heading = None if fenced else HEADING.match(line)
        if heading:
            out.append((heading.group(1).strip(), ""))
        elif out:
            out[-1] = (out[-1][0], out[-1][1] + line)
    return out
