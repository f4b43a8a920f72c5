"""Which commit: `git` in a directory, and the commit checked out here. The plan (a design's commit),
launch (each process's commit) and analysis (a record's commit) all ask it. Both are
`jaxsocial.run.checkout`'s, which training runs use too (with whether the package's files are the commit's:
`checkout.tree`)."""

from __future__ import annotations

from jaxsocial.run.checkout import git, head_commit

__all__ = ["git", "head_commit"]
