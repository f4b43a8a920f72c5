"""The resume state kept in git for a design's unfinished runs: slimmed to the latest checkpoint every seed
has (no policies), packed deterministically, unpacked elsewhere and resumed, it trains on exactly as the
uninterrupted run."""

import dataclasses
import subprocess
import tarfile
from pathlib import Path

from conftest import TINY, needs_records

from jaxsocial import train
from jaxsocial.experiments.launch import inflight, verify
from jaxsocial.run import rundir


def test_a_packed_state_resumes_exactly(tmp_path, two_seed_run):
    """Two seeds vmapped in one program, as on a GPU: half the run, packed as a device block leaves it, then
    unpacked and resumed, equals the whole run (`two_seed_run`, the same program, which the tiny-runs group
    trains once)."""
    two_seeds = dataclasses.replace(TINY, run_name="run", seeds=2, seed_batching="vmap")
    half = train.run(dataclasses.replace(two_seeds, runs_dir=str(tmp_path / "b"), iterations=2))
    progress = "run (2 seeds)  2/4 [ 50%] 0.5 it/s env-steps/s=64 return[0 learner]=0.25 eta 0:00:04\n"
    (half / "device-20261127T122903.log").write_text(progress)  # as a device block leaves its log
    device = tmp_path / "device.tgz"  # what a device block brings back: the runs under their tree
    with tarfile.open(device, "w:gz") as tar:
        tar.add(half.parent, arcname="runs")
    (state,) = inflight.slim_states([device], tmp_path / "state")
    assert state.name == "run.tgz"
    assert not progress_logs(state)  # blind: no progress line with returns in git
    again = tmp_path / "again.tgz"
    inflight.pack_state(*inflight.unpack_state(state, tmp_path / "check"), again)
    assert again.read_bytes() == state.read_bytes()  # deterministic: the same files, the same bytes
    (resumed,) = inflight.unpack_state(state, tmp_path / "next")
    assert not list(resumed.rglob("policy"))  # policies are left out: a resumed run exports its own
    train.run(dataclasses.replace(two_seeds, runs_dir=str(resumed.parent), resume=True))
    for seed in ("s0", "s1"):
        rows, expected = rundir.read_metrics(resumed / seed), rundir.read_metrics(two_seed_run / seed)
        assert len(rows) == 4 and verify.first_difference(expected, rows) is None


def progress_logs(tgz: Path) -> list[str]:
    """The members of a packed state that are progress logs, or hold a progress line's return."""
    with tarfile.open(tgz) as tar:
        return [
            m.name
            for m in tar.getmembers()
            if Path(m.name).match(inflight.PROGRESS_LOGS)
            or (m.isfile() and not m.name.endswith(".jsonl") and b"return[" in tar.extractfile(m).read())
        ]


@needs_records("inflight")
def test_the_committed_states_hold_no_progress_log():
    states = sorted((Path(__file__).parents[1] / "benchmarks/results/inflight").glob("*/state/*.tgz"))
    assert states and {str(s): progress_logs(s) for s in states} == {str(s): [] for s in states}


def test_a_blocks_progress_output_is_blind():
    """What a GPU block prints and commits of its runs' progress (`prereg_gpu_block.sh blind`): iterations
    and speed, no return, while the design runs."""
    lines = [
        "gpu/social_rec-s100-103 (4 seeds): compiling the 10-iteration chunk (stage -1) ...",
        "gpu/social_rec-s100-103 (4 seeds)  110/1920 [  6%] 0.406 it/s env-steps/s=211,003 "
        "return[0 learner]=0.529 return[1 explorer]=38.9 return[2 explorer]=38.9  eta 1:14:23",
        "final return (last 10% of the iterations): learner 0.5289",
    ]
    script = Path(__file__).parents[1] / "benchmarks" / "prereg_gpu_block.sh"
    out = subprocess.run(["bash", script, "blind"], input="\n".join(lines) + "\n", capture_output=True,
                         text=True, check=True).stdout  # fmt: skip
    assert out.splitlines() == [
        lines[0],
        "gpu/social_rec-s100-103 (4 seeds)  110/1920 [  6%] 0.406 it/s env-steps/s=211,003  eta 1:14:23",
    ]
