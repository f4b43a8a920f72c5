"""Re-train the first iterations of a committed record and say whether its training re-runs exactly.

    python -m jaxsocial.experiments verify benchmarks/results/records/laptop/bc-s0-0
    python -m jaxsocial.experiments verify RECORD --iterations 20 --out verify.json

The record's config.json (read under today's field names) is trained again for its first K iterations in a
fresh run directory outside the record, in a process of its own with the $XLA_FLAGS the record's run
had (from its provenance; older records: single-threaded XLA where it says one core, as `pinned` trains)
and seeing as many CPU cores as the record's process saw (`record_cores`): pinned to one where the record's
was, since XLA's CPU bits depend on how many cores a process sees even single-threaded
(docs/reproducibility.md, "Does the training re-run?"). The two metrics logs are compared row by row, every
field but the timings (`TIMING_FIELDS`). The report says **exact**, or the first row and field that differ
with both values and the size of the difference, and names the CPU of the record and of this machine, the
cores each process saw, and where their instruction sets, cache sizes or package versions differ
(`provenance.environment`): bitwise agreement is expected on the same CPU model, commit and count of cores,
and across models only where their committed operation fingerprints agree under the record's $XLA_FLAGS
(`cpu_kinds`). Before it trains it says what to expect (`prediction`: "exact expected", "expected to differ,
because ..." or unknown, from the record's CPU and this machine's, the record's flags and the kinds'
fingerprint files, the cores and the package versions), and its report starts with that; it ends with what
re-trains the record bit for bit (`how_to_reproduce`). Nothing is written into the record.

A run directory that is no record verifies too: its process file (`provenance.RUN_FILE`, which every
training run writes) says what a record's provenance says. Run it from a worktree of the record's commit
(with the record's `tree-*.diff` applied where its run trained from a dirty tree) for the strict check; on
today's code it checks that the mathematics did not change since, where the configs map. The laptop and cpu
scales have no schedule over the run's length, so their first K iterations are those of the full run.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from jaxsocial.experiments.analyse import cpu_kinds, records
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan import xla_flags
from jaxsocial.run import checkout, config, cpuinfo, metrics, provenance, rundir
from jaxsocial.run.flags import config_flags

TIMING_FIELDS = (metrics.SPEED, metrics.COMPILE_S)
"""Row fields that measure the machine, not the mathematics: never compared."""
DEFAULT_ITERATIONS = 10


def retrain(record_dir: Path, iterations: int, work_dir: Path) -> Path:
    """Train the first `iterations` of the record's config into `work_dir` in a process of its own, with
    `retraining_flags`, on `retraining_cores`; return the new run directory."""
    cfg = config.config_from_dict(rundir.read_config(record_dir))
    if iterations > cfg.iterations:
        raise ValueError(f"--iterations {iterations}: the record trained only {cfg.iterations}")
    cfg = dataclasses.replace(cfg, iterations=iterations)
    cores = retraining_cores(record_cores(record_dir))
    return train_in_process(cfg, work_dir, retraining_flags(record_dir), cores)


def record_field(record_dir: Path, key: str) -> Any:
    """One field of the record's run provenance; of a run directory that is no record, its process file's
    (what `train` or `pinned` wrote: a plain `python -m jaxsocial.train` run verifies as a record does)."""
    return records.run_field(record_dir, key, process_file=True)


def record_cores(record_dir: Path) -> int | None:
    """How many CPU cores the record's training process could see: its provenance's `visible_cores`; for a
    record from before that field, the runner's rule: one where `pinned.run` gave it a core (`cores` 1) or
    its device says "one core per" seed or branch, else all the "N cores" of its device (None: not said)."""
    visible = record_field(record_dir, "visible_cores")
    if visible:
        return len(visible)
    if record_field(record_dir, "cores") == 1:
        return 1
    device = record_field(record_dir, "device") or ""
    if "one core per" in device:
        return 1
    count = re.search(r"(\d+) cores", device)
    return int(count[1]) if count else None


def retraining_cores(count: int | None) -> list[int] | None:
    """The cores to pin a re-training of a record whose process saw `count` to: the first `count` of this
    process's where it sees more (None: no pinning, where it sees as many, fewer, or `count` is unknown)."""
    mine = provenance.visible_cores()
    return mine[:count] if count and mine and count < len(mine) else None


def retraining_flags(record_dir: Path) -> str:
    """The $XLA_FLAGS the record's provenance records (a record without them: the single-core flags where its
    run had one core, else this process's)."""
    xla_flags = record_field(record_dir, "xla_flags")
    if xla_flags is None:
        one_core = record_cores(record_dir) == 1
        xla_flags = pinned.SINGLE_CORE_XLA_FLAGS if one_core else os.environ.get("XLA_FLAGS", "")
    return xla_flags


def train_in_process(
    cfg: config.TrainConfig, work_dir: Path, xla_flags: str, cores: list[int] | None = None
) -> Path:
    """Train `cfg` (its seeds, iterations and program as they are) as run 'verify' under `work_dir`, in a
    process of its own with $XLA_FLAGS `xla_flags`, pinned to `cores` (`pinned.pin`; None: this process's),
    no logger, progress line or compilation cache; return the run directory (RuntimeError, with the log's
    tail, if training fails)."""
    cfg = dataclasses.replace(
        cfg,
        runs_dir=str(work_dir),
        run_name="verify",
        resume=False,
        overwrite=False,
        logger=None,
        progress=False,
        compile_cache=None,
    )
    log = work_dir / "verify.log"
    with log.open("w") as out:
        process = subprocess.run(
            [*pinned.pin(cores), sys.executable, "-m", "jaxsocial.train", *config_flags(cfg)],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=_uncached(os.environ) | {"XLA_FLAGS": xla_flags},
        )
    if process.returncode != 0:
        tail = "\n".join(log.read_text().splitlines()[-15:])
        raise RuntimeError(f"re-training failed (exit {process.returncode}):\n{tail}")
    return work_dir / "verify"


def _uncached(env: Mapping[str, str]) -> dict[str, str]:
    """`env` without $JAX_COMPILATION_CACHE_DIR: a program compiled by another process (maybe seeing other
    cores) is not loaded."""
    return {k: v for k, v in env.items() if k != "JAX_COMPILATION_CACHE_DIR"}


def first_difference(
    recorded: list[dict[str, Any]], retrained: list[dict[str, Any]]
) -> dict[str, Any] | None:
    """The first row (in order) and field (in the record's order) whose values differ, timings aside, with
    both values and their absolute and relative difference; None if every row is equal. A field one row has
    and the other lacks counts as a difference."""
    for old, new in zip(recorded, retrained, strict=False):
        for field in dict.fromkeys([*old, *new]):
            if field in TIMING_FIELDS:
                continue
            a, b = old.get(field), new.get(field)
            if a == b or _both_nan(a, b):
                continue
            out = {"iteration": old.get(metrics.ITERATION), "field": field, "record": a, "retrained": b}
            if isinstance(a, int | float) and isinstance(b, int | float):
                out["abs"] = abs(float(a) - float(b))
                out["rel"] = out["abs"] / max(abs(float(a)), abs(float(b)), 1e-300)
            return out
    return None


def _both_nan(a: Any, b: Any) -> bool:
    return isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)


def without_final_evaluation(
    retrained: list[dict[str, Any]], recorded: list[dict[str, Any]]
) -> list[dict[str, Any]]:
    """`retrained` without the evaluations its last row holds where the record's row of that iteration has
    none: a run evaluates when it ends, so a re-training cut short of the record's length evaluates at an
    iteration where the record did not (its training fields are still compared)."""
    if not retrained or len(retrained) > len(recorded):
        return retrained
    last, theirs = retrained[-1], recorded[len(retrained) - 1]
    kept = {k: v for k, v in last.items() if not (metrics.is_eval_key(k) and k not in theirs)}
    return [*retrained[:-1], kept]


def verify(record_dir: Path, iterations: int = DEFAULT_ITERATIONS, work_dir: Path | None = None) -> dict:
    """Re-train the first `iterations` of a record and compare (see the module docstring). `work_dir`: where
    the new run goes (default: a temporary directory, removed afterwards)."""
    record_dir = Path(record_dir)
    if not (record_dir / rundir.CONFIG_FILE).is_file():
        raise FileNotFoundError(f"{record_dir} holds no config.json: not a record or run directory")
    recorded = rundir.read_metrics(record_dir)[:iterations]
    if len(recorded) < iterations:
        raise ValueError(f"--iterations {iterations}: the record logged only {len(recorded)} rows")
    cores = record_cores(record_dir)
    expected = prediction(record_dir, cores, pinned.cores_seen(retraining_cores(cores)))
    print(f"prediction: {expected['says']}", flush=True)
    here = checkout.tree()
    with tempfile.TemporaryDirectory(prefix="jaxsocial-verify-") as tmp:
        run_dir = retrain(record_dir, iterations, Path(work_dir or tmp))
        retrained = without_final_evaluation(rundir.read_metrics(run_dir), recorded)
    difference = first_difference(recorded, retrained)
    return {
        "record": str(record_dir),
        "iterations": iterations,
        "prediction": expected,
        "exact": difference is None and len(retrained) == len(recorded),
        "rows": [len(recorded), len(retrained)],
        "first_difference": difference,
        "compared": "every field of every row but " + ", ".join(TIMING_FIELDS),
        "cpu": {
            "record": record_field(record_dir, "device") or record_field(record_dir, "cpu"),
            "here": cpuinfo.model(),
        },
        "environment": {
            "record": {field: record_field(record_dir, field) for field in provenance.ENVIRONMENT_FIELDS},
            "here": provenance.environment(),
        },
        "commit": {"record": record_field(record_dir, "commit"), "here": here.commit},
        "tree": {
            "record": {k: record_field(record_dir, k) for k in checkout.TREE_FIELDS},
            "here": here.fields(),
        },
        "xla_flags": retraining_flags(record_dir),
        "cores": {"record": cores, "here": pinned.cores_seen(retraining_cores(cores))},
    }


def record_cpu(record_dir: Path) -> str | None:
    """The CPU the record trained on: its provenance's `cpu`, else its `device` (older records name the CPU
    and its family and model there)."""
    return record_field(record_dir, "cpu") or record_field(record_dir, "device")


def prediction(record_dir: Path, cores: int | None, cores_here: int | None) -> dict:
    """What re-training the record here should give, said before it trains (`cpu_kinds.predict`'s dict, with
    `alike`: the kinds whose fingerprints all equal the record's kind's under its flags): expected to differ
    where this process cannot see as many cores as the record's did, unknown where the count is not recorded
    or the package versions differ, else from the record's CPU and this one's under the record's flags."""
    cpu, flags = record_cpu(record_dir), retraining_flags(record_dir)
    kinds = cpu_kinds.read_kinds()
    alike = {"alike": cpu_kinds.alike(kinds, cpu, flags)}
    theirs, mine = record_field(record_dir, "versions"), provenance.environment()["versions"]
    if cores is None:
        said = "the record does not say how many cores its process saw: unknown"
        return cpu_kinds.expectation(cpu_kinds.UNKNOWN, said) | alike
    if cores != cores_here:
        said = f"expected to differ, because its process saw {_count(cores)} and the re-training sees "
        return cpu_kinds.expectation(cpu_kinds.DIFFER, said + _count(cores_here)) | alike
    if theirs and theirs != mine:
        changed = "; ".join(
            f"{p}: record {theirs.get(p)}, here {v}" for p, v in mine.items() if theirs.get(p) != v
        )
        said = f"package versions differ ({changed}): unknown"
        return cpu_kinds.expectation(cpu_kinds.UNKNOWN, said) | alike
    return cpu_kinds.predict(cpu, cpuinfo.model(), flags, cores, kinds) | alike


def environment_differences(record: dict, here: dict) -> list[str]:
    """One line per `provenance.environment` field in which the record's run and this machine differ, for
    people ('not recorded' where the record predates the field)."""
    lines = []
    for field, mine in here.items():
        theirs = record.get(field)
        if theirs is None:
            lines.append(f"  {field}: not recorded; here {mine}")
        elif theirs != mine:
            lines.append(f"  {field} differ: record {theirs}; here {mine}")
    return lines


def report(result: dict) -> str:
    """A verification's result, for people."""
    head = f"{result['record']}: first {result['iterations']} iterations re-trained"
    expected = result.get("prediction")
    lines = [f"prediction: {expected['says']}", head] if expected else [head]
    if result["exact"]:
        lines.append(f"  exact: every row equal ({result['compared']})")
    elif result["first_difference"] is None:
        lines.append(f"  differs: rows logged {result['rows'][0]} (record) against {result['rows'][1]}")
    else:
        d = result["first_difference"]
        size = f" (abs {d['abs']:.3g}, rel {d['rel']:.3g})" if "abs" in d else ""
        lines.append(
            f"  differs from iteration {d['iteration']}, field {d['field']}: record {d['record']!r}, "
            f"re-trained {d['retrained']!r}{size}"
        )
    lines.append(f"  CPU: record {result['cpu']['record']}; here {result['cpu']['here']}")
    lines.append(f"  XLA flags (the record's): {result['xla_flags'] or 'none'}")
    cores = result["cores"]
    lines.append(f"  cores seen: record {_count(cores['record'])}; re-training {_count(cores['here'])}")
    if not result["exact"] and not xla_flags.hold(result["xla_flags"], pinned.CROSS_CPU_XLA_FLAGS):
        lines.append(
            "  where the CPU models differ that is expected: the record trained with XLA's platform-dependent"
            f" math, whose bits differ across them ({pinned.CROSS_CPU_XLA_FLAGS} removes it; "
            "docs/reproducibility.md)"
        )
    if not result["exact"] and (cores["record"] is None or cores["record"] != cores["here"]):
        lines.append(
            "  where the counts of cores differ that is expected: XLA's CPU bits depend on how many cores a"
            " process sees, even single-threaded (docs/reproducibility.md)"
        )
    lines += environment_differences(result["environment"]["record"], result["environment"]["here"])
    tree = result.get("tree") or {"record": {}, "here": {}}
    lines.append(
        f"  commit: record {result['commit']['record']}{_dirty(tree['record'])}; "
        f"here {result['commit']['here']}{_dirty(tree['here'])}"
    )
    lines.append(how_to_reproduce(result))
    return "\n".join(lines)


def _dirty(tree: dict) -> str:
    """What a commit line adds for a tree (`checkout.Tree.fields`): nothing where clean or not recorded."""
    return f" with jaxsocial/ changed ({tree.get('tree_diff')})" if tree.get("dirty") else ""


def _count(cores: int | None) -> str:
    return "not recorded" if cores is None else f"{cores} core{'s' * (cores != 1)}"


def how_to_reproduce(result: dict) -> str:
    """What re-trains the record bit for bit, as measured (docs/reproducibility.md, "Does the training
    re-run?")."""
    flags, cores, cpu = result["xla_flags"], result["cores"]["record"], result["cpu"]["record"]
    cpus = cpu or "its CPU model (not recorded)"
    alike = (result.get("prediction") or {}).get("alike")
    if alike:
        cpus += (
            f" or a kind whose operation fingerprints agree with it under those flags ({', '.join(alike)})"
        )
    seen = "as many cores as its process did (not recorded)" if cores is None else _count(cores)
    diff = ((result.get("tree") or {}).get("record") or {}).get("tree_diff")
    commit = (result["commit"]["record"] or "(not recorded)") + (
        f" with its {diff} applied (git apply)" if diff else ""
    )
    return (
        f"  bit for bit it re-trains from commit {commit}, with "
        f"$XLA_FLAGS '{flags}', in a process that sees {seen} (verify pins itself so), on {cpus}, with the "
        "same package versions"
    )
