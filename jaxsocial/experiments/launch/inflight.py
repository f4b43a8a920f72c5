"""The resume state of a design's runs that have not finished (a GPU design's blocks), kept in git so that the
next lent GPU can continue them from any workspace.

A run's state is its directory with only the latest checkpoint every seed has, no exported policy (a
resumed run exports the policy of the checkpoint it restores) and no progress log (`PROGRESS_LOGS`: a
device block's raw log of a run prints its returns, which a design's committed files keep unread until it
is complete; the block's script commits them blinded beside the state), packed as one deterministic .tgz
per run (`pack_state`: sorted members, no times or owners). `benchmarks/prereg_gpu_block.sh collect` slims the
state a device block brings back into `benchmarks/results/inflight/<design>-gpu/state/`, replacing the copy
there, so the tree holds one state per run:

    python -m jaxsocial.experiments inflight STATE.tgz ... --out benchmarks/results/inflight/DESIGN-gpu/state
"""

from __future__ import annotations

import argparse
import gzip
import io
import shutil
import tarfile
import tempfile
from pathlib import Path

from jaxsocial.run import jsonio, rundir
from jaxsocial.run.rundir import CHECKPOINTS_DIR as CHECKPOINTS
from jaxsocial.run.rundir import POLICY_DIR

PROGRESS_LOGS = "device-*.log"
"""The raw training logs a device block leaves in a run directory (benchmarks/prereg_gpu_block.sh), one per
block: progress lines with the learners' returns. Resuming needs none of them."""


def slim(run_dir: Path) -> int:
    """Keep only the latest checkpoint every seed of `run_dir` has, drop the exported policies and the
    `PROGRESS_LOGS`; returns that checkpoint's step (ValueError if the seeds share none)."""
    from jaxsocial.run import checkpoint  # orbax and JAX: imported to slim, not by a refusal

    seeds = rundir.written_seed_dirs(run_dir)
    common = set.intersection(*(set(checkpoint.all_steps(d / CHECKPOINTS)) for d in seeds))
    if not common:
        raise ValueError(f"{run_dir}: its seeds share no checkpoint to resume from")
    keep = max(common)
    for d in seeds:
        for step_dir in (d / CHECKPOINTS).iterdir():
            if step_dir.name != str(keep):
                shutil.rmtree(step_dir) if step_dir.is_dir() else step_dir.unlink()
        shutil.rmtree(d / POLICY_DIR, ignore_errors=True)
    for log in run_dir.glob(PROGRESS_LOGS):
        log.unlink()
    return keep


def pack_state(run_dir: Path, out: Path) -> None:
    """`run_dir` as a .tgz at `out` whose bytes depend only on the files (members `<run name>/...`, sorted,
    with no times, owners or modes beyond the file/directory distinction)."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for path in sorted([run_dir, *run_dir.rglob("*")]):
            info = tar.gettarinfo(path, arcname=str(path.relative_to(run_dir.parent)))
            info.mtime, info.uid, info.gid, info.uname, info.gname = 0, 0, 0, "", ""
            info.mode = 0o755 if path.is_dir() else 0o644
            if path.is_file():
                with path.open("rb") as f:
                    tar.addfile(info, f)
            else:
                tar.addfile(info)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(gzip.compress(buffer.getvalue(), compresslevel=9, mtime=0))


def unpack_state(tgz: Path, dest: Path) -> list[Path]:
    """Extract a packed state into `dest`; returns the run directories it held."""
    with tarfile.open(tgz) as tar:
        tar.extractall(dest, filter="data")
        tops = sorted({Path(m.name).parts[0] for m in tar.getmembers()})
    return [dest / t for t in tops]


def slim_states(tgzs: list[Path], out_dir: Path) -> list[Path]:
    """Every run directory inside the device's state archives `tgzs` (any depth), slimmed and packed into
    `out_dir/<run>.tgz`, which is emptied first (one copy, replaced). Returns the written files."""
    written = []
    with tempfile.TemporaryDirectory(prefix="jaxsocial-state-") as tmp:
        runs = []
        for tgz in tgzs:
            with tarfile.open(tgz) as tar:
                tar.extractall(tmp, filter="data")
        for config in sorted(Path(tmp).rglob(rundir.CONFIG_FILE)):
            if not rundir.one_seed_of_many(jsonio.read_json(config)):
                runs.append(config.parent)
        if out_dir.exists():
            shutil.rmtree(out_dir)
        for run in runs:
            step = slim(run)
            pack_state(run, out_dir / f"{run.name}.tgz")
            written.append(out_dir / f"{run.name}.tgz")
            print(f"{run.name}: state at iteration {step}, {written[-1].stat().st_size / 2**20:.1f} MiB")
    return written


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m jaxsocial.experiments inflight", description=__doc__)
    parser.add_argument("tgz", nargs="+", type=Path, help="the device block's state archives")
    parser.add_argument("--out", type=Path, required=True, help="where the slim states go (replaced)")
    args = parser.parse_args(argv)
    missing = [str(t) for t in args.tgz if not t.is_file()]
    if missing:
        parser.error(f"no such archive: {', '.join(missing)}")
    slim_states(args.tgz, args.out)
