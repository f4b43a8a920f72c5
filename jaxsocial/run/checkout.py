"""Which code a process runs: the commit of the git checkout its `jaxsocial` package was imported from, and
whether the package's files there are that commit's (`tree`). A run's process file (`provenance.RUN_FILE`)
and a record's provenance say both (`Tree.fields`); where the files differ, the diff beside them
(`Tree.diff_file`, its sha256 in the fields) turns a checkout of the commit into them with `git apply`.

Clean or dirty is judged on the package alone, `jaxsocial/`: a tracked file there changed (staged or not) or
deleted, or a file git neither tracks nor ignores there (a module, a design a recipe loads by name), makes the
tree dirty, and the diff holds them all; changes elsewhere in the checkout (docs, notebooks, benchmarks,
results) change nothing a run computes. A package installed outside a checkout of its own has no commit:
`Tree.reason` says why, and nothing is an error.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import subprocess
from pathlib import Path

SCOPE = "jaxsocial"
"""The folder, relative to the checkout's root, whose files decide what a run computes."""
ROOT = Path(__file__).resolve().parents[2]
"""The folder holding the package this process imported: a checkout's root when it runs from one."""
TREE_FIELDS = ("dirty", "tree_diff", "tree_diff_sha256", "no_commit_reason")
"""What a process file and a record's provenance say of the checkout beside its `commit` (`Tree.fields`)."""
DIFF_OPTIONS = ("--binary", "--no-color", "--no-ext-diff", "--no-textconv", "--no-renames")
PREFIXES = ("--src-prefix=a/", "--dst-prefix=b/")
"""`git diff` output that `git apply` takes whatever the user's git config says."""
DIFF_GLOB = "tree-*.diff"
"""The name of a diff beside a process file (`Tree.diff_file`: '*' is the start of its sha256)."""


def git(*args: str, cwd: str | Path = ".") -> subprocess.CompletedProcess:
    """`git args...` in `cwd`, its output captured as text."""
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=30)


def head_commit(cwd: str | Path = ".") -> str | None:
    """The commit checked out in `cwd` (None outside a git repository)."""
    out = git("rev-parse", "HEAD", cwd=cwd)
    return out.stdout.strip() if out.returncode == 0 else None


@dataclasses.dataclass(frozen=True)
class Tree:
    """The package's files against a commit: `dirty` False (they are the commit's), True (`diff` turns the
    commit's into them; `changes`: `git status` lines of what differs) or None (not known: `reason`, and no
    commit unless `git status` alone failed)."""

    commit: str | None
    dirty: bool | None
    diff: bytes = b""
    changes: tuple[str, ...] = ()
    reason: str | None = None

    @property
    def diff_sha256(self) -> str | None:
        return hashlib.sha256(self.diff).hexdigest() if self.dirty else None

    @property
    def diff_file(self) -> str | None:
        """The diff's file name beside a process file or in a record, named by its hash (None if clean)."""
        return DIFF_GLOB.replace("*", self.diff_sha256[:12]) if self.dirty else None

    def fields(self) -> dict[str, str | bool | None]:
        """`commit` and the `TREE_FIELDS`, as process files and provenance hold them."""
        values = (self.dirty, self.diff_file, self.diff_sha256, self.reason)
        return {"commit": self.commit, **dict(zip(TREE_FIELDS, values, strict=True))}

    def write_diff(self, directory: str | Path) -> None:
        """Write the diff as `diff_file` into `directory` (nothing if clean)."""
        if self.dirty:
            (Path(directory) / self.diff_file).write_bytes(self.diff)

    def describe(self, most: int = 5) -> str:
        """E.g. 'jaxsocial/ differs from commit 4c8a185a9e1f (M jaxsocial/experiments/plan/recipes.py)'."""
        if self.dirty is None:
            return f"whether {SCOPE}/ is a commit's is not known ({self.reason})"
        if not self.dirty:
            return f"{SCOPE}/ is commit {self.commit[:12]}'s"
        more = len(self.changes) - most
        shown = ", ".join(self.changes[:most]) + (f" and {more} more" if more > 0 else "")
        return f"{SCOPE}/ differs from commit {self.commit[:12]} ({shown})"


def tree(root: str | Path | None = None) -> Tree:
    """The package's files in the checkout at `root` (default `ROOT`) against its HEAD: clean, or dirty with
    the diff (`git diff HEAD` of the package, then each untracked file as new), or no commit where `root` is
    not a checkout's root (the package installed elsewhere), git is missing, or nothing is committed yet
    (and not known, with the commit, where `git status` fails)."""
    root = Path(root or ROOT).resolve()
    try:
        top = git("rev-parse", "--show-toplevel", cwd=root)
    except (FileNotFoundError, NotADirectoryError) as err:
        return Tree(None, None, reason=f"git cannot run in {root} ({err})")
    if top.returncode != 0 or Path(top.stdout.strip()).resolve() != root:
        return Tree(
            None, None, reason=f"{root / SCOPE} is not in a git checkout of its own (an installed package?)"
        )
    commit = head_commit(root)
    if commit is None:
        return Tree(None, None, reason=f"the checkout {root} has no commit yet")
    status = git(
        "--no-optional-locks", "status", "--porcelain", "-z", "--untracked-files=all", "--", SCOPE, cwd=root
    )
    if status.returncode != 0:
        return Tree(commit, None, reason=f"git status failed in {root}: {status.stderr.strip()}")
    changes = _status_lines(status.stdout)
    if not changes:
        return Tree(commit, False)
    untracked = [line[3:] for line in changes if line.startswith("?? ")]
    return Tree(commit, True, _diff(root, untracked), tuple(changes))


def _status_lines(porcelain: str) -> list[str]:
    """`git status --porcelain -z` output as 'XY path' lines, X left out where blank (a rename's or copy's
    source path dropped)."""
    entries, lines = porcelain.split("\0"), []
    while entries:
        entry = entries.pop(0)
        if entry:
            lines.append(entry.lstrip())  # 'M path' for ' M path': read by people
            if entry[0] in "RC":
                entries.pop(0)
    return lines


def _diff(root: Path, untracked: list[str]) -> bytes:
    """The package's tracked changes against HEAD, then each of its `untracked` files as a new file."""

    def diff(*args: str) -> bytes:
        command = ["git", "diff", *DIFF_OPTIONS, *PREFIXES, *args]
        return subprocess.run(command, cwd=root, capture_output=True, timeout=60).stdout

    return diff("HEAD", "--", SCOPE) + b"".join(
        diff("--no-index", "--", os.devnull, path) for path in untracked
    )
