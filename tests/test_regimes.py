"""Training regimes: stages (penalty curriculum, solo/social switch), solo/social mixing, expert slots and
zero-shot evaluation."""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from conftest import TINY

import jaxsocial
from jaxsocial import train
from jaxsocial.agents import network, population
from jaxsocial.env import core
from jaxsocial.evaluate import EvalConfig, evaluate, mean_ci95
from jaxsocial.run import policy_io, rundir, schedule
from jaxsocial.run.startup import setup
from jaxsocial.specs import PolicyRef
from jaxsocial.train import run

CURRICULUM = "2:penalty=1.0;return>=-1000:penalty=1.5"  # 1.5 is the preset's: the first program again


def test_parse_stages_and_accumulated_overrides():
    stages = schedule.parse_stages("0:penalty=0.5;" + CURRICULUM + ";return>=3:solo_prob=0.75")
    assert [s.start for s in stages] == [0, 2, None, None]
    assert [s.threshold for s in stages] == [None, None, -1000.0, 3.0]
    assert schedule.overrides_at(stages, 0) == {"penalty": 0.5}
    assert schedule.overrides_at(stages, 3) == {"penalty": 1.5, "solo_prob": 0.75}
    assert schedule.overrides_at(stages, -1) == {}
    assert schedule.initial_index(stages) == 0 and schedule.initial_index(stages[1:]) == -1
    static = setup(dataclasses.replace(TINY, stages=CURRICULUM))
    assert static.stage(0) == dataclasses.replace(static.stage(-1), penalty=1.0)
    # a stage whose environment is the preset's runs the program of the plain config (same cache key)
    assert static.stage(1) == static.stage(-1)
    # iteration stages switch on the iteration, threshold stages on the chunk's learner return
    assert schedule.advance(stages, 0, 1, 50.0) == 0 and schedule.advance(stages, 0, 2, None) == 1
    assert schedule.advance(stages, 2, 9, None) == 2 and schedule.advance(stages, 2, 9, 3.0) == 3
    assert schedule.advance(stages, 3, 9, 99.0) == 3  # the last stage stays


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("5:penalty", "field=value"),
        ("soon:penalty=1", "iteration number"),
        ("4:penalty=1;2:penalty=2", "increasing"),
        ("return>=x:penalty=1", "threshold"),
        ("0:width=9", "array shapes"),
        ("0:penalty=1;3:bogus=1", "unknown EnvParams"),
        ("4:solo_prob=0.5", "put learners first"),
    ],
)
def test_bad_stages_fail_before_compiling(tmp_path, text, message):
    slots = "random,learner,random" if "solo" in text else ""
    with pytest.raises(ValueError, match=message):
        run(dataclasses.replace(TINY, stages=text, slots=slots, runs_dir=str(tmp_path)))
    assert not any(tmp_path.iterdir())


def test_penalty_curriculum_switches_at_the_configured_points(tmp_path):
    cfg = dataclasses.replace(
        TINY, stages=CURRICULUM, iterations=7, chunk_iterations=3, runs_dir=str(tmp_path)
    )
    rows = rundir.read_metrics(run(cfg))
    # before the first stage the plain environment runs; stage 0 starts exactly at iteration 2 (the first
    # chunk is cut short to land on it); the threshold of stage 1 is met by stage 0's first chunk
    # (iterations 3-5), so stage 1 runs from iteration 6
    assert [(r["iteration"], r["stage"]) for r in rows] == [
        (1, -1),
        (2, -1),
        (3, 0),
        (4, 0),
        (5, 0),
        (6, 1),
        (7, 1),
    ]
    static = setup(cfg)
    assert [static.stage(i).penalty for i in (-1, 0, 1)] == [1.5, 1.0, 1.5]
    program = [train.compiled_program(cfg, stage=i) for i in (-1, 0, 1)]
    assert program[2] is program[0] and program[1] is not program[0]  # stage 1 reuses the first program


def test_solo_mixture_proportion_and_absent_agents(step_env, observe_fn):
    _, params = jaxsocial.make("goalcycle3", solo_prob=0.75)
    n = 4000
    obs, states = jax.jit(jax.vmap(core.reset, in_axes=(0, None)), static_argnums=1)(
        jax.random.split(jax.random.key(0), n), params
    )
    present = np.asarray(states.present)
    assert present[:, 0].all()  # the first slot always takes part
    solo = ~present[:, 1]
    np.testing.assert_array_equal(present[:, 1], present[:, 2])  # solo episodes drop every other slot
    assert abs(solo.mean() - 0.75) < 0.03  # 4000 draws: std 0.007
    assert not np.asarray(states.active)[solo][:, 1:].any()
    # an absent agent is never drawn: a solo episode's view equals one rendered with the others removed
    i = int(np.flatnonzero(solo)[0])
    one = jax.tree.map(lambda x: x[i], states)
    _, alone = jaxsocial.make("goalcycle3-solo")
    single = one.replace(
        **{
            f: getattr(one, f)[:1]
            for f in ("pos", "dir", "cycle_state", "prestige", "active", "present", "arrival")
        }
    )
    np.testing.assert_array_equal(obs[i, 0], observe_fn(single, alone)[0])
    # and never acts: it stays put and earns nothing, whatever it does
    _, after, reward, terminated, _ = step_env(one, np.array([2, 2, 2], np.int32), params)
    np.testing.assert_array_equal(after.pos[1:], one.pos[1:])
    assert float(np.abs(reward[1:]).sum()) == 0.0 and terminated[1:].all()


def test_slot_parsing_with_expert_arguments():
    slots = population.parse_slots("learner,expert:explorer:epsilon=0.1,forget=0.02,expert:ckpt=runs/x#1", 3)
    assert slots[1].kind == "expert" and slots[1].expert.epsilon == 0.1 and slots[1].expert.forget == 0.02
    assert slots[2] == population.Slot("frozen", PolicyRef(Path("runs/x"), 1))
    with pytest.warns(DeprecationWarning, match=r"runs/x#1; '@' names a checkpoint's iteration"):
        assert population.parse_slots("learner,random,frozen:runs/x@1", 3)[2] == slots[2]  # the old spelling
    _, params = jaxsocial.make("maze-distractors")
    assert population.default_slots(params) == "learner,expert:navigator,expert:navigator,random,random"
    with pytest.raises(ValueError, match="say which expert"):
        population.parse_slots("learner,expert,random", 3)
    pop = population.Population(population.parse_slots("learner,expert:navigator,random", 3))
    with pytest.raises(ValueError, match="slot 1"):
        pop.validate(jaxsocial.make("goalcycle3")[1])


def test_ci95():
    mean, low, high = mean_ci95(np.array([1.0, 2.0, 3.0]))
    t_975_df2 = 0.95 / np.sqrt(2 * 0.975 * 0.025)  # closed form at 2 degrees of freedom
    assert mean == 2.0 and np.isclose(high - mean, t_975_df2 * 1.0 / np.sqrt(3))
    assert mean_ci95(np.array([5.0])) == (5.0, 5.0, 5.0)


def save_policy(run_dir, net, seed=0):
    """A run directory with a saved (untrained) policy, as training leaves it."""
    params = jax.vmap(lambda k: network.init(k, net))(jax.random.split(jax.random.key(seed), 1))
    policy_io.export_policy(run_dir, 1, params, net)
    return run_dir


def test_evaluate_saved_agent_zero_shot_and_wrong_architecture(tmp_path):
    runs = [str(save_policy(tmp_path / f"s{seed}", TINY.net, seed)) for seed in (0, 1)]
    base = EvalConfig(
        ckpt=tuple(runs),
        env="fourrooms",
        env_args="max_steps=20",
        slots="learner,expert:navigator,random",
        episodes=6,
    )
    result = evaluate(base)
    learner, expert = result["results"][0], result["results"][1]
    assert result["slots"] == ["learner", "expert:navigator", "random"]
    assert learner["ci_over"] == "seeds" and learner["episodes"] == 12 and len(learner["per_seed_mean"]) == 2
    assert learner["ci95"][0] <= learner["mean_return"] <= learner["ci95"][1]
    assert expert["mean_return"] > 0  # navigators reach the goal in small four-rooms episodes
    # a policy saved by a run with another network cannot fill a slot beside this one
    other = save_policy(tmp_path / "other", dataclasses.replace(TINY.net, hidden=8))
    wrong = dataclasses.replace(base, ckpt=runs[:1], slots=f"learner,expert:ckpt={other},random")
    with pytest.raises(ValueError, match="another architecture"):
        evaluate(dataclasses.replace(wrong, env="goalcycle3"))
    with pytest.raises(ValueError, match="give both"):
        evaluate(dataclasses.replace(base, ckpt=()))


def test_evaluate_cli_scripted_only(tmp_path):
    out = tmp_path / "eval.json"
    cmd = [sys.executable, "-m", "jaxsocial.evaluate", "--env", "goalcycle3", "--env-args", "max_steps=40",
           "--slots", "expert:oracle,random,random", "--episodes", "8", "--out", str(out)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    result = json.loads(out.read_text())
    assert result["results"][0]["mean_return"] > 3  # the oracle collects a reward every few steps
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert again.returncode != 0 and "--overwrite" in again.stderr
