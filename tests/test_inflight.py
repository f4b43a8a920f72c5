"""The resume state kept in git for a design's unfinished runs: slimmed to the latest checkpoint every seed
has (no policies), packed deterministically, unpacked elsewhere and resumed, it trains on exactly as the
uninterrupted run."""

import dataclasses
import tarfile

from conftest import TINY

from jaxsocial import train
from jaxsocial.experiments import inflight, verify
from jaxsocial.run import metrics


def test_a_packed_state_resumes_exactly(tmp_path):
    whole = train.run(dataclasses.replace(TINY, runs_dir=str(tmp_path / "a"), run_name="run", seeds=2,
                                          iterations=4, checkpoint_every=2))  # fmt: skip
    half = train.run(dataclasses.replace(TINY, runs_dir=str(tmp_path / "b"), run_name="run", seeds=2,
                                         iterations=2, checkpoint_every=2))  # fmt: skip
    device = tmp_path / "device.tgz"  # what a device block brings back: the runs under their tree
    with tarfile.open(device, "w:gz") as tar:
        tar.add(half.parent, arcname="runs")
    (state,) = inflight.slim_states([device], tmp_path / "state")
    assert state.name == "run.tgz"
    again = tmp_path / "again.tgz"
    inflight.pack(*inflight.unpack(state, tmp_path / "check"), again)
    assert again.read_bytes() == state.read_bytes()  # deterministic: the same files, the same bytes
    (resumed,) = inflight.unpack(state, tmp_path / "next")
    assert not list(resumed.rglob("policy"))  # policies are left out: a resumed run exports its own
    train.run(dataclasses.replace(TINY, runs_dir=str(resumed.parent), run_name="run", seeds=2, iterations=4,
                                  checkpoint_every=2, resume=True))  # fmt: skip
    for seed in ("s0", "s1"):
        rows, expected = metrics.read_rows(resumed / seed), metrics.read_rows(whole / seed)
        assert len(rows) == 4 and verify.first_difference(expected, rows) is None
