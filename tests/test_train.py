"""The trainer: determinism, resume, frozen slots, independent learners, the CLI and bad input."""

import dataclasses
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from conftest import TINY, TINY_FLAGS, metrics_without_speed, needs_records

from jaxsocial.agents import rollout
from jaxsocial.agents.network import NetworkConfig
from jaxsocial.agents.network import init as init_params
from jaxsocial.agents.ppo_config import PPOConfig
from jaxsocial.env.observe import observe
from jaxsocial.run import (
    checkout,
    checkpoint,
    config,
    cpuinfo,
    jsonio,
    loop,
    policy_io,
    provenance,
    rundir,
    startup,
)
from jaxsocial.run.config import PRESETS
from jaxsocial.train import make_train, parse_args, run


def test_every_field_is_a_run_program_or_driver_field():
    kinds = (config.RunConfig, config.ProgramConfig, config.DriverConfig)
    parts = [{f.name for f in dataclasses.fields(kind)} for kind in kinds]
    assert sum(map(len, parts)) == len(set().union(*parts)) == len(dataclasses.fields(config.TrainConfig))
    driven = dataclasses.replace(TINY, iterations=99, run_name="x", eval_every=3, seed=4)
    assert driven.program == TINY.program  # the run's seed and the driver's fields are not compiled
    assert dataclasses.replace(TINY, num_envs=8).program != TINY.program
    changed = dataclasses.replace(TINY, iterations=9, seed=5, net=dataclasses.replace(TINY.net, hidden=4))
    conflicts = config.resume_conflicts(config.config_dict(TINY), config.config_dict(changed))
    assert conflicts == ["net.hidden", "seed"]  # iterations is the driver's: a resume may extend a run


@pytest.fixture(scope="module")
def two_learners():
    cfg = dataclasses.replace(TINY, slots="learner,learner,random")
    init, _, train = make_train(cfg)
    train = jax.jit(train)
    return cfg, init, train


@pytest.mark.slow  # a program of its own; test_same_seed_same_run checks determinism on the fast path
def test_determinism_and_independent_learners(two_learners):
    cfg, init, train = two_learners
    state_a, metrics_a = train(jax.random.key(0))
    state_b, metrics_b = train(jax.random.key(0))
    _, metrics_c = train(jax.random.key(1))
    for a, b in zip(jax.tree.leaves(metrics_a), jax.tree.leaves(metrics_b), strict=True):
        np.testing.assert_array_equal(a, b)
    assert any(not np.array_equal(metrics_a[k], metrics_c[k]) for k in ("aux_loss", "value_loss"))
    start = jax.jit(init)(jax.random.key(0))
    before, after = jax.tree.leaves(start.params), jax.tree.leaves(state_a.params)
    assert all(x.shape[0] == 2 for x in before)  # a separate set of weights per learner
    assert any(not np.array_equal(x[0], x[1]) for x in before)  # initialised independently
    assert all(not np.array_equal(x[0], x[1]) for x in after)  # and trained apart
    assert all(not np.array_equal(b, a) for b, a in zip(before, after, strict=True))
    # and one optimiser state per learner
    assert all(x.shape[0] == 2 for x in jax.tree.leaves(state_a.opt_state) if x.ndim)


@pytest.fixture(scope="module")
def tiny_runs(tmp_path_factory):
    """TINY run in one go ('full') and again ('again'), with seed 1 ('other'), and cut after 2 iterations
    then resumed ('cut'); one compiled program."""
    runs_dir = tmp_path_factory.mktemp("runs")
    full = run(dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="full"))
    again = run(dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="again"))
    other = run(dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="other", seed=1))
    run(dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="cut", iterations=2))
    resumed = run(dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="cut", resume=True))
    return {"runs_dir": runs_dir, "full": full, "again": again, "other": other, "resumed": resumed}


def test_stop_at_return_ends_the_run_after_the_chunk_that_reached_it(tmp_path, capsys):
    cfg = dataclasses.replace(TINY, runs_dir=str(tmp_path), run_name="stop", stop_at_return=-1e9)
    run_dir = run(cfg)
    assert len(rundir.read_metrics(run_dir)) == TINY.chunk_iterations < TINY.iterations
    assert checkpoint.latest_step(run_dir / rundir.POLICY_DIR) == TINY.chunk_iterations  # saved at the stop
    shown = re.search(
        r"stopped after iteration (\d+): the learners' return (\S+) reached", capsys.readouterr().out
    )
    assert shown and int(shown[1]) == TINY.chunk_iterations and float(shown[2]) == float(shown[2])  # a number
    run(dataclasses.replace(cfg, run_name="blind", blind=True))
    assert (
        f"stopped after iteration {TINY.chunk_iterations}: the learners' return reached"
        in capsys.readouterr().out
    )
    never = run(dataclasses.replace(cfg, run_name="never", stop_at_return=1e9))
    assert len(rundir.read_metrics(never)) == TINY.iterations


def test_the_run_ends_with_its_outcome():
    from jaxsocial.agents.population import parse_slot_list
    from jaxsocial.run.outputs import outcome

    def rows(learner_return):
        return [{"iteration": 1, "return/0": learner_return, "episodes/0": 2, "return/1": 38.0,
                 "episodes/1": 2, "return/2": 39.0, "episodes/2": 2}]  # fmt: skip

    social = startup.setup(PRESETS["small"], load_frozen=False)  # a learner beside two experts, penalty 1.5
    plateau = outcome(rows(0.9), social, 512_000)
    assert plateau.startswith("final return (last 10% of the iterations): learner 0.9, expert:explorer 38")
    assert "on the one-tile plateau" in plateau
    assert "expected at this budget (512,000 env-steps) under the 1.5 penalty" in plateau
    long = outcome(rows(0.9), social, 20_000_000)
    assert "expected" not in long and long.endswith("after 20,000,000 env-steps under the 1.5 penalty")
    assert "left the one-tile plateau" in outcome(rows(12.0), social, 512_000)
    unfinished = outcome([{**rows(0.0)[0], "episodes/0": 0}], social, 5_120)  # no learner episode ended
    assert "learner nan" in unfinished and "plateau" not in unfinished
    assert "no episode of the learner ended in the last 10% of the iterations (5,120 env-steps" in unfinished
    learners_only = dataclasses.replace(PRESETS["small"], slots=parse_slot_list("learner,learner,learner"))
    three = outcome(rows(0.9), startup.setup(learners_only, load_frozen=False), 512_000)
    assert (
        "on the one-tile plateau" in three and "beside experts" not in three
    )  # no experts: no such expectation
    assert three.endswith("after 512,000 env-steps under the 1.5 penalty")
    no_penalty = startup.setup(dataclasses.replace(PRESETS["small"], env_args="penalty=0"), load_frozen=False)
    assert "plateau" not in outcome(rows(0.9), no_penalty, 512_000)
    # a run stopped by --stop-at-return: its last chunk, not the diluted final window, says what happened
    stopped = outcome(rows(0.9), social, 12_861_440, stopped_at=5.58)
    assert stopped.startswith("stopped early: the learners' return reached 5.58 after 12,861,440 env-steps")
    assert "the learner left the one-tile plateau" in stopped and "final return: learner" not in stopped
    # a run of several seeds gives the mean over them and each seed's value before the first seed's verdict
    from jaxsocial.run.outputs import seeds_summary
    from jaxsocial.run.rundir import SeedRun

    seeds = [SeedRun(s, Path(f"s{s}"), {}) for s in (4, 5, 6)]
    line = seeds_summary([rows(0.9), rows(12.0), rows(0.3)], seeds, social)
    assert line.endswith("over the 3 seeds (last 10% of the iterations): mean 4.4 (s4 0.9, s5 12, s6 0.3)")


def test_the_run_says_how_it_re_trains_bit_for_bit(monkeypatch):
    """The closing line names what `verify` re-trains under: this process's $XLA_FLAGS and visible cores."""
    from jaxsocial.run.outputs import reproduce_line

    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    line = reproduce_line(Path("runs/x"))
    assert "$XLA_FLAGS '--xla_cpu_multi_thread_eigen=false', in a process that sees 1 core(s)" in line
    assert line.endswith(
        "jaxsocial.experiments verify runs/x checks it (docs/reproducibility.md names the kinds that agree)"
    )


def test_same_seed_same_run(tiny_runs):
    full = metrics_without_speed(tiny_runs["full"])
    assert metrics_without_speed(tiny_runs["again"]) == full
    assert metrics_without_speed(tiny_runs["other"]) != full


def test_resumed_run_equals_uninterrupted_run(tiny_runs):
    assert metrics_without_speed(tiny_runs["resumed"]) == metrics_without_speed(tiny_runs["full"])


def test_a_checkpoint_holding_every_slots_views_resumes_the_same_run(tiny_runs):
    """Checkpoints written before programs rendered only the views their networks read hold every slot's
    views (obs [E, N, ...]); resuming one takes the learner's rows, and the run goes on as uninterrupted."""
    runs_dir = tiny_runs["runs_dir"]
    cut = run(dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="every_view", iterations=2))
    ckpt_dir = cut / "checkpoints"
    static = startup.setup(TINY, load_frozen=False)
    env_params = static.stage(-1)
    init, _ = loop.make_program(TINY.program, env_params, static.pop)
    state = checkpoint.restore(ckpt_dir, jax.eval_shape(init, jax.random.key(0)), 2)
    every = jax.vmap(observe, in_axes=(0, None))(state.env_states, env_params)  # [E, N, ...]
    assert rollout.program_observers(static.pop, "ppo") == (0,)
    assert every.shape[1] == 3 > state.obs.shape[1] == 1
    np.testing.assert_array_equal(every[:, :1], state.obs)
    metadata = checkpoint.read_metadata(ckpt_dir, 2)
    shutil.rmtree(ckpt_dir / "2")
    checkpoint.save(ckpt_dir, 2, state._replace(obs=every), metadata=metadata)
    assert checkpoint.leaf_shapes(ckpt_dir)[".obs"] == every.shape
    resumed = run(dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="every_view", resume=True))
    assert metrics_without_speed(resumed) == metrics_without_speed(tiny_runs["full"])


def test_a_plain_run_records_its_code_and_machine(tiny_runs):
    """`train.run` (what `python -m jaxsocial.train` calls) writes the process file a runner writes: its
    command, the commit, whether the package's files were its (with the diff that rebuilds them where not),
    the CPU, visible cores, flags and versions; the resumed run keeps the process before it (issue 84)."""
    info = jsonio.read_json(tiny_runs["full"] / provenance.RUN_FILE)
    assert info["command"].startswith(
        "python -m jaxsocial.train --preset small --env goalcycle3 --iterations 4"
    )
    assert "--run-name full" in info["command"] and info["cores"] is None
    assert info["rc"] == 0 and info["ended"] >= info["started"] and "earlier" not in info
    assert len(info["commit"]) == 40 and info["no_commit_reason"] is None  # trained from this checkout
    if info["dirty"]:  # uncommitted work under jaxsocial/: its diff, as hashed
        diff = (tiny_runs["full"] / info["tree_diff"]).read_bytes()
        assert hashlib.sha256(diff).hexdigest() == info["tree_diff_sha256"]
    else:
        assert info["dirty"] is False and info["tree_diff"] is None
    assert info["cpu"] == cpuinfo.model() and info["visible_cores"] == provenance.visible_cores()
    assert info["xla_flags"] == os.environ.get("XLA_FLAGS", "")
    assert {k: info[k] for k in provenance.ENVIRONMENT_FIELDS} == provenance.environment()
    assert set(checkout.TREE_FIELDS) <= set(info)
    resumed = jsonio.read_json(tiny_runs["resumed"] / provenance.RUN_FILE)
    assert resumed["rc"] == 0 and [p["rc"] for p in resumed["earlier"]] == [0]
    assert "--iterations 2" in resumed["earlier"][0]["command"] and "--resume" in resumed["command"]


def test_checkpoints_every_checkpoint_every_iterations(tiny_runs):
    assert checkpoint.all_steps(tiny_runs["full"] / "checkpoints") == [2, 4]


def test_existing_run_is_not_overwritten_without_a_flag(tiny_runs):
    with pytest.raises(FileExistsError, match="--resume"):
        run(dataclasses.replace(TINY, runs_dir=str(tiny_runs["runs_dir"]), run_name="full"))


def test_resume_with_another_program_config_is_refused(tiny_runs):
    cfg = dataclasses.replace(TINY, runs_dir=str(tiny_runs["runs_dir"]), run_name="full", resume=True, seed=3)
    with pytest.raises(ValueError, match="config differs"):
        run(cfg)


def test_frozen_slot_plays_the_saved_learner_and_is_never_updated(tiny_runs):
    full = tiny_runs["full"]
    saved = policy_io.load_policy(str(full), TINY.net)
    policy_before = json.dumps(checkpoint.read_metadata(full / "policy"))
    runs_dir = str(tiny_runs["runs_dir"])
    frozen_dir = run(
        dataclasses.replace(TINY, slots=f"learner,frozen:{full},random", runs_dir=runs_dir, run_name="frozen")
    )
    for a, b in zip(
        jax.tree.leaves(saved), jax.tree.leaves(policy_io.load_policy(str(full), TINY.net)), strict=True
    ):
        np.testing.assert_array_equal(a, b)
    assert json.dumps(checkpoint.read_metadata(full / "policy")) == policy_before
    rows = rundir.read_metrics(frozen_dir)
    assert "kl/0" in rows[0] and "kl/1" not in rows[0]  # only the learner is updated


def test_frozen_checkpoint_of_another_architecture_is_refused(tiny_runs):
    full = tiny_runs["full"]
    other = dataclasses.replace(
        TINY,
        slots=f"learner,frozen:{full},random",
        runs_dir=str(tiny_runs["runs_dir"]),
        run_name="other",
        net=NetworkConfig(conv_channels=(4, 8, 8), hidden=32, mlp=8),
    )
    with pytest.raises(ValueError, match="another architecture"):
        run(other)


def test_load_policy_ignores_how_the_network_is_computed(tiny_runs):
    """Only the architecture must match: `frame_batch`, `conv_impl` and `dtype` (policy_io.SPEED_FIELDS) may
    differ."""
    full = str(tiny_runs["full"])
    other_speed = dataclasses.replace(TINY.net, frame_batch=64, conv_impl="xla", dtype="bfloat16")
    assert set(policy_io.SPEED_FIELDS) == {"frame_batch", "conv_impl", "dtype"}
    for a, b in zip(
        jax.tree.leaves(policy_io.load_policy(full, TINY.net)),
        jax.tree.leaves(policy_io.load_policy(full, other_speed)),
        strict=True,
    ):
        np.testing.assert_array_equal(a, b)


def test_a_policy_saved_with_the_old_field_name_loads(tmp_path):
    """Policies exported before `NetworkConfig.chunk` became `frame_batch` (metadata 'chunk') load: one
    written so here (a committed record's in the test below)."""
    net = dataclasses.replace(TINY.net, frame_batch=64)
    params = jax.vmap(lambda k: init_params(k, net))(jax.random.split(jax.random.key(0), 1))
    meta = policy_io.json_net(net)
    meta["chunk"] = meta.pop("frame_batch")
    checkpoint.save(
        tmp_path / rundir.POLICY_DIR, 3, {"params": params}, metadata={"net": meta, "n_learners": 1}
    )
    assert policy_io.saved_net(tmp_path) == net
    for a, b in zip(
        jax.tree.leaves(policy_io.load_policy(tmp_path, net)), jax.tree.leaves(params), strict=True
    ):
        np.testing.assert_array_equal(a, b[0])


@needs_records("records/tiny")
def test_a_committed_records_policy_saved_with_the_old_field_name_loads():
    """A committed tiny record's policy, exported before the rename, loads with the network it names."""
    record = (
        Path(__file__).resolve().parents[1] / "benchmarks/results/records/tiny/social_pred_nopenalty-s0-1/s0"
    )
    assert "chunk" in checkpoint.read_metadata(record / rundir.POLICY_DIR)["net"]
    saved = policy_io.saved_net(record)
    assert saved.frame_batch == 512 and jax.tree.leaves(policy_io.load_policy(record, saved))


@pytest.mark.slow  # a subprocess compiling the default slots' program (scripted experts)
def test_cli_end_to_end(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "jaxsocial.train",
        "--runs-dir",
        str(tmp_path),
        "--run-name",
        "cli",
        *TINY_FLAGS,
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    run_dir = tmp_path / "cli"
    config = json.loads((run_dir / "config.json").read_text())
    assert config["num_envs"] == 4 and config["net"]["hidden"] == 16
    rows = rundir.read_metrics(run_dir)
    assert [r["iteration"] for r in rows] == [1, 2] and "return/0" in rows[0] and "episodes/2" in rows[0]
    assert checkpoint.latest_step(run_dir / "checkpoints") == 2
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert again.returncode != 0 and "--overwrite" in again.stderr
    assert rundir.read_metrics(run_dir) == rows  # nothing overwritten


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"ppo": PPOConfig(minibatch_segments=512, segment_length=4)}, "larger than the batch"),
        ({"ppo": PPOConfig(segment_length=3)}, "must divide"),
        ({"env": "goalcycle9"}, "unknown environment"),
        ({"slots": "learner,random"}, "3 agents"),
        ({"slots": "random,random,random"}, "no learner"),
        ({"slots": "learner,frozen,random"}, "needs a run directory"),
        ({"env_args": "n_agents=8"}, "agent colours"),
        ({"algo": "dqn"}, "unknown --algo"),
        ({"algo": "bc", "slots": "learner,random,random"}, "clones expert or frozen slots"),
        ({"slots": "learner,expert:navigator,random"}, "navigator"),
        ({"slots": "learner,expert:explorer:epsilon=2,random"}, "epsilon"),
        (
            {"algo": "bc", "slots": "learner,expert:explorer,random", "net": NetworkConfig(n_actions=3)},
            "must be 7",
        ),
        ({"eval_envs": ("goalcycle7",)}, "unknown environment"),
        ({"eval_envs": ("goalcycle4:penalty=abc,nope=1",)}, "unknown EnvParams field"),
        ({"eval_envs": ("goalcycle4",), "eval_every": 0}, "eval_every"),
        ({"eval_envs": ("goalcycle4",), "eval_episodes": 0}, "eval_episodes"),
        (
            {"eval_envs": ("goalcycle4:observation=symbolic",)},
            "eval env \"goalcycle4:observation='symbolic'\"",
        ),
        ({"env_args": "solo_prob=0.5", "slots": "random,learner,random"}, "--env-args: solo episodes keep"),
        ({"env_args": "penalty=abc"}, "penalty='abc' must be of type float"),
        ({"net": NetworkConfig(aux="attention", n_others=3)}, "net.n_others 2"),
        (
            {"algo": "bc", "slots": "learner,expert:explorer,random", "net": NetworkConfig(aux="attention")},
            "needs --algo ppo",
        ),
    ],
)
def test_bad_config_fails_before_compiling(tmp_path, changes, message):
    with pytest.raises(ValueError, match=message):
        run(dataclasses.replace(TINY, runs_dir=str(tmp_path), **changes))
    assert not any(tmp_path.iterdir())  # nothing written


def test_setup_builds_each_evaluation_environment_with_its_default_companions():
    cfg = dataclasses.replace(TINY, eval_envs=("goalcycle4", "goalcycle3-solo:width=7"))
    evals = startup.setup(cfg, load_frozen=False).eval_envs
    assert [str(e.spec) for e in evals] == ["goalcycle4", "goalcycle3-solo:width=7"]
    assert [(e.env_params.n_goals, e.env_params.width, e.env_params.n_agents) for e in evals] == [
        (4, 13, 3),
        (3, 7, 1),
    ]
    gc4, solo = (e.pop for e in evals)  # the learner in slot 0 beside the environment's scripted experts
    assert gc4.learners == (0,) and gc4.experts == (1, 2) and solo.learners == (0,) and not solo.experts


@pytest.mark.slow  # a learning test; test_ppo and test_network check the attention loss itself
def test_attention_loss_learns_where_the_others_are_under_expert_dropout():
    """The attention targets recorded in the rollout are learnable: the loss falls well below its start."""
    cfg = dataclasses.replace(
        TINY,
        env_args="max_steps=12,width=7,height=7,dropout_prob=0.5,dropin_prob=0.5",
        iterations=8,
        net=dataclasses.replace(TINY.net, aux="pred+attention"),
        ppo=dataclasses.replace(TINY.ppo, lr=0.03, kl_target=10.0, kl_hard_limit=10.0),
    )
    _, metrics = jax.jit(make_train(cfg)[2])(jax.random.key(0))
    losses = np.asarray(metrics["attention_loss"])[:, 0]
    assert losses[0] > 3.0 and losses[-1] < losses[0] - 1.0, losses


@pytest.mark.parametrize(
    "argv", [["--preset", "paper"], ["--preset=paper"], ["--preset", "small", "--preset=paper"]]
)
def test_preset_flag_forms(argv):
    cfg = parse_args([*argv, "--iterations", "7"])
    assert (cfg.preset, cfg.net, cfg.iterations) == ("paper", PRESETS["paper"].net, 7)
    with pytest.raises(SystemExit, match="unknown --preset"):
        parse_args(["--preset=nope"])
