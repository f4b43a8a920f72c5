"""Tests of jaxsocial.run.rundir and jsonio (run dir policies, config, JSONL metrics) and of loggers (progress
line, optional loggers)."""

import io
import json
import sys

import jax.numpy as jnp
import numpy as np
import pytest

from jaxsocial.run import loggers, rundir


def test_run_dir_policies(tmp_path):
    run = rundir.prepare_run_dir(tmp_path, "exp1")
    assert run == tmp_path / "exp1" and run.is_dir()
    assert rundir.prepare_run_dir(tmp_path, "exp1") == run  # empty: fine
    (run / "marker").write_text("x")

    with pytest.raises(FileExistsError, match="--resume.*--overwrite"):
        rundir.prepare_run_dir(tmp_path, "exp1")
    assert rundir.prepare_run_dir(tmp_path, "exp1", resume=True) == run and (run / "marker").exists()
    assert rundir.prepare_run_dir(tmp_path, "exp1", overwrite=True) == run and not any(run.iterdir())
    with pytest.raises(ValueError, match="at most one"):
        rundir.prepare_run_dir(tmp_path, "exp1", resume=True, overwrite=True)
    with pytest.raises(FileNotFoundError, match="cannot resume"):
        rundir.prepare_run_dir(tmp_path, "nope", resume=True)
    with pytest.raises(ValueError):
        rundir.prepare_run_dir(tmp_path, "..", overwrite=True)


def test_config_write_read_diff(tmp_path):
    config = {"seed": 0, "agent": {"lr": np.float32(0.5), "layers": (64, 64)}, "env": "goal_cycle"}
    path = rundir.write_config(tmp_path, config)
    text = path.read_text()
    assert text.index('"agent"') < text.index('"env"') < text.index('"seed"') and '\n  "agent"' in text
    loaded = rundir.read_config(tmp_path)
    assert loaded == {"seed": 0, "agent": {"lr": 0.5, "layers": [64, 64]}, "env": "goal_cycle"}
    assert rundir.config_diff(loaded, config) == []
    changed = {"seed": 1, "agent": {"lr": 0.5, "layers": [64, 64], "clip": 0.2}, "env": "goal_cycle"}
    assert rundir.config_diff(loaded, changed) == ["agent.clip", "seed"]
    with pytest.raises(FileNotFoundError):
        rundir.read_config(tmp_path / "missing")


def test_metrics_append_read_truncate(tmp_path):
    log = rundir.MetricsLog(tmp_path)
    assert rundir.read_metrics(tmp_path) == []
    log.append(
        {"iteration": np.int32(i), "return": np.float32(i / 2), "per_agent": jnp.array([i, 2 * i])}
        for i in range(1, 4)
    )
    log.append([{"iteration": 4, "loss": float("nan"), "kl": np.float64(np.inf), "ok": np.bool_(True)}])
    rows = rundir.read_metrics(tmp_path)
    assert rows[0] == {"iteration": 1, "return": 0.5, "per_agent": [1, 2]}
    assert rows[3] == {"iteration": 4, "loss": None, "kl": None, "ok": True}
    assert all(json.loads(line) for line in (tmp_path / "metrics.jsonl").read_text().splitlines())

    assert log.truncate_after(2) == 2
    assert [r["iteration"] for r in rundir.read_metrics(tmp_path)] == [1, 2]

    with open(log.path, "a") as f:  # a crash left a partial line
        f.write('{"iteration": 3, "ret')
    with pytest.warns(UserWarning, match="truncated"):
        assert len(log.read()) == 2
    log.append([{"iteration": 3}])
    with pytest.warns(UserWarning):
        assert [r["iteration"] for r in log.read()] == [1, 2, 3]
    with pytest.raises(TypeError):
        log.append([{"iteration": object()}])


def test_gzipped_metrics_read_like_plain_ones(tmp_path):
    """A record's metrics.jsonl.gz reads as the metrics.jsonl it was packed from; a plain file wins."""
    import gzip

    rows = [{"iteration": 1, "return/0": 0.5}, {"iteration": 2, "return/0": None}]
    assert not rundir.has_metrics(tmp_path)
    text = "".join(json.dumps(r) + "\n" for r in rows)
    (tmp_path / rundir.METRICS_GZ_FILE).write_bytes(gzip.compress(text.encode()))
    assert rundir.read_metrics(tmp_path) == rows and rundir.has_metrics(tmp_path)
    rundir.MetricsLog(tmp_path).append(rows[:1])
    assert rundir.read_metrics(tmp_path) == rows[:1]


def test_progress_non_tty(capsys):
    progress = loggers.Progress(200, "train", unit="env-steps", unit_scale=1000, interval=3600.0)
    progress.update(40, **{"return[0]": np.float32(1.23456), "frames": 1234567, "ok": True})
    progress.update(80, loss=0.5)  # within the interval: not printed
    progress.close()  # prints the last state
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("train  40/200 [ 20%]")
    assert "env-steps/s" in lines[0] and "return[0]=1.23" in lines[0] and "frames=1,234,567" in lines[0]
    assert "ok=True" in lines[0] and "eta " in lines[0]
    assert "80/200" in lines[1] and "loss=0.5" in lines[1]

    with loggers.Progress(3, interval=3600.0) as progress:
        for i in range(1, 4):
            progress.update(i, x=i)
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 and "3/3" in lines[1] and "elapsed" in lines[1]  # first and final update


def test_progress_rate_leaves_out_excluded_time(monkeypatch):
    clock = [100.0]
    monkeypatch.setattr(loggers.time, "monotonic", lambda: clock[0])
    progress = loggers.Progress(100, unit="it", stream=io.StringIO())
    clock[0] += 30.0  # 10 units in 10 s of training and 20 s of compiling
    progress.exclude(20.0)
    line = progress.format(10, {})
    assert "1 it/s" in line and "eta 0:01:30" in line  # 90 units left at 1 unit/s


def test_progress_tty():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    stream = Tty()
    progress = loggers.Progress(10, "eval", stream=stream)
    progress.update(5, score=1 / 3)
    progress.update(10)
    progress.close()
    out = stream.getvalue()
    assert out.count("\r") == 2 and out.endswith("\n") and "score=0.333" in out and "10/10" in out


def test_make_logger(tmp_path, monkeypatch):
    logger = loggers.make_logger(None, tmp_path, {})
    logger.log({"a": 1.0}, step=0)
    logger.close()
    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # makes the import fail
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(ImportError, match="pip install tensorboardX"):
        loggers.make_logger("tensorboard", tmp_path, {})
    monkeypatch.setitem(sys.modules, "wandb", None)
    with pytest.raises(ImportError, match="pip install wandb"):
        loggers.make_logger("wandb", tmp_path, {})
    with pytest.raises(ValueError, match="unknown logger"):
        loggers.make_logger("mlflow", tmp_path, {})
