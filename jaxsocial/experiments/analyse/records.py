"""Run records: a seed's run directory slimmed to what a result rests on, small enough for the repository.

A record is itself a run directory, so every tool that reads a run reads a record (`experiments figure
--runs-dir benchmarks/results/records`, `evaluate --ckpt`, `render --ckpt`). It holds:

* `config.json`, as the run wrote it;
* `metrics.jsonl.gz`, the metrics gzipped (`rundir.read_metrics` reads it);
* `policy/<iteration>/`, the final policy exactly as `policy_io` exported it (params only);
* `checkpoints/<iteration>/`, only where a follow-up branches from it (`pack`'s `checkpoint_reason`, which
  the provenance keeps): the final checkpoint (params, optimiser state and stage), so that a later sitting
  can branch from the record (`train --init-from RECORD`), e.g. the follow-ups of a design's learners that
  learned (about 1.5 MB at the laptop scale);
* `eval/*.json`, the evaluations after training (`rundir.EVAL_DIR`);
* `provenance.json`: how the run was made (`run`: the exact command, git commit, device, jax version, start
  date, exit status, as given to `pack`; from a run's process file also whether the package's files were the
  commit's, the CPU, visible cores and package versions) and how the record was made (`record`: source, date,
  packing commit and whether the package's files were its);
* `tree-<sha256 prefix>.diff`, where the run trained from a dirty tree: the diff its provenance names
  (`tree_diff`, `tree_diff_sha256`), which `git apply` applies to a checkout of its commit to rebuild the code
  it ran (`jaxsocial.run.checkout`).

Records mirror the run directories: `<runs_dir>/<scale>/<run>/s<seed>/` packs to
`<records_dir>/<scale>/<run>/s<seed>/`.
"""

from __future__ import annotations

import datetime
import gzip
import hashlib
import json
import re
import shutil
from pathlib import Path
from typing import Any

from jaxsocial.run import checkout, jsonio, metrics, provenance, rundir

PROVENANCE_FILE = "provenance.json"
ORBAX_COMMIT_NOTE = "commit_success.txt"
"""The file orbax writes into each saved item naming the absolute path it went to (reading needs none)."""


def read_provenance(seed_dir: str | Path) -> dict[str, Any] | None:
    """The `provenance.json` of a seed's directory, or of the run directory holding it (None if neither)."""
    for where in (Path(seed_dir), Path(seed_dir).parent):
        if (where / PROVENANCE_FILE).is_file():
            return jsonio.read_json(where / PROVENANCE_FILE)
    return None


def run_field(seed_dir: str | Path, key: str, process_file: bool = False) -> Any:
    """One field of the `run` part of a seed's record provenance (None without a record, or without it); with
    `process_file`, a run directory that is no record answers from its process file (`provenance.RUN_FILE`,
    which holds the same fields of the last process that trained it)."""
    recorded = read_provenance(seed_dir)
    if recorded is None and process_file:
        return (read_process_file(seed_dir) or {}).get(key)
    return ((recorded or {}).get("run") or {}).get(key)


def read_process_file(seed_dir: str | Path) -> dict[str, Any] | None:
    """The process file of a seed's run directory (the seed's directory or the run's holding it; None if
    neither has one)."""
    for where in (Path(seed_dir), Path(seed_dir).parent):
        if (where / provenance.RUN_FILE).is_file():
            return jsonio.read_json(where / provenance.RUN_FILE)
    return None


def processes(run: dict[str, Any]) -> list[dict[str, Any]]:
    """The processes a run's provenance describes: its last, then those before it (`earlier`, if resumed)."""
    return [run, *run.get("earlier", [])]


def dirty_diffs(run: dict[str, Any]) -> list[str]:
    """The diff files named by the run's processes that trained from a dirty tree ([] if none did)."""
    return [process.get("tree_diff") or "no diff" for process in processes(run) if process.get("dirty")]


def tree_diffs(seed_dir: str | Path, run: dict[str, Any]) -> list[Path]:
    """The diff files a run's provenance names (its `tree_diff` and its earlier processes'), where its process
    file is (the seed's directory or the run's holding it): ValueError if one is missing or its sha256 is not
    the one recorded."""
    found = []
    for process in processes(run):
        name, sha256 = process.get("tree_diff"), process.get("tree_diff_sha256")
        if not name:
            continue
        paths = [
            where / name for where in (Path(seed_dir), Path(seed_dir).parent) if (where / name).is_file()
        ]
        if not paths:
            raise ValueError(f"{seed_dir}: its run trained from a dirty tree, and its diff {name} is missing")
        if hashlib.sha256(paths[0].read_bytes()).hexdigest() != sha256:
            raise ValueError(f"{paths[0]}: its sha256 is not the {sha256} its run recorded")
        found.append(paths[0])
    return found


def read_commands_log(path: str | Path) -> dict[str, dict[str, Any]]:
    """The training commands of a commands log, by the run name their `--run-name` gives.

    A line `<ISO date> <40-hex commit> <command>` starts a run; a later line
    `<ISO date> done <condition> rc=<k> [<seconds>s]` ends the last started run of that condition (whose run
    name is `<scale>/<condition>-s<first>-<last>`); a line `<ISO date> machine <JSON object>` says where the
    runs started after it train (`provenance.machine`: CPU, $XLA_FLAGS, instruction sets, versions). Returns
    {run name: {'command', 'commit', 'started', 'ended', 'rc', 'machine'}} ('machine' {} where no line said
    it); a run started twice keeps its last start (a resumed run continues its directory)."""
    runs: dict[str, dict[str, Any]] = {}
    machine: dict[str, Any] = {}
    for line in Path(path).read_text().splitlines():
        parts = line.split()
        if len(parts) < 3:
            continue
        date, second, rest = parts[0], parts[1], line.split(maxsplit=2)[2]
        if second == "machine":
            machine = json.loads(rest)
        elif re.fullmatch(r"[0-9a-f]{40}", second):
            name = re.search(r"--run-name[ =](\S+)", rest)
            if name:
                runs.pop(name[1], None)  # re-inserted last: the latest start
                runs[name[1]] = {
                    "command": rest,
                    "commit": second,
                    "started": date,
                    "ended": None,
                    "rc": None,
                    "machine": machine,
                }
        elif second == "done" and len(parts) >= 4 and parts[3].startswith("rc="):
            started = [
                n for n in runs if Path(n).name.startswith(f"{parts[2]}-s") and runs[n]["ended"] is None
            ]
            if started:
                runs[started[-1]].update(ended=date, rc=int(parts[3].removeprefix("rc=")))
    return runs


def logged_provenance(
    run_name: str, commands: dict[str, dict[str, Any]], device: str | None, jax_version: str | None
) -> dict[str, Any]:
    """The `run` part of a record's provenance: the commands log's entry for `run_name` (its `--run-name`)
    with the device and jax version it ran on, and the machine its last start logged. ValueError if the log
    has no such run, or it failed (`ended_well`)."""
    if run_name not in commands:
        raise ValueError(f"the commands log has no command with --run-name {run_name}")
    entry = {
        **dict.fromkeys(provenance.RUN_FIELDS),
        **commands[run_name],
        "device": device,
        "jax": jax_version,
    }
    ended_well(entry, f"{run_name} in the commands log")
    return {k: entry[k] for k in provenance.RUN_FIELDS} | entry.get("machine", {})


def ended_well(run: dict[str, Any], where: str | Path) -> None:
    """ValueError if the process of `run` (a run's provenance, or its process file) exited with an error: a
    failed run is not a result to record. Every record's provenance passes here (`pinned.run_provenance`,
    `logged_provenance`)."""
    if run.get("rc") not in (None, 0):
        raise ValueError(f"{where}: its process exited with {run['rc']}; not a result to record")


def checkpoint_reason(which: str | None, final: float, threshold: float) -> str | None:
    """Why a seed's record keeps its final checkpoint (`which`, as `record --final-checkpoint` says:
    'learned', 'all', or None: never), given its final return `final` and the learned threshold; None when it
    keeps none."""
    branch = "later sittings branch from it (train --init-from RECORD)"
    if which == "all":
        return f"every seed's was asked for (--final-checkpoint all): {branch}"
    if which == "learned" and final > threshold:
        learned = f"the seed learned (final return {final:.2f} > {threshold:g})"
        return f"{learned}: follow-ups of learned seeds {branch}"
    return None


def pack(
    seed_dir: str | Path,
    record_dir: str | Path,
    run: dict[str, Any],
    source: str,
    overwrite: bool = False,
    checkpoint_reason: str | None = None,
) -> Path:
    """Pack one seed's run directory into the record `record_dir` (see the module docstring); `run` is the
    run's provenance (`provenance.RUN_FIELDS`), `source` the seed's name under its runs root (e.g.
    'cpu/RUN/s0'); with a `checkpoint_reason` (why a follow-up branches from it; the provenance keeps it) the
    checkpoint of the final policy's iteration goes in too. Checks everything before writing (`packable`;
    FileExistsError if the record exists, unless `overwrite`; ValueError if a diff the run names is missing
    or altered: `tree_diffs`, which go in too). Returns it."""
    seed_dir, record_dir = Path(seed_dir), Path(record_dir)
    final_checkpoint = checkpoint_reason is not None
    iteration, rows = packable(seed_dir, final_checkpoint)
    diffs, tree = tree_diffs(seed_dir, run), checkout.tree()
    planned = rundir.read_config(seed_dir)["iterations"]
    if record_dir.exists() and any(record_dir.iterdir()):
        if not overwrite:
            raise FileExistsError(f"record {record_dir} exists; pass --overwrite to replace it")
        shutil.rmtree(record_dir)
    record_dir.mkdir(parents=True, exist_ok=True)
    shutil.copy2(seed_dir / rundir.CONFIG_FILE, record_dir / rundir.CONFIG_FILE)
    if (seed_dir / rundir.METRICS_FILE).is_file():
        text = "".join(
            line + "\n" for line in (seed_dir / rundir.METRICS_FILE).read_text().splitlines() if line
        )
        (record_dir / rundir.METRICS_GZ_FILE).write_bytes(gzip.compress(text.encode(), mtime=0))
    else:  # a record packed again
        shutil.copy2(seed_dir / rundir.METRICS_GZ_FILE, record_dir / rundir.METRICS_GZ_FILE)
    kept = [rundir.POLICY_DIR] + ([rundir.CHECKPOINTS_DIR] if final_checkpoint else [])
    for directory in kept:  # without orbax's commit notes, which name the absolute path it was written to
        shutil.copytree(
            seed_dir / directory / str(iteration),
            record_dir / directory / str(iteration),
            ignore=shutil.ignore_patterns(ORBAX_COMMIT_NOTE),
        )
    if (seed_dir / rundir.EVAL_DIR).is_dir():
        shutil.copytree(seed_dir / rundir.EVAL_DIR, record_dir / rundir.EVAL_DIR)
    for diff in diffs:
        shutil.copy2(diff, record_dir / diff.name)
    recorded = {
        "run": run,
        "record": {
            "source": source,
            "iterations": len(rows),
            "stopped_early": len(rows) < planned,
            "policy_iteration": iteration,
            "checkpoint_iteration": iteration if final_checkpoint else None,
            "checkpoint_reason": checkpoint_reason,
            "packed": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "packed_at_commit": tree.commit,
            "packed_dirty": tree.dirty,
            "packed_with_jax": provenance.package_version("jax"),
        },
    }
    jsonio.write_json(record_dir / PROVENANCE_FILE, recorded)
    return record_dir


def packable(seed_dir: str | Path, final_checkpoint: bool = False) -> tuple[int, list[dict[str, Any]]]:
    """The final policy's iteration and the metrics rows of a seed's run directory that `pack` can pack:
    FileNotFoundError if it has no config, metrics or policy (or, with `final_checkpoint`, no checkpoint of
    that iteration), ValueError if it is unfinished (neither every iteration logged nor stopped early)."""
    from jaxsocial.run import checkpoint  # orbax and JAX: imported by packing, not by reading a record

    seed_dir = Path(seed_dir)
    if not (seed_dir / rundir.CONFIG_FILE).is_file() or not rundir.has_metrics(seed_dir):
        raise FileNotFoundError(f"{seed_dir} is not a finished seed run directory (no config or metrics)")
    policy_dir = seed_dir / rundir.POLICY_DIR
    iteration = checkpoint.latest_step(policy_dir)
    if iteration is None:
        raise FileNotFoundError(f"{seed_dir} has no exported policy under {policy_dir}")
    rows = rundir.read_metrics(seed_dir)
    config = rundir.read_config(seed_dir)
    if len(rows) < config["iterations"] and not (stopped_early(config, rows) and iteration == len(rows)):
        raise ValueError(f"{seed_dir} is unfinished: {len(rows)} of {config['iterations']} iterations logged")
    if final_checkpoint:
        require_checkpoint(seed_dir, iteration)
    return iteration, rows


def require_checkpoint(seed_dir: str | Path, iteration: int) -> None:
    """FileNotFoundError unless the seed's run directory (or record) holds the checkpoint of `iteration`."""
    from jaxsocial.run import checkpoint

    if iteration not in checkpoint.all_steps(rundir.checkpoints(seed_dir)):
        raise FileNotFoundError(f"{seed_dir} has no checkpoint of its final iteration {iteration}")


def stopped_early(config: dict[str, Any], rows: list[dict[str, Any]]) -> bool:
    """Whether a run's metrics end where its `stop_at_return` stopped it: the learners' mean return over its
    last chunk's rows reached the threshold."""
    threshold = config.get("stop_at_return")
    if threshold is None or not rows:
        return False
    last = rows[-config.get("chunk_iterations", 1) :]
    per_learner = [metrics.slot_returns(last, s) for s in metrics.learners(rows[-1])]
    total = sum(returns.sum() for returns, _ in per_learner)
    episodes = sum(counts.sum() for _, counts in per_learner)
    return episodes > 0 and total / episodes >= threshold


def size_bytes(directory: str | Path) -> int:
    """Total size of the files under `directory`."""
    return sum(p.stat().st_size for p in Path(directory).rglob("*") if p.is_file())
