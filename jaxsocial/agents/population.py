"""What acts in each environment slot: a learner, a frozen policy (loaded from a checkpoint), a scripted
expert or a random distractor. Neural slots share one architecture; their parameters are stacked on a
leading slot axis and applied with `jax.vmap`, so nothing is shared between agents but the code.

This module is the slot mini-language (`parse_slot_list`, `format_slots`, `check_slots`) and the slots'
bookkeeping (`Population`); how they act is `jaxsocial.agents.acting`, and saved policies are read and
written by `jaxsocial.run.policy_io`. Only `stack` imports JAX: a run's slots are read and checked before.
"""

from __future__ import annotations

import dataclasses
from typing import Annotated

from jaxsocial import syntax
from jaxsocial.agents import expert_spec
from jaxsocial.env.params import EnvParams
from jaxsocial.specs import PolicyRef, TextField

SLOT_KINDS = ("learner", "frozen", "expert", "random")


@dataclasses.dataclass(frozen=True)
class Slot:
    """One environment slot: `kind` in SLOT_KINDS; `policy` the saved policy of a frozen slot (`RUN_DIR` or
    `RUN_DIR#k`, `specs.PolicyRef`); `expert` the scripted expert of an expert slot."""

    kind: str
    policy: PolicyRef | None = None
    expert: expert_spec.ExpertSpec | None = None

    @property
    def neural(self) -> bool:
        return self.kind in ("learner", "frozen")

    @property
    def label(self) -> str:
        """Short name for results: the kind, 'expert:KIND' for a scripted expert."""
        return f"expert:{self.expert.kind}" if self.kind == "expert" else self.kind

    def __str__(self) -> str:
        """The slot as `parse_slot` reads it: 'learner', 'frozen:POLICY', 'expert:KIND[:k=v,...]', ..."""
        if self.kind == "frozen":
            return f"frozen:{self.policy}"
        return f"expert:{self.expert}" if self.kind == "expert" else self.kind


def _split_entries(text: str) -> list[str]:
    """Split a slot list on commas, keeping an expert's own 'k=v,k=v' arguments with their entry."""
    entries: list[str] = []
    for token in syntax.split_entries(text):
        if entries and "=" in token and syntax.split_name(token)[0] not in SLOT_KINDS:
            entries[-1] += "," + token
        else:
            entries.append(token)
    return entries


def parse_slot(entry: str) -> Slot:
    """'learner' | 'random' | 'frozen:POLICY' | 'expert:ckpt=POLICY' (a trained expert, same as frozen; POLICY
    is `RUN_DIR` or `RUN_DIR#k`, `specs.PolicyRef`) | 'expert:KIND[:k=v,...]' (a scripted expert, see
    `expert_spec.parse_expert`). Raises ValueError."""
    kind, arg = syntax.split_name(entry)
    if kind not in SLOT_KINDS:
        raise ValueError(f"unknown slot kind {kind!r} in {entry!r}; choose from {SLOT_KINDS}")
    if kind == "expert":
        if not arg:
            raise ValueError(f"slot {entry!r}: say which expert, e.g. expert:explorer or expert:ckpt=RUN_DIR")
        if arg.startswith("ckpt="):
            return parse_slot(f"frozen:{arg.removeprefix('ckpt=')}")
        return Slot("expert", expert=expert_spec.parse_expert(arg))
    if (kind == "frozen") != bool(arg):
        raise ValueError(f"slot {entry!r}: 'frozen:POLICY' needs a run directory; {kind} takes none")
    return Slot(kind, PolicyRef.parse(arg) if arg else None)


def parse_slot_list(text: str) -> tuple[Slot, ...]:
    """Parse 'learner,expert:explorer,random,frozen:POLICY' (one entry per agent slot; '' gives ()): the
    syntax only, see `check_slots`. Raises ValueError."""
    return tuple(parse_slot(e) for e in _split_entries(text))


def check_slots(slots: tuple[Slot, ...], n_agents: int, need_learner: bool = True) -> tuple[Slot, ...]:
    """`slots` if there is one per agent and (with `need_learner`) a learner among them; else ValueError."""
    if len(slots) != n_agents:
        raise ValueError(
            f"--slots lists {len(slots)} slots ({format_slots(slots)!r}) but the environment has {n_agents} "
            "agents"
        )
    if need_learner and not any(s.kind == "learner" for s in slots):
        raise ValueError(f"--slots {format_slots(slots)!r} has no learner: nothing would be trained")
    return slots


def parse_slots(text: str, n_agents: int, need_learner: bool = True) -> tuple[Slot, ...]:
    """`parse_slot_list` then `check_slots`. Raises ValueError."""
    return check_slots(parse_slot_list(text), n_agents, need_learner)


def format_slots(slots: tuple[Slot, ...]) -> str:
    """The inverse of `parse_slot_list`: 'learner,expert:explorer,random'."""
    return ",".join(map(str, slots))


SLOTS = TextField(parse_slot_list, format_slots, "SLOT,...")
SlotsFlag = Annotated[tuple[Slot, ...], SLOTS.flag()]
"""Agent slots, held parsed, written 'SLOT,...' (`--slots`)."""

DEFAULT_EXPERT = {"goalcycle": "explorer", "fourrooms": "navigator", "maze": "navigator"}
"""The scripted expert of each layout."""


def default_slots(env_params: EnvParams) -> str:
    """The paper's set-up: a learner in slot 0, scripted experts in the next two slots (the environment's
    own agents), random distractors in any further slots (the `-distractors` presets)."""
    expert = f"expert:{DEFAULT_EXPERT[env_params.layout]}"
    return ",".join(
        ["learner"] + [expert] * min(2, env_params.n_agents - 1) + ["random"] * (env_params.n_agents - 3)
    )


def run_slots(slots: tuple[Slot, ...], env_params: EnvParams) -> tuple[Slot, ...]:
    """A training run's slots: `slots` (a run's `--slots`), or the environment's default where empty;
    checked for one per agent and a learner (ValueError)."""
    if not slots:
        default = default_slots(env_params)
        slots = parse_slot_list(default)
    return check_slots(slots, env_params.n_agents)


def require_rgb(env_params: EnvParams, where: str) -> None:
    """ValueError unless `env_params` gives RGB observations (for pictures of the decoder's predicted
    frames)."""
    if env_params.observation != "rgb":
        raise ValueError(f"{where}: pictures of predicted frames need RGB observations (observation='rgb')")


@dataclasses.dataclass(frozen=True)
class Population:
    """Static slot bookkeeping: indices of learner, frozen, neural (learner then frozen) and expert slots."""

    slots: tuple[Slot, ...]

    def _of(self, kind: str) -> tuple[int, ...]:
        return tuple(i for i, s in enumerate(self.slots) if s.kind == kind)

    @property
    def learners(self) -> tuple[int, ...]:
        return self._of("learner")

    @property
    def frozen(self) -> tuple[int, ...]:
        return self._of("frozen")

    @property
    def experts(self) -> tuple[int, ...]:
        return self._of("expert")

    @property
    def demonstrators(self) -> tuple[int, ...]:
        """Slots behaviour cloning learns from: scripted experts and frozen policies."""
        return tuple(sorted(self.experts + self.frozen))

    @property
    def neural(self) -> tuple[int, ...]:
        """Neural slots in stacking order: learners first, then frozen policies."""
        return self.learners + self.frozen

    def observers(self, cloned: bool = False) -> tuple[int, ...]:
        """The slots whose views are rendered (`observe.Observers`), in slot order: the neural slots, which
        read them (scripted experts and random slots read none), and with `cloned` the demonstrators, whose
        views behaviour cloning trains on."""
        return tuple(sorted(set(self.neural) | set(self.demonstrators if cloned else ())))

    def check_solo_learners(self, env_params: EnvParams, where: str) -> None:
        """ValueError if a learner would sit out the solo episodes of `env_params` (which keep only the first
        `solo_agents` slots); `where` names the environment."""
        if env_params.solo_prob > 0 and any(i >= env_params.solo_agents for i in self.learners):
            raise ValueError(
                f"{where}: solo episodes keep only the first solo_agents={env_params.solo_agents} slots, but "
                f"learners are in slots {self.learners}; put learners first or raise solo_agents"
            )

    def validate(self, env_params: EnvParams) -> None:
        """Raise ValueError if a scripted expert cannot play this environment."""
        for i in self.experts:
            try:
                expert_spec.check_playable(self.slots[i].expert, env_params)
            except ValueError as err:
                raise ValueError(f"slot {i}: {err}") from err


def default_population(env_params: EnvParams) -> Population:
    """The paper's set-up of an environment (`default_slots`), validated: the learner in slot 0."""
    pop = Population(parse_slots(default_slots(env_params), env_params.n_agents))
    pop.validate(env_params)
    return pop


def stack(trees: list) -> object:
    """Stack a list of equally shaped pytrees on a new leading axis."""
    import jax
    import jax.numpy as jnp

    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)
