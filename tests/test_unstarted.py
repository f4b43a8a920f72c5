"""A run directory that holds no completed iteration (issue 84): the directory an interrupted or killed run
left before its first iteration does not block the command that made it, while one that holds another run's
config, metrics rows, a checkpoint or a policy is refused as before, before the cost line, with nothing
changed (and before JAX is imported: `test_refusals`)."""

import dataclasses
import json

import pytest
from conftest import TINY, TINY_FLAGS

from jaxsocial import train
from jaxsocial.run import config, driver, rundir, unstarted


def interrupted(monkeypatch, fn, arg, raises=KeyboardInterrupt) -> pytest.ExceptionInfo:
    """`fn(arg)` (`train.run` or `train.main`) interrupted by Ctrl-C where its driver starts, before its
    first iteration: what it raised."""

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch, pytest.raises(raises) as exc:
        patch.setattr(driver, "train_chunks", interrupt)
        fn(arg)
    return exc


def interrupted_run(cfg, monkeypatch) -> None:
    """`train.run(cfg)` interrupted before its first iteration."""
    interrupted(monkeypatch, train.run, cfg)


@pytest.fixture
def trained(monkeypatch):
    """Replace the training loop with one that records the configs it was called with (nothing compiles)."""
    calls = []
    monkeypatch.setattr(driver, "train_chunks", lambda cfg, *args: calls.append(cfg))
    return calls


def test_the_same_command_starts_again_where_a_run_was_interrupted_before_its_first_iteration(
    tmp_path, monkeypatch, capsys, trained
):
    cfg = dataclasses.replace(TINY, runs_dir=str(tmp_path), run_name="x")
    interrupted_run(cfg, monkeypatch)
    run_dir = tmp_path / "x"
    assert rundir.read_config(run_dir) == config.config_dict(cfg)
    assert json.loads((run_dir / "process.json").read_text())["rc"] == 130
    assert unstarted.leftovers(run_dir, [""]) == []
    capsys.readouterr()
    assert train.run(cfg) == run_dir
    assert trained == [cfg]
    assert "holds only what a run of this config wrote before its first iteration" in capsys.readouterr().out
    assert json.loads((run_dir / "process.json").read_text())["rc"] == 0  # the new process's, alone
    assert "earlier" not in json.loads((run_dir / "process.json").read_text())


def test_ctrl_c_says_the_same_command_starts_again_and_another_config_is_refused_before_the_cost_line(
    tmp_path, monkeypatch, capsys
):
    argv = [*TINY_FLAGS, "--runs-dir", str(tmp_path), "--run-name", "x"]
    assert interrupted(monkeypatch, train.main, argv, SystemExit).value.code == 130
    said = capsys.readouterr().err
    assert (
        f"interrupted; {tmp_path / 'x'} holds no completed iteration, so the same command starts it again"
        in said
    )
    written = (tmp_path / "x" / "config.json").read_text()
    with pytest.raises(SystemExit) as exc:
        train.main([*argv, "--iterations", "3"])
    assert "holds no completed iteration, but it is another run's" in str(exc.value)
    assert "differs in ['iterations']; pass --overwrite" in str(exc.value)
    assert "cost:" not in capsys.readouterr().out
    assert (tmp_path / "x" / "config.json").read_text() == written


@pytest.mark.parametrize(
    "trace",
    [
        {"metrics.jsonl": '{"iteration": 1}\n'},
        {"checkpoints/2/meta.json": "{}"},
        {"policy/2/params": ""},
        {"notes.txt": "mine"},
    ],
)
def test_a_directory_holding_more_than_an_unstarted_run_is_refused(tmp_path, monkeypatch, capsys, trace):
    cfg = dataclasses.replace(TINY, runs_dir=str(tmp_path), run_name="x")
    interrupted_run(cfg, monkeypatch)
    for name, text in trace.items():
        (tmp_path / "x" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "x" / name).write_text(text)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    capsys.readouterr()
    with pytest.raises(FileExistsError, match="already exists and is not empty; pass --resume"):
        train.run(cfg)
    assert "cost:" not in capsys.readouterr().out
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
    for name, text in trace.items():
        assert (tmp_path / "x" / name).read_text() == text


def test_leftovers_of_a_several_seed_run(tmp_path):
    for seed in ("s0", "s1"):
        for sub in ("checkpoints", "policy"):
            (tmp_path / seed / sub).mkdir(parents=True)
        (tmp_path / seed / "config.json").write_text("{}")
        (tmp_path / seed / "metrics.jsonl").write_text("")
    (tmp_path / "config.json").write_text("{}")
    (tmp_path / "tree-0123456789ab.diff").write_text("")
    assert unstarted.leftovers(tmp_path, ["s0", "s1"]) == []
    (tmp_path / "s1" / "checkpoints" / "2").mkdir()
    assert unstarted.leftovers(tmp_path, ["s0", "s1"]) == [tmp_path / "s1" / "checkpoints"]
    assert unstarted.leftovers(tmp_path, ["s0"]) == [tmp_path / "s1"]  # a seed the config does not have


def test_auto_choices_and_the_init_from_iteration_are_compared_after_they_are_made():
    cfg = dataclasses.replace(TINY, net=dataclasses.replace(TINY.net, dtype="auto", conv_impl="auto"))
    assert unstarted.loose_keys(cfg) == {"net.dtype", "net.conv_impl"}
    assert unstarted.loose_keys(TINY) == set()
