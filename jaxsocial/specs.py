"""References to saved state, written as text on command lines and in config.json and held parsed:

* `PolicyRef`: a learner's exported policy, ``RUN_DIR`` (its first learner) or ``RUN_DIR#k`` (its k-th), for
  frozen slots, trained experts (`expert:ckpt=`), `evaluate --ckpt` and `render --ckpt`;
* `CheckpointRef`: a training checkpoint, ``RUN_DIR`` (its latest) or ``RUN_DIR@ITERATION``, for
  `train --init-from`.

'@' names an iteration and '#' a learner. ``RUN_DIR@k`` for a learner is the old spelling: it still reads,
with a DeprecationWarning. Each type has one parser (`parse`) and one formatter (`str`), and
``parse(str(x)) == x``.
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path


@dataclasses.dataclass(frozen=True)
class PolicyRef:
    """The exported policy of learner `learner` (0: the first) of the run directory `run`."""

    run: Path
    learner: int = 0

    @classmethod
    def parse(cls, text: str) -> PolicyRef:
        """``RUN_DIR`` or ``RUN_DIR#k`` (``RUN_DIR@k``: deprecated); text after '#' or '@' that is not a
        whole number is part of the path."""
        for mark in ("#", "@"):
            run, sep, index = str(text).rpartition(mark)
            if sep and index.isdigit():
                if mark == "@":
                    warnings.warn(
                        f"{text}: write the learner as {run}#{index}; '@' names a checkpoint's iteration "
                        "(as in --init-from RUN_DIR@ITERATION)",
                        DeprecationWarning,
                        stacklevel=2,
                    )
                return cls(Path(run), int(index))
        return cls(Path(text))

    @classmethod
    def of(cls, value: PolicyRef | str | Path) -> PolicyRef:
        """`value` itself, or parsed from text or a path."""
        return value if isinstance(value, PolicyRef) else cls.parse(str(value))

    def __str__(self) -> str:
        return str(self.run) if self.learner == 0 else f"{self.run}#{self.learner}"


@dataclasses.dataclass(frozen=True)
class CheckpointRef:
    """The checkpoint of iteration `iteration` (None: the latest) of the run directory `run`."""

    run: Path
    iteration: int | None = None

    @classmethod
    def parse(cls, text: str) -> CheckpointRef:
        """``RUN_DIR`` or ``RUN_DIR@ITERATION``; ValueError if ITERATION is not a whole number."""
        if "@" not in text:
            return cls(Path(text))
        run, _, iteration = text.rpartition("@")
        if not iteration.isdigit():
            raise ValueError(f"{text}: ITERATION after '@' must be a whole number")
        return cls(Path(run), int(iteration))

    def __str__(self) -> str:
        return str(self.run) if self.iteration is None else f"{self.run}@{self.iteration}"
