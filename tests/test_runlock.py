"""One process at a time per run directory: a live run's lock refuses `train`, `--resume` and `--overwrite`
(naming the holder) before anything is deleted or written; a killed run's lock is stale and taken over."""

import fcntl
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest
from conftest import TINY_RUN_FLAGS

from jaxsocial import train
from jaxsocial.run import checkpoint, rundir
from jaxsocial.run.runlock import FLOCK_WAIT_S, RunLock, RunLockedError, lock_path

HOLDER = f"process {os.getpid()} on host {socket.gethostname()}"


def test_a_held_lock_refuses_another_holder_until_released(tmp_path):
    run_dir = tmp_path / "run"
    with RunLock(run_dir):
        with pytest.raises(RunLockedError, match=f"{run_dir} is in use by {HOLDER}"):
            RunLock(run_dir).acquire()
        assert json.loads(lock_path(run_dir).read_text())["pid"] == os.getpid()
    assert not lock_path(run_dir).exists()
    with RunLock(run_dir):  # free again
        pass


def test_a_stale_lock_is_taken_over_with_a_warning(tmp_path, capsys):
    run_dir = tmp_path / "run"
    record = {"pid": 2**22 + 1, "host": "gone", "started": time.time() - 60}  # what a killed holder leaves
    lock_path(run_dir).write_text(json.dumps(record))
    with RunLock(run_dir):
        assert json.loads(lock_path(run_dir).read_text())["pid"] == os.getpid()
    err = capsys.readouterr().err
    assert f"taking over the lock of {run_dir} left by process {2**22 + 1} on host gone" in err


def test_live_holder_asks_the_flock_and_a_look_does_not_refuse_a_run(tmp_path):
    """`live_holder` names the holder where a process holds the lock's flock, and no one where none does,
    whatever the file names (a pid alive here, another host); a look holds a shared flock for an instant,
    which `acquire` waits out instead of refusing."""
    run_dir = tmp_path / "run"
    assert RunLock(run_dir).live_holder() is None  # no lock file
    with RunLock(run_dir):
        assert RunLock(run_dir).live_holder()["pid"] == os.getpid()
        with pytest.raises(RunLockedError):  # still held after the look
            RunLock(run_dir).acquire()
    for host in (socket.gethostname(), "another-host"):  # left by a holder whose flock is gone
        lock_path(run_dir).write_text(json.dumps({"pid": os.getpid(), "host": host, "started": time.time()}))
        assert RunLock(run_dir).live_holder() is None
    with open(lock_path(run_dir)) as look:
        fcntl.flock(look, fcntl.LOCK_SH)  # a look, from another process, at the moment a run starts
        threading.Timer(FLOCK_WAIT_S, fcntl.flock, (look, fcntl.LOCK_UN)).start()
        with RunLock(run_dir):
            assert json.loads(lock_path(run_dir).read_text())["pid"] == os.getpid()


@pytest.mark.parametrize("mode", [["--overwrite"], ["--resume"], []])
def test_train_on_a_locked_run_directory_is_refused_before_touching_it(tmp_path, mode):
    run_dir = tmp_path / "x"
    run_dir.mkdir()
    (run_dir / rundir.METRICS_FILE).write_text('{"iteration": 1}\n')
    with RunLock(run_dir), pytest.raises(SystemExit) as exc:
        train.main([*TINY_RUN_FLAGS, "--runs-dir", str(tmp_path), "--run-name", "x", *mode])
    assert str(exc.value).startswith(f"error: run directory {run_dir} is in use by {HOLDER}"), exc.value
    assert [p.name for p in run_dir.iterdir()] == [rundir.METRICS_FILE]
    assert (run_dir / rundir.METRICS_FILE).read_text() == '{"iteration": 1}\n'


@pytest.mark.slow  # a training subprocess, killed, then resumed here
def test_overwrite_during_a_run_is_refused_and_a_killed_run_resumes(tmp_path, capsys):
    """Start a long run; `--overwrite` and `--resume` while it trains are refused and leave it training;
    after kill -9 its lock is stale: `--resume` takes it over and continues from the last checkpoint."""
    run_dir = tmp_path / "live"
    cache = Path(tempfile.gettempdir()) / "jaxsocial-tests-xla-cache"  # the suite's (conftest.py)
    flags = [*TINY_RUN_FLAGS, "--runs-dir", str(tmp_path), "--run-name", "live"]
    cmd = [
        sys.executable,
        "-m",
        "jaxsocial.train",
        *flags,
        "--iterations",
        "100000",
        "--compile-cache",
        str(cache),
    ]
    live = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while not checkpoint.all_steps(run_dir / "checkpoints"):
            assert live.poll() is None, live.stderr.read()
            assert time.monotonic() < deadline, "the run wrote no checkpoint in 240 s"
            time.sleep(0.5)
        for mode in (["--overwrite"], ["--resume"]):
            with pytest.raises(SystemExit, match=f"is in use by process {live.pid} on host"):
                train.main([*flags, *mode])
        assert live.poll() is None and (run_dir / rundir.CONFIG_FILE).is_file()
    finally:
        live.send_signal(signal.SIGKILL)
        live.wait()
    steps = checkpoint.all_steps(run_dir / "checkpoints")
    assert steps and lock_path(run_dir).exists()  # the killed run left its lock
    total = steps[-1] + 2
    train.main([*flags, "--resume", "--iterations", str(total)])
    assert "taking over the lock" in capsys.readouterr().err
    assert [r["iteration"] for r in rundir.read_metrics(run_dir)] == list(range(1, total + 1))
    assert checkpoint.latest_step(run_dir / "checkpoints") == total and not lock_path(run_dir).exists()
