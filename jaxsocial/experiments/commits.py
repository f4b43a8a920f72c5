"""Which commit: `git` in a directory, and the commit checked out here. The plan (a design's commit),
launch (each process's commit) and analysis (a record's commit) all ask it."""

from __future__ import annotations

import subprocess
from pathlib import Path


def git(*args: str, cwd: str | Path = ".") -> subprocess.CompletedProcess:
    """`git args...` in `cwd`, its output captured as text."""
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=30)


def head_commit() -> str | None:
    """The commit checked out in the working directory (None outside a git repository)."""
    out = git("rev-parse", "HEAD")
    return out.stdout.strip() if out.returncode == 0 else None
