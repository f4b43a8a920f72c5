"""Values written as text on command lines and in config.json and held parsed:

* ``field=value,...``: EnvParams overrides (`ENV_ARGS`; held as pairs, values Python literals), the syntax
  of `--env-args`, of a stage's overrides (`run.schedule`) and of an `EnvSpec`'s;
* `EnvSpec`: an environment, ``NAME`` or ``NAME:field=value,...`` (evaluation environments, `--env` of
  training and the tools, where ``--env NAME:ARGS`` is ``--env NAME --env-args ARGS``): the text only;
  ``registry.env_params(spec.name, spec.args)`` builds its parameters;
* `PolicyRef`: a learner's exported policy, ``RUN_DIR`` (its first learner) or ``RUN_DIR#k`` (its k-th), for
  frozen slots, trained experts (`expert:ckpt=`), `evaluate --ckpt` and `render --ckpt`;
* `CheckpointRef`: a training checkpoint, ``RUN_DIR`` (its latest) or ``RUN_DIR@ITERATION``, for
  `train --init-from`.

'@' names an iteration and '#' a learner. ``RUN_DIR@k`` for a learner is the old spelling: it still reads,
with a DeprecationWarning. Each type has one parser (`parse`) and one formatter (`str`), and
``parse(str(x)) == x``. `TextField` carries such a parser and formatter to the command line (tyro) and to
config.json (`config.TEXT_FIELDS`).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import tyro

from jaxsocial import syntax


@dataclasses.dataclass(frozen=True)
class EnvSpec:
    """The registered environment `name` with the EnvParams overrides `args` ((field, value) pairs)."""

    name: str
    args: tuple[tuple[str, Any], ...] = ()

    @classmethod
    def parse(cls, text: str) -> EnvSpec:
        """``NAME`` or ``NAME:field=value,...`` (the syntax only: `registry.env_params` checks the name and
        the fields). ValueError on an override without '='."""
        name, args = syntax.split_name(text)
        return cls(name.strip(), ENV_ARGS.parse(args))

    def extended(self, env_args: tuple[tuple[str, Any], ...]) -> EnvSpec:
        """This spec with the overrides `env_args` (`--env-args`) added: ``--env NAME:a=1 --env-args b=2`` is
        ``NAME:a=1,b=2``. ValueError for a field set in both (a silent override would hide one)."""
        both = sorted(set(dict(self.args)) & set(dict(env_args)))
        if both:
            raise ValueError(
                f"--env {self} and --env-args {ENV_ARGS.format(env_args)} both set {', '.join(both)}: "
                "give each field once, in either"
            )
        return EnvSpec(self.name, self.args + tuple(env_args))

    @property
    def env_args(self) -> str:
        """The overrides as `--env-args` text."""
        return ENV_ARGS.format(self.args)

    def __str__(self) -> str:
        return f"{self.name}:{self.env_args}" if self.args else self.name


def join_env_in(obj: Any) -> None:
    """Move the overrides of a frozen dataclass's `env` (``NAME:ARGS``) into its `env_args` (parsed pairs), in
    place (`EnvSpec.extended`): `env` is then a name alone. ValueError naming `--env` for bad overrides."""
    try:
        spec = EnvSpec.parse(obj.env)
    except ValueError as err:
        raise ValueError(f"--env {obj.env}: {err} (write NAME or NAME:field=value,...)") from err
    env = spec.extended(obj.env_args)
    object.__setattr__(obj, "env", env.name)
    object.__setattr__(obj, "env_args", env.args)


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


@dataclasses.dataclass(frozen=True)
class TextField:
    """A field written as text (a flag, config.json) and held parsed, as an instance of `kind`: `parse` runs
    once, where the config is made (the command line, `config_from_dict`, or text given to the constructor);
    `format` gives the text back (`parse(format(x)) == x`). A field that may be None is null in
    config.json."""

    parse: Callable[[str], Any]
    format: Callable[[Any], str]
    metavar: str
    kind: type = tuple

    def parse_in(self, obj: Any, name: str) -> None:
        """Parse `obj.name` (a frozen dataclass's field) in place where it was given as text."""
        if isinstance(value := getattr(obj, name), str):
            object.__setattr__(obj, name, self.parse(value))

    def flag(self) -> tyro.constructors.PrimitiveConstructorSpec:
        """How the command line reads and shows it."""
        return tyro.constructors.PrimitiveConstructorSpec(
            nargs=1,
            metavar=self.metavar,
            instance_from_str=lambda args: self.parse(args[0]),
            is_instance=lambda value: isinstance(value, self.kind),
            str_from_instance=lambda value: [self.format(value)],
        )


POLICY = TextField(PolicyRef.parse, str, "RUN_DIR[#k]", PolicyRef)
PolicyFlag = Annotated[PolicyRef, POLICY.flag()]
"""A `PolicyRef` flag."""
ENV = TextField(EnvSpec.parse, str, "NAME[:FIELD=VALUE,...]", EnvSpec)
EnvFlag = Annotated[EnvSpec, ENV.flag()]
"""An `EnvSpec` flag."""
ENV_ARGS = TextField(
    lambda text: tuple(dict(syntax.parse_assignments(text, syntax.literal)).items()),
    lambda pairs: syntax.format_assignments(pairs, repr),
    "FIELD=VALUE,...",
)
EnvArgsFlag = Annotated[tuple[tuple[str, Any], ...], ENV_ARGS.flag()]
"""EnvParams overrides, held as (field, value) pairs (a field given twice: its last value), written
'field=value,...' (`--env-args`)."""
