"""Policies played zero-shot: an evaluation design's evaluations (`run`: what is missing, blind, each
process logged, `plan.evaluation_design`), and one seed's final policy in one environment, its result
written (`evaluate_into`: the recipes' evaluations after training, the follow-ups')."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from jaxsocial.env import registry
from jaxsocial.experiments.analyse import evaluation_results
from jaxsocial.experiments.plan import commits, paths
from jaxsocial.experiments.plan.evaluation_design import PROVENANCE, EvaluationDesign, evaluations, out_dir
from jaxsocial.run import jsonio, provenance
from jaxsocial.specs import EnvSpec


def run(design: EvaluationDesign, records_root: Path, science: Path) -> None:
    """Play every evaluation of the design that has no result yet, blind (no score is printed), and log each
    process's commit, date and machine in `<out>/provenance.jsonl`. Nothing runs if a record is missing."""
    from jaxsocial import evaluate
    from jaxsocial.agents import population

    missing = evaluation_results.absent_records(design, records_root)
    if missing:
        hint = paths.missing_records(records_root / design.records)
        raise FileNotFoundError(hint or f"the design's material is incomplete: {', '.join(missing)}")
    out = out_dir(design, science)
    todo = [e for e in evaluations(design, records_root) if not e.path(out).exists()]
    print(f"[{design.name}] {len(todo)} of {len(evaluations(design, records_root))} evaluations to play")
    for e in todo:
        spec, slots = EnvSpec.parse(e.env), ()
        if e.slot:  # in the learner's place, beside the environment's own slots
            others = population.default_slots(registry.env_params(spec.name, spec.args)).split(",")[1:]
            slots = population.parse_slot_list(",".join([e.slot, *others]))
        config = evaluate.EvalConfig(
            ckpt=e.ckpts,
            env=spec.name,
            env_args=spec.args,
            episodes=design.episodes,
            seed=design.eval_seed,
            slots=slots,
        )
        started = provenance.now()
        result = evaluate.evaluate(config)
        out.mkdir(parents=True, exist_ok=True)
        jsonio.write_json(e.path(out), result)
        when = {
            "file": e.path(out).name,
            "commit": commits.head_commit(),
            "started": started,
            "ended": provenance.now(),
        }
        line = when | provenance.machine(None)
        with (out / PROVENANCE).open("a") as f:
            f.write(json.dumps(line) + "\n")
        print(f"[{design.name}] {e.env} {e.player}: played ({len(e.ckpts) or 1} policies)", flush=True)


def evaluate_into(out: Path, seed_dir: Path, spec: str, episodes: int, protocol: str) -> dict[str, Any]:
    """Play the final policy of `seed_dir` in the environment `spec` (NAME[:field=value,...]) for `episodes`
    episodes with the evaluation `protocol` (`jaxsocial.evaluate`); write the result to `out`, return it."""
    from jaxsocial import evaluate

    env = EnvSpec.parse(spec)
    config = evaluate.EvalConfig(
        ckpt=(str(seed_dir),), env=env.name, env_args=env.args, episodes=episodes, protocol=protocol
    )
    result = evaluate.evaluate(config)
    out.parent.mkdir(parents=True, exist_ok=True)
    jsonio.write_json(out, result)
    return result
