"""The metrics format: what the rows of a training run's `metrics.jsonl` hold, how they are written from a
chunk's metrics (`metric_rows`) and how they are read back (curves, final returns, the slots, learners and
evaluations present, the cost of training).

A row is one training iteration::

    {"iteration": 12, "env_steps_per_s": 51234, "stage": -1,
     "return/0": 1.5, "episodes/0": 4, "return/1": 30.0, "episodes/1": 4,     # every slot
     "aux_loss/0": 0.12, "kl/0": 0.01, "entropy/0": 1.0, ...,                # every learner slot
     "eval/goalcycle4:width=9": 3.2,                                         # evaluation iterations only
     "compile_s": 12.3, "nonfinite": [...]}                                   # where they apply

Keys are built and taken apart only here (`key`, `eval_key`, `split_key`). The file itself (append,
truncate, the gzipped copy of a record) and the seed directories of a run are `jaxsocial.run.rundir`'s
(`MetricsLog`, `read_metrics`, `written_seed_dirs`); the statistics over seeds are `jaxsocial.stats`. This
module needs numpy only: tools that read runs (`plot`, `render`, `experiments.summaries`) import it without
the training stack.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

ITERATION = "iteration"
SPEED = "env_steps_per_s"
LEARNED_RETURN = 2.0
"""A seed whose final return exceeds this has learned more than the cautious individual policy, which collects
the free first tile (+1) and then avoids tiles (the one-tile plateau); summaries count such seeds."""
"""Env-steps per second per seed of the chunk the row belongs to."""
STAGE = "stage"
"""The schedule stage the iteration trained in (-1: before the first stage)."""
COMPILE_S = "compile_s"
"""Seconds spent compiling, on the first row of a chunk that compiled."""
RETURN = "return"
"""Per slot: the mean return of the episodes that ended in the iteration (0 if none did)."""
EPISODES = "episodes"
"""Per slot: how many episodes ended in the iteration."""
EVAL = "eval"
"""Per evaluation environment spec: the first learner's mean return (`eval/<spec>`)."""
SLOT_METRICS = (RETURN, EPISODES)
"""Metrics logged for every slot; every other metric of a chunk is logged per learner slot."""

FINAL_FRACTION = 0.1
"""The share of training iterations, at the end, over which the final return is averaged."""
CURVE_POINTS = 50
"""Points per learning curve (iterations are averaged in blocks)."""


# ----------------------------------------------------------------------------------------------------------
# Keys
# ----------------------------------------------------------------------------------------------------------


def key(name: str, slot: int) -> str:
    """The key of metric `name` of agent `slot`, e.g. 'return/0', 'aux_loss/1'."""
    return f"{name}/{slot}"


def eval_key(spec: str) -> str:
    """The key of the evaluation in environment `spec`, e.g. 'eval/goalcycle4:width=9'."""
    return f"{EVAL}/{spec}"


def split_key(k: str) -> tuple[str, str] | None:
    """(name, slot or spec) of a per-slot or evaluation key ('return/0' -> ('return', '0')); None for the
    row's other keys ('iteration', 'stage', ...)."""
    name, sep, rest = k.partition("/")
    return (name, rest) if sep else None


def eval_spec(k: str) -> str:
    """The environment spec of an evaluation key ('eval/goalcycle4' -> 'goalcycle4')."""
    return k.removeprefix(EVAL + "/")


def is_eval_key(k: str) -> bool:
    return k.startswith(EVAL + "/")


# ----------------------------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------------------------


def metric_rows(
    metrics: Mapping[str, np.ndarray], first_iteration: int, sps: float, pop
) -> list[dict[str, Any]]:
    """One row per iteration of a chunk's `metrics` (host arrays with a leading iteration axis: 'return' and
    'episodes' [I, slots], every other metric [I, learners]): the iteration (counted from
    `first_iteration` + 1), the speed `sps`, every slot's return and episode count and every learner's
    metrics. `pop` is the run's `population.Population` (its `slots` and `learners`)."""
    rows = []
    n = len(next(iter(metrics.values())))
    for i in range(n):
        row: dict[str, Any] = {ITERATION: first_iteration + i + 1, SPEED: sps}
        for slot in range(len(pop.slots)):
            row[key(RETURN, slot)] = float(metrics[RETURN][i][slot])
            row[key(EPISODES, slot)] = int(metrics[EPISODES][i][slot])
        for name, value in metrics.items():
            if name in SLOT_METRICS:
                continue
            for j, slot in enumerate(pop.learners):
                row[key(name, slot)] = float(value[i][j])
        rows.append(row)
    return rows


def eval_fields(results: Mapping[str, float]) -> dict[str, float]:
    """The row entries of evaluations during training: {spec: mean return} -> {'eval/<spec>': mean return}."""
    return {eval_key(spec): value for spec, value in results.items()}


def progress_fields(
    metrics: Mapping[str, np.ndarray], sps: float, pop, returns_shown: bool = True
) -> dict[str, Any]:
    """What the progress line shows for a chunk: speed and (`returns_shown`) each slot's mean return over the
    episodes that finished in the chunk ('-' where none did), named `return[<slot> <kind>]`, e.g.
    'return[1 explorer]'."""
    shown: dict[str, Any] = {"env-steps/s": int(sps)}
    if not returns_shown:
        return shown
    episodes = metrics[EPISODES].sum(0)
    returns = (metrics[RETURN] * metrics[EPISODES]).sum(0) / np.maximum(episodes, 1)
    for s, (r, n) in enumerate(zip(returns, episodes, strict=True)):
        shown[f"return[{s} {pop.slots[s].label.split(':')[-1]}]"] = float(r) if n else "-"
    return shown


def learner_return(metrics: Mapping[str, np.ndarray], pop) -> float | None:
    """The learners' mean episode return over a chunk's finished episodes (None if none finished)."""
    learners = list(pop.learners)
    episodes = metrics[EPISODES][:, learners]
    if episodes.sum() == 0:
        return None
    return float((metrics[RETURN][:, learners] * episodes).sum() / episodes.sum())


# ----------------------------------------------------------------------------------------------------------
# Reading: what a run logged
# ----------------------------------------------------------------------------------------------------------


def slots(row: Mapping[str, Any]) -> list[int]:
    """The agent slots a row reports (those with a return)."""
    return sorted(int(p[1]) for k in row if (p := split_key(k)) and p[0] == RETURN)


def logged(row: Mapping[str, Any], name: str, slot: int) -> bool:
    """Whether `row` has metric `name` of `slot`."""
    return key(name, slot) in row


def learner_metrics(row: Mapping[str, Any]) -> dict[str, list[int]]:
    """Each per-learner metric a row reports and the slots it reports it for, e.g. {'kl': [0]}."""
    out: dict[str, list[int]] = {}
    for k in row:
        parts = split_key(k)
        if parts and parts[0] not in (*SLOT_METRICS, EVAL):
            out.setdefault(parts[0], []).append(int(parts[1]))
    return {name: sorted(s) for name, s in out.items()}


def learners(row: Mapping[str, Any]) -> list[int]:
    """The learner slots a row reports metrics for."""
    return sorted({s for found in learner_metrics(row).values() for s in found})


def eval_keys(seed_rows: Iterable[Iterable[Mapping[str, Any]]]) -> list[str]:
    """The evaluation keys ('eval/<spec>') any row of any seed logged, sorted."""
    return sorted({k for rows in seed_rows for r in rows for k in r if is_eval_key(k)})


def switch_iteration(rows: list[Mapping[str, Any]]) -> int | None:
    """The first iteration a run trained in a stage of its schedule (None: it never left the plain
    environment), e.g. where a mixed condition switched to solo episodes."""
    return next((row[ITERATION] for row in rows if row.get(STAGE, -1) >= 0), None)


# ----------------------------------------------------------------------------------------------------------
# Reading: curves and final values
# ----------------------------------------------------------------------------------------------------------


def slot_returns(rows: list[Mapping[str, Any]], slot: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-iteration float64[I] summed returns and episode counts of one slot."""
    r, e = key(RETURN, slot), key(EPISODES, slot)
    returns = np.array([row[r] * row[e] for row in rows], np.float64)
    episodes = np.array([row[e] for row in rows], np.float64)
    return returns, episodes


def final_return(rows: list[Mapping[str, Any]], slot: int = 0) -> float:
    """Episode-weighted mean return of `slot` over the last `FINAL_FRACTION` of the iterations (nan if no
    episode ended there)."""
    n = max(1, round(len(rows) * FINAL_FRACTION))
    returns, episodes = slot_returns(rows[-n:], slot)
    return float(returns.sum() / episodes.sum()) if episodes.sum() else float("nan")


def curve(
    rows: list[Mapping[str, Any]], slot: int = 0, points: int = CURVE_POINTS
) -> tuple[np.ndarray, np.ndarray]:
    """(iterations, episode-weighted mean return) in `points` blocks of consecutive iterations."""
    returns, episodes = slot_returns(rows, slot)
    blocks = np.array_split(np.arange(len(rows)), min(points, len(rows)))
    x = np.array([rows[b[-1]][ITERATION] for b in blocks], np.float64)
    y = np.array([returns[b].sum() / max(episodes[b].sum(), 1.0) for b in blocks])
    return x, y


def metric_curve(rows: list[Mapping[str, Any]], k: str) -> tuple[np.ndarray, np.ndarray]:
    """(iterations, value) float64[I] of every row, e.g. key 'kl/0'; nan where a row has no (finite) value."""
    iterations = np.array([r[ITERATION] for r in rows], np.float64)
    return iterations, np.array([np.nan if r.get(k) is None else r[k] for r in rows], np.float64)


def eval_curve(rows: list[Mapping[str, Any]], k: str) -> tuple[np.ndarray, np.ndarray]:
    """(iterations, value) of the rows that logged the evaluation `k` (e.g. 'eval/goalcycle4')."""
    found = [r for r in rows if r.get(k) is not None]
    return np.array([r[ITERATION] for r in found], np.float64), np.array([r[k] for r in found])


def final_eval(rows: list[Mapping[str, Any]], k: str) -> float:
    """The mean of the evaluation `k` over its last `FINAL_FRACTION` of evaluations (nan if none)."""
    _, values = eval_curve(rows, k)
    n = max(1, round(len(values) * FINAL_FRACTION))
    return float(values[-n:].mean()) if len(values) else float("nan")


# ----------------------------------------------------------------------------------------------------------
# Cost
# ----------------------------------------------------------------------------------------------------------


def steps_per_iteration(config: Mapping[str, Any]) -> int:
    """Env-steps per iteration and seed of a run's config."""
    return config["num_envs"] * config["rollout_steps"]


def cpu_minutes(
    rows: list[Mapping[str, Any]], per_iteration: int, cores: int, iterations: int | None = None
) -> float:
    """CPU-minutes of training (compilation excluded) over the first `iterations` rows (default: all), from
    each row's logged env-steps/s (`per_iteration` env-steps a row), on `cores` cores."""
    seconds = sum(per_iteration / row[SPEED] for row in rows[:iterations])
    return float(seconds) * cores / 60
