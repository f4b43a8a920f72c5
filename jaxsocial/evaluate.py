"""Zero-shot evaluation of saved agents in any environment, beside any companions.

    python -m jaxsocial.evaluate --ckpt runs/goalcycle3-s0 --env fourrooms --episodes 100
    python -m jaxsocial.evaluate --ckpt runs/a runs/b --env goalcycle4 --slots learner,expert:explorer,random
    python -m jaxsocial.evaluate --env maze --slots expert:navigator,random,random     # no saved agent

    python -m jaxsocial.evaluate --ckpt runs/a runs/b runs/c --env goalcycle3 --protocol ct

The saved agent (`--ckpt`: run directories, one per training seed; `RUN_DIR#k` picks its k-th learner) plays
the `learner` slot; the other slots are scripted experts, frozen policies or random distractors (default:
the environment's scripted experts, as in training). Every episode runs to its end (no auto-reset). It prints
a table: each slot's mean episode return with a 95% confidence interval, over training seeds when there are
several checkpoints (Student t on the per-seed means) and over episodes otherwise; `--out FILE` writes the
full results as JSON.

`--protocol ct` is the cultural-transmission evaluation (after Bhoopchand et al. 2023; not in the paper): the
same episodes (same layouts and spawns) are played three times, with the other slots present throughout,
leaving at half time, and absent (solo). The CT score is the learner's gain from the experts, `(R_with -
R_solo) / R_experts`; recall is the gain kept after they left, the same over the second half of the episode
with the dropout case in place of `R_with`: 1 means the learner does as well as the experts, 0 that they make
no difference.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxsocial.agents import network, population
from jaxsocial.agents.episodes import Episodes, play_episodes
from jaxsocial.env import registry
from jaxsocial.env.types import EnvParams
from jaxsocial.run import jsonio, policy_io
from jaxsocial.run.metrics import LEARNED_RETURN
from jaxsocial.specs import (
    ENV_ARGS,
    EnvArgsFlag,
    EnvSpec,
    PolicyFlag,
    PolicyRef,
    join_env_in,
)
from jaxsocial.stats import mean_ci95


@dataclasses.dataclass(frozen=True)
class EvalConfig:
    """An evaluation. Every field is a command-line flag."""

    ckpt: tuple[PolicyFlag, ...] = ()
    """Run directories of the agent under test (RUN_DIR or RUN_DIR#k), one per training seed."""
    env: str = "goalcycle3"
    """Environment preset: goalcycle3, goalcycle4, fourrooms, maze, each also as NAME-solo and
    NAME-distractors; NAME or NAME:field=value,... (the overrides join --env-args)."""
    env_args: EnvArgsFlag = ()
    """EnvParams overrides, e.g. 'penalty=0.5,solo_prob=1.0'."""
    slots: population.SlotsFlag = ()
    """Slots as in training; 'learner' is the agent under test (default: the learner in slot 0 and the
    environment's scripted experts and distractors)."""
    episodes: int = 100
    """Episodes per checkpoint."""
    seed: int = 0
    """PRNG seed of the evaluation episodes."""
    out: str | None = None
    """Write the full results as JSON to this file (an existing file is not replaced without --overwrite)."""
    overwrite: bool = False
    """Replace an existing --out file."""
    protocol: str = "returns"
    """'returns' (each slot's episode return) or 'ct' (the cultural-transmission scores, see above)."""

    def __post_init__(self):  # text or paths given to the constructor are parsed here, once
        object.__setattr__(self, "ckpt", tuple(PolicyRef.of(c) for c in self.ckpt))
        ENV_ARGS.parse_in(self, "env_args")
        join_env_in(self)  # NAME:ARGS is NAME with --env-args ARGS
        population.SLOTS.parse_in(self, "slots")


PROTOCOLS = ("returns", "ct")


def _setup(eval_cfg: EvalConfig):
    """Validate everything and load the policies; raises ValueError before compiling."""
    if eval_cfg.episodes < 1:
        raise ValueError(f"--episodes {eval_cfg.episodes} must be >= 1")
    if eval_cfg.protocol not in PROTOCOLS:
        raise ValueError(f"unknown --protocol {eval_cfg.protocol!r}; choose one of {PROTOCOLS}")
    _, env_params = registry.make(eval_cfg.env, **dict(eval_cfg.env_args))
    slots = eval_cfg.slots or population.parse_slot_list(population.default_slots(env_params))
    pop = population.Population(population.check_slots(slots, env_params.n_agents, need_learner=False))
    pop.validate(env_params)
    if len(pop.learners) > 1:
        raise ValueError("evaluate one agent at a time: one 'learner' slot (use frozen:POLICY for others)")
    if bool(pop.learners) != bool(eval_cfg.ckpt):
        raise ValueError(
            "--ckpt fills the 'learner' slot: give both, or neither (then --slots must have no learner)"
        )
    policies = [pop.slots[i].policy for i in pop.frozen]
    first = (list(eval_cfg.ckpt) + policies)[:1]
    net_cfg = policy_io.saved_net(first[0]) if first else network.NetworkConfig(obs=env_params.observation)
    if first:
        net_cfg.check_env(env_params, f"--env {eval_cfg.env} with the policy {first[0]}")
    frozen = [policy_io.load_policy(p, net_cfg) for p in policies]
    if eval_cfg.protocol == "ct" and (
        pop.learners != (0,) or env_params.n_agents < 2 or env_params.solo_agents != 1
    ):
        raise ValueError(
            "--protocol ct plays the learner in slot 0 with and without the others: it needs --ckpt, the "
            f"learner first, at least 2 agent slots and solo_agents=1 (got slots "
            f"{[s.label for s in pop.slots]}, solo_agents={env_params.solo_agents})"
        )
    per_ckpt = [population.stack([policy_io.load_policy(c, net_cfg), *frozen]) for c in eval_cfg.ckpt]
    if not eval_cfg.ckpt:
        per_ckpt = [population.stack(frozen) if frozen else None]
    return env_params, pop, net_cfg, per_ckpt


def evaluate(eval_cfg: EvalConfig) -> dict[str, Any]:
    """Run the evaluation (`eval_cfg.protocol`) and return the JSON-able results."""
    env_params, pop, net_cfg, per_ckpt = _setup(eval_cfg)
    key = jax.random.key(eval_cfg.seed)
    header = {
        "env": eval_cfg.env,
        "env_args": ENV_ARGS.format(eval_cfg.env_args),
        "slots": [s.label for s in pop.slots],
        "checkpoints": [str(c) for c in eval_cfg.ckpt],
        "policy_iterations": [policy_io.policy_iteration(c) for c in eval_cfg.ckpt],
        "episodes_per_checkpoint": eval_cfg.episodes,
        "seed": eval_cfg.seed,
        "max_steps": env_params.max_steps,
    }
    if eval_cfg.protocol == "ct":
        cases = ct_cases(env_params)
        played = {
            name: [
                jax.device_get(play_episodes(key, pop, net_cfg, case, params, eval_cfg.episodes))
                for params in per_ckpt
            ]
            for name, case in cases.items()
        }
        demonstrators = pop.demonstrators or tuple(range(1, env_params.n_agents))
        return {**header, "protocol": "ct", **cultural_transmission(played, demonstrators)}
    results = [
        jax.device_get(play_episodes(key, pop, net_cfg, env_params, params, eval_cfg.episodes))
        for params in per_ckpt
    ]
    slots = []
    for i, slot in enumerate(pop.slots):
        samples = [r.returns[r.present[:, i], i] for r in results]
        seed_means = np.array([s.mean() for s in samples if len(s)])
        over_seeds = len(seed_means) > 1
        all_samples = np.concatenate(samples)
        if not len(all_samples):
            slots.append({"slot": i, "kind": slot.kind, "episodes": 0})
            continue
        mean, low, high = mean_ci95(seed_means if over_seeds else all_samples)
        spec = str(slot.policy) if slot.policy else dataclasses.asdict(slot.expert) if slot.expert else None
        slots.append(
            {
                "slot": i,
                "kind": slot.kind,
                "spec": spec,
                "mean_return": mean,
                "ci95": [low, high],
                "ci_over": "seeds" if over_seeds else "episodes",
                "episodes": int(len(all_samples)),
                "per_seed_mean": seed_means.tolist(),
            }
        )
    return {**header, "results": slots}


def ct_cases(env_params: EnvParams) -> dict[str, EnvParams]:
    """The three presence settings of the CT protocol: the other slots present throughout ('with'),
    leaving after half the episode ('dropout'), absent ('solo')."""
    social = env_params.replace(solo_prob=0.0, dropout_prob=0.0, dropin_prob=0.0)
    half = env_params.max_steps // 2
    return {
        "with": social,
        "dropout": social.replace(dropout_prob=1.0, dropout_min_step=half, dropout_max_step=half),
        "solo": social.replace(solo_prob=1.0),
    }


def _interval(values: np.ndarray) -> dict[str, Any]:
    mean, low, high = mean_ci95(values)
    return {"mean": mean, "ci95": [low, high]}


def cultural_transmission(played: dict[str, list[Episodes]], experts: tuple[int, ...]) -> dict[str, Any]:
    """CT scores from the `ct_cases` episodes of each checkpoint (the same episodes in every case), with the
    learner in slot 0 and the experts (the demonstrating slots) in `experts`.

    Per checkpoint, with `E` the experts' mean return in 'with' (over the whole episode, and `E_late` over
    its second half): `ct = (R_with - R_solo) / E` and `recall = (R_dropout_late - R_solo_late) / E_late`,
    where R are the learner's mean returns. Intervals are over checkpoints (seeds) when there are several,
    otherwise over episodes (the paired per-episode differences, divided by the same E).
    """
    learner = {name: [(r.returns[:, 0], r.late_returns[:, 0]) for r in runs] for name, runs in played.items()}
    cols = list(experts)
    expert_returns = [(r.returns[:, cols].mean(), r.late_returns[:, cols].mean()) for r in played["with"]]
    per_episode = {"ct": [], "recall": []}
    for k, (expert, expert_late) in enumerate(expert_returns):
        if expert <= 0 or expert_late <= 0:
            raise ValueError(
                f"checkpoint {k}: the experts' return over the episode ({expert:.3f}) and over its second "
                f"half ({expert_late:.3f}) must be > 0 to normalise"
            )
        per_episode["ct"].append((learner["with"][k][0] - learner["solo"][k][0]) / expert)
        per_episode["recall"].append((learner["dropout"][k][1] - learner["solo"][k][1]) / expert_late)
    over_seeds = len(expert_returns) > 1
    scores = {
        name: _interval(np.array([v.mean() for v in values]) if over_seeds else values[0])
        for name, values in per_episode.items()
    }
    returns = {
        name: {
            part: _interval(np.array([r[j].mean() for r in runs]) if over_seeds else runs[0][j])
            for j, part in enumerate(("episode", "second_half"))
        }
        for name, runs in learner.items()
    }
    return {
        **scores,
        "learner_returns": returns,
        "expert_return": {
            "episode": float(np.mean([e for e, _ in expert_returns])),
            "second_half": float(np.mean([e for _, e in expert_returns])),
        },
        "per_seed": {name: [float(v.mean()) for v in values] for name, values in per_episode.items()},
        "ci_over": "seeds" if over_seeds else "episodes",
    }


def _ci(value: dict[str, Any] | float, low: float | None = None, high: float | None = None, fmt=".2f") -> str:
    """'mean [low, high]' of a `_interval` dict, or of the three numbers."""
    if isinstance(value, dict):
        value, (low, high) = value["mean"], value["ci95"]
    return f"{value:{fmt}} [{low:{fmt}}, {high:{fmt}}]"


def format_table(result: dict[str, Any]) -> str:
    """A short human summary of an `evaluate` result: one line per slot (its mean episode return and 95%
    interval), or for `--protocol ct` the CT score, recall and the learner's returns in the three cases."""
    over = "training seeds" if len(result["checkpoints"]) > 1 else "episodes"
    iterations = ", ".join(str(i) for i in result["policy_iterations"])
    head = f"{result['env']}{':' + result['env_args'] if result['env_args'] else ''}: "
    head += f"{result['episodes_per_checkpoint']} episodes per checkpoint"
    if iterations:
        head += f", policies of training iteration {iterations}"
    if result.get("protocol") == "ct":
        returns = result["learner_returns"]
        lines = [
            f"{head}; 95% intervals over {over}",
            f"CT score  {_ci(result['ct'], fmt='.3f')}   (learner's gain from the experts / their return)",
            f"recall    {_ci(result['recall'], fmt='.3f')}   (the gain kept in the 2nd half after they left)",
            f"learner's return with the experts {_ci(returns['with']['episode'])}, alone "
            f"{_ci(returns['solo']['episode'])}, "
            f"in the 2nd half after they left {_ci(returns['dropout']['second_half'])}",
            f"experts' return {result['expert_return']['episode']:.2f} per episode",
        ]
        return "\n".join(lines)
    rows = [("slot", "agent", "mean return [95% interval]", "episodes")]
    for slot, label in zip(result["results"], result["slots"], strict=True):
        interval = _ci(slot["mean_return"], *slot["ci95"]) if slot["episodes"] else "absent"
        rows.append((str(slot["slot"]), label, interval, str(slot["episodes"])))
    widths = [max(len(row[i]) for row in rows) for i in range(4)]
    body = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip() for row in rows]
    return "\n".join([f"{head}; 95% intervals over {over}", *body])


def _contains_zero(value: dict[str, Any]) -> bool:
    return value["ci95"][0] <= 0.0 <= value["ci95"][1]


def learning_verdict(learner: float, experts: float, env_params: EnvParams) -> str:
    """Whether a learner's mean return beside experts shows the task learned: in Goal Cycle under a penalty,
    against the one-tile plateau (`metrics.LEARNED_RETURN`); elsewhere, as a share of the experts'."""
    share = f"{learner / experts:.0%} of the experts' return" if experts > 0 else "the experts score nothing"
    if env_params.layout != "goalcycle" or env_params.penalty == 0:
        return f"that is {share}"
    if learner > LEARNED_RETURN:
        return (
            f"past the one-tile plateau (return > {LEARNED_RETURN:g}): it completes the cycle here, {share}"
        )
    paid = "; below 0 it pays more wrong-tile penalties than it earns" if learner < 0 else ""
    cycle = f"{env_params.n_goals}-goal cycle"
    return (
        f"on the one-tile plateau (return <= {LEARNED_RETURN:g}): it does not complete the {cycle} here{paid}"
    )


def result_lines(result: dict[str, Any], eval_cfg: EvalConfig) -> list[str]:
    """What an `evaluate` result shows, in words, and the commands to look further: the learner's return
    against its experts'; for `--protocol ct`, whether the experts make a difference and whether it lasts
    after they leave."""
    lines = []
    if result.get("protocol") == "ct":
        ct, recall = result["ct"], result["recall"]
        if _contains_zero(ct):
            lines.append("the experts make no difference the interval can tell from 0 (CT score)")
        elif ct["mean"] > 0 and _contains_zero(recall):
            lines.append(
                "the learner scores more beside the experts, but not once they leave (recall about 0): "
                "it follows them rather than having learned the task from them"
            )
        elif ct["mean"] > 0:
            lines.append("the learner scores more beside the experts, and keeps part of it after they leave")
        else:
            lines.append("the learner scores less beside the experts than alone")
    else:
        by_kind = {kind: [s for s in result["results"] if s["kind"] == kind and s["episodes"]] for kind in
                   ("learner", "expert")}  # fmt: skip
        if by_kind["learner"] and by_kind["expert"]:
            learner = np.mean([s["mean_return"] for s in by_kind["learner"]])
            experts = np.mean([s["mean_return"] for s in by_kind["expert"]])
            lines.append(f"the learner scored {learner:.2f} per episode beside experts scoring {experts:.2f}")
            lines.append(
                learning_verdict(learner, experts, registry.env_params(eval_cfg.env, eval_cfg.env_args))
            )
    lines += _next(result, eval_cfg)
    if not eval_cfg.out:
        lines.append("      add --out FILE to keep every number above (and the per-seed values) as JSON")
    return lines


def _next(result: dict[str, Any], eval_cfg: EvalConfig) -> list[str]:
    """The command to run after an evaluation of a saved learner: the CT protocol where it applies (the
    learner first, beside experts, solo_agents 1), then a designed comparison over seeds (`render` points
    here, so this points onwards)."""
    if not eval_cfg.ckpt:
        return []
    env = EnvSpec(eval_cfg.env, eval_cfg.env_args)
    slots = result.get("results", ())
    if result.get("protocol") != "ct" and slots and slots[0]["kind"] == "learner" and any(
        s["kind"] == "expert" for s in slots
    ) and registry.env_params(env.name, env.args).solo_agents == 1:  # fmt: skip
        ckpts = " ".join(str(c) for c in eval_cfg.ckpt)
        return [
            "next: does it learn from the experts, and keep it once they leave? python -m "
            f"jaxsocial.evaluate --ckpt {ckpts} --env {env} --protocol ct"
        ]
    return ["next: compare conditions over fresh seeds, with a test: docs/your-experiment.md"]


def main(argv: list[str] | None = None) -> None:
    import tyro

    eval_cfg = tyro.cli(
        EvalConfig,
        args=sys.argv[1:] if argv is None else argv,
        description=__doc__,
        prog="python -m jaxsocial.evaluate",
    )
    if eval_cfg.out and Path(eval_cfg.out).exists() and not eval_cfg.overwrite:
        raise SystemExit(f"error: {eval_cfg.out} exists; pass --overwrite to replace it")
    try:
        result = evaluate(eval_cfg)
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from err
    print(format_table(result))
    for line in result_lines(result, eval_cfg):
        print(line)
    if eval_cfg.out:
        Path(eval_cfg.out).parent.mkdir(parents=True, exist_ok=True)
        jsonio.write_json(eval_cfg.out, result)
        print(f"wrote {eval_cfg.out}")


if __name__ == "__main__":
    main()
