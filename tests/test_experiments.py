"""Experiment recipes: every condition is a valid run at every scale, the summaries' arithmetic, and the
run -> resume/skip -> figure plumbing at the tiny scale (with evaluation during training and a stage)."""

import dataclasses
import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import needs_records

from jaxsocial import stats, train
from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments.analyse import kinds, plot_figures, rundirs, summaries, takeoff
from jaxsocial.experiments.launch import pinned, runner
from jaxsocial.experiments.plan import conditions, paths, recipes
from jaxsocial.run import config, jsonio, metrics, rundir, schedule, startup
from jaxsocial.run.cost import read_rate
from jaxsocial.run.runlock import RunLock


@pytest.mark.parametrize("scale", sorted(recipes.SCALES))
def test_every_condition_is_a_valid_run(scale):
    for name, cond in conditions.CONDITIONS.items():
        programs = recipes.condition_programs(recipes.SCALES[scale], name, seed=3, seeds=2, runs_dir="r")
        per_seed = [(3, 1), (4, 1)] if cond.program_per_seed else [(3, 2)]
        assert [(cfg.seed, cfg.seeds) for cfg in programs] == per_seed
        for cfg in programs:
            startup.setup(cfg, load_frozen=False)  # raises on any invalid setting, compiles nothing
            assert cfg.iterations == recipes.SCALES[scale].iterations
            assert cfg.run_name == f"{scale}/{name}-s{cfg.seed}-{cfg.seed + cfg.seeds - 1}"
            assert cfg.env == cond.env
            assert bool(cfg.eval_envs) == cond.eval_during_training
            flags = recipes.condition_flags(recipes.SCALES[scale], name, cfg.seed, cfg.seeds, "r")
            assert train.parse_args(flags) == cfg  # the command line a run is launched with gives it back
    for recipe in recipes.RECIPES.values():
        assert set(recipe.conditions) <= set(conditions.CONDITIONS)


def test_learned_mixing_switches_each_seed_on_its_own_return(tmp_path, capsys):
    """The faithful Fig. 6 protocol: each seed's program switches to 75% solo episodes once its own return
    reaches MIXING_RETURN; the dry run lists one command per seed, and the seeds are read back together."""
    assert conditions.CONDITIONS["social_pred_mixed_learned"].program_per_seed
    first, second = recipes.condition_programs(recipes.GPU, "social_pred_mixed_learned", 0, 2, str(tmp_path))
    assert first.stages == second.stages
    assert schedule.format_stages(first.stages) == f"return>={conditions.MIXING_RETURN!r}:solo_prob=0.75"
    mixed = recipes.condition_config(recipes.GPU, "social_pred_mixed", 0, 2, "r")
    assert schedule.format_stages(mixed.stages) == "200:solo_prob=0.75"
    cli.main(
        ["run", "fig6_mixing", "--scale", "gpu", "--seeds", "2", "--runs-dir", str(tmp_path), "--dry-run"]
    )
    out = capsys.readouterr().out
    for seed in (0, 1):
        assert f"[fig6_mixing/gpu] social_pred_mixed_learned s{seed}: missing" in out
        run_name = f"gpu/social_pred_mixed_learned-s{seed}-{seed}"
        command = next(line for line in out.splitlines() if f"--run-name {run_name}" in line)
        assert (
            f"--seed {seed} " in command and "--seeds 1 " in command and f"--runs-dir {tmp_path}" in command
        )
    assert not any(tmp_path.iterdir())  # a dry run writes nothing
    dirs = runner.condition_seed_dirs(recipes.GPU, "social_pred_mixed_learned", 0, 2, str(tmp_path))
    assert dirs == [tmp_path / f"gpu/social_pred_mixed_learned-s{s}-{s}" for s in (0, 1)]


def test_paper_scale_is_the_paper_preset():
    cfg = recipes.condition_config(recipes.PAPER, "social_pred", 0, 1, "r")
    paper = config.PRESETS["paper"]
    assert (cfg.net.conv_channels, cfg.net.hidden, cfg.net.aux) == ((32, 64, 64), 192, "pred")
    assert (cfg.ppo, cfg.num_envs, cfg.rollout_steps, cfg.iterations) == (
        paper.ppo,
        paper.num_envs,
        paper.rollout_steps,
        paper.iterations,
    )
    assert cfg.env_args == ()  # 13x13 Goal Cycle as in the paper
    mixed = recipes.condition_config(recipes.PAPER, "social_pred_mixed", 0, 1, "r")
    assert schedule.format_stages(mixed.stages) == f"{round(paper.iterations / 3)}:solo_prob=0.75"


def _rows(returns, episodes):
    return [
        {"iteration": i + 1, "return/0": r, "episodes/0": n, "return/1": 10.0, "episodes/1": 1}
        for i, (r, n) in enumerate(zip(returns, episodes, strict=True))
    ]


def test_final_return_is_episode_weighted_over_the_last_tenth():
    rows = _rows([5.0] * 18 + [1.0, 4.0], [1] * 18 + [3, 1])
    assert metrics.final_return(rows) == pytest.approx((3 * 1.0 + 4.0) / 4)
    assert metrics.final_return(rows, slot=1) == 10.0
    assert math.isnan(metrics.final_return(_rows([0.0] * 10, [0] * 10)))
    x, y = metrics.curve(rows, points=4)
    np.testing.assert_array_equal(x, [5, 10, 15, 20])
    assert y[-1] == pytest.approx((5.0 * 3 + 3.0 + 4.0) / 7)


T_975_DF2 = 0.95 / math.sqrt(2 * 0.975 * 0.025)
"""Student t's 0.975 quantile at 2 degrees of freedom, in closed form: (2p - 1) / sqrt(2p(1 - p))."""


def test_stats_and_ci_separation():
    s = stats.summary([1.0, 2.0, 3.0])
    half = T_975_DF2 * 1.0 / math.sqrt(3)
    assert s["mean"] == 2.0
    assert s["ci95"] == pytest.approx([2.0 - half, 2.0 + half], abs=1e-4)
    conditions = {
        "a": stats.summary([10.0, 10.5, 11.0]),  # CI [9.26, 11.74]
        "b": stats.summary([1.0, 2.0, 3.0]),  # CI [-0.48, 4.48]
        "c": s,  # the same as b: neither is above the other
        "d": stats.summary([0.0, 2.5, 5.0]),  # CI [-3.71, 8.71]
    }
    assert stats.separations(conditions) == {
        "a > b": True,
        "a > c": True,
        "a > d": True,
        "d > b": False,
        "d > c": False,
    }


def test_iqm_and_its_bootstrap_interval():
    # a quarter cut from each end: 6 seeds keep the middle 4
    s = stats.summary([0.7, 30.0, 0.9, 35.2, 0.8, 1.1])
    assert s["iqm"] == pytest.approx((0.8 + 0.9 + 1.1 + 30.0) / 4)
    assert 0.7 <= s["iqm_ci95"][0] < s["iqm"] < s["iqm_ci95"][1] <= 35.2
    assert stats.summary([0.7, 30.0, 0.9, 35.2, 0.8, 1.1]) == s  # a fixed generator: re-derives exactly
    # seeds that either learn or do not: the t interval leaves the seeds' range, the IQM's does not
    bimodal = stats.summary([0.0, 0.0, 0.0, 30.0, 30.0, 30.0])
    assert bimodal["ci95"][0] < 0.0 and bimodal["ci95"][1] > 30.0
    assert bimodal["iqm_ci95"][0] >= 0.0 and bimodal["iqm_ci95"][1] <= 30.0
    assert stats.summary([5.0])["iqm_ci95"] == [5.0, 5.0]
    assert stats.summary([float("nan")])["iqm"] is None


def test_learned_seed_tests_state_their_direction():
    """The recipe's stated comparisons are one-sided in their direction, whichever way the counts fall; every
    other pair is two-sided and Holm-adjusted over the exploratory pairs."""
    conditions = {c: {"seeds_above_one_tile": k, "final_returns": [1.0] * n} for c, k, n in
                  (("a", 2, 6), ("b", 0, 6), ("c", 0, 3), ("d", 3, 3))}  # fmt: skip
    tests = stats.learned_seed_tests(conditions, (("a", "b"), ("c", "d"), ("a", "absent")))
    assert list(tests["stated"]) == ["a > b", "c > d"]  # a comparison with an absent condition is dropped
    assert tests["stated"]["a > b"]["fisher_p"] == pytest.approx(math.comb(6, 2) / math.comb(12, 2), abs=1e-4)
    assert tests["stated"]["c > d"]["fisher_p"] == 1.0  # against the counts: no evidence in the stated way
    assert tests["stated"]["a > b"]["learned"] == [2, 6, 0, 6]
    exploratory = tests["exploratory"]
    assert list(exploratory) == ["a vs c", "a vs d", "b vs c", "b vs d"]
    raw = {pair: stats.fisher(*e["learned"], alternative="two-sided") for pair, e in exploratory.items()}
    assert exploratory["b vs d"]["fisher_p"] == pytest.approx(raw["b vs d"], abs=1e-4)
    holm = stats.holm(raw)
    for pair, entry in exploratory.items():
        assert entry["fisher_p_holm"] == pytest.approx(holm[pair], abs=1e-4)
        assert entry["boschloo_p_holm"] >= entry["boschloo_p"]
    assert "one-sided" in tests["method"] and "Holm" in tests["method"]


def test_learned_seed_tests_never_print_a_small_p_as_zero():
    """4 decimals, or 3 significant digits below 1e-4: pred8's 30 of 40 against 6 of 40 once read 0.0."""
    conditions = {
        c: {"seeds_above_one_tile": k, "final_returns": [1.0] * 40} for c, k in (("a", 30), ("b", 6))
    }
    stated = stats.learned_seed_tests(conditions, (("a", "b"),))["stated"]["a > b"]
    assert stated == {"learned": [30, 40, 6, 40], "fisher_p": 4.75e-08, "boschloo_p": 1.8e-08}
    assert stats.round_p(0.123456, 4) == 0.1235 and stats.round_p(1e-4, 4) == 1e-4
    assert stats.round_p(9.996e-5, 4) == 0.0001 and stats.round_p(9.99e-5, 4) == 9.99e-05
    assert stats.round_p(0.0, 4) == 0.0 and stats.round_p(1.0, 4) == 1.0


def test_every_stated_comparison_names_the_recipes_conditions():
    for recipe in recipes.RECIPES.values():
        for a, b in recipe.hypotheses:
            assert a in recipe.conditions and b in recipe.conditions and a != b, recipe.name


def _fake_run(root, scale, condition, first, last, iterations):
    """A run directory of `condition` holding seeds first..last, each with `iterations` metrics rows."""
    run = root / scale.name / f"{condition}-s{first}-{last}"
    for seed in range(first, last + 1):
        seed_dir = run / f"s{seed}" if last > first else run
        seed_dir.mkdir(parents=True)
        rundir.MetricsLog(seed_dir).append(_rows([float(seed)] * iterations, [1] * iterations))
    (run / rundir.CONFIG_FILE).write_text("{}")


def test_a_seed_two_runs_hold_is_an_error_unless_one_is_picked(tmp_path):
    scale, n = recipes.TINY, recipes.TINY.iterations
    _fake_run(tmp_path, scale, "social_rec", 0, 2, n)
    _fake_run(tmp_path, scale, "social_rec", 1, 1, n)  # seed 1 again, in a run of its own
    with pytest.raises(ValueError, match=r"seed 1 of social_rec is held by 2 runs .*--pick"):
        runner.condition_seed_dirs(scale, "social_rec", 0, 3, str(tmp_path))
    with pytest.raises(ValueError, match="held by 2 runs"):
        summaries.RecipeRuns(recipes.RECIPES["h1"], scale, 0, 3, str(tmp_path))
    base = tmp_path / "tiny"
    dirs = runner.condition_seed_dirs(scale, "social_rec", 0, 3, str(tmp_path), pick=("social_rec-s1-1",))
    assert dirs == [
        base / "social_rec-s0-2" / "s0",
        base / "social_rec-s1-1",
        base / "social_rec-s0-2" / "s2",
    ]
    dirs = runner.condition_seed_dirs(scale, "social_rec", 0, 3, str(tmp_path), pick=("social_rec-s0-2",))
    assert dirs[1] == base / "social_rec-s0-2" / "s1"


def test_seeds_are_read_from_whichever_run_holds_them(tmp_path):
    """Seeds trained in two programs (`--seeds 3`, then `--seed 3 --seeds 3`) read together as `--seeds 6`;
    a seed no run holds is left out of its condition, and listed."""
    scale, n = recipes.TINY, recipes.TINY.iterations
    _fake_run(tmp_path, scale, "social_rec", 0, 2, n)
    _fake_run(tmp_path, scale, "social_rec", 3, 5, n)
    _fake_run(tmp_path, scale, "social_none", 0, 0, n)
    _fake_run(tmp_path, scale, "social_rec", 0, 5, n)  # renamed below to a name that is not a run's
    (tmp_path / "tiny" / "social_rec-s0-5").rename(tmp_path / "tiny" / "social_rec-s0-5-old")
    dirs = runner.condition_seed_dirs(scale, "social_rec", 0, 6, str(tmp_path))
    base = tmp_path / "tiny"
    assert dirs == [base / "social_rec-s0-2" / f"s{s}" for s in range(3)] + [
        base / "social_rec-s3-5" / f"s{s}" for s in range(3, 6)
    ]
    social_rec = recipes.condition_config(scale, "social_rec", 0, 6, str(tmp_path))
    run_dir = rundir.run_path(social_rec)
    assert rundirs.run_state(run_dir, social_rec.iterations, dirs) == "finished"
    runs = summaries.RecipeRuns(recipes.RECIPES["h1"], scale, 0, 6, str(tmp_path))
    assert runs.missing == ["solo_pred", "social_pred"]
    assert runs.missing_seeds == {"social_none": [1, 2, 3, 4, 5]}
    assert [metrics.final_return(rows) for rows in runs.rows["social_rec"]] == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    assert runs.seed_dirs["social_none"] == [base / "social_none-s0-0"]
    summary = summaries.summarize(runs, "the command")
    assert summary["conditions"]["social_rec"]["seeds_above_one_tile"] == 3  # seeds 3, 4, 5 return > 2
    said = summaries.outcome_lines(summary)  # what `figure` ends with
    assert said[[c for c in runs.rows].index("social_rec")].startswith(
        "social PPO + aux rec: 3 of 6 seeds past the one-tile plateau (the first at "
    )
    # h1 states social_rec > social_none: 3 of 6 against 0 of 1, one-sided
    stated = summary["learned_seed_tests"]["stated"]
    assert list(stated) == ["social_rec > social_none"]
    assert stated["social_rec > social_none"]["fisher_p"] == pytest.approx(4 / 7, abs=1e-4)
    takeoffs = summary["time_to_learning"]["conditions"]["social_rec"]
    cfg = runs.configs["social_rec"]
    per_iteration = cfg.num_envs * cfg.rollout_steps  # every iteration of seeds 3-5 is above 2:
    first_block = takeoff.window_curve(runs.rows["social_rec"][0], per_iteration)[0][0]  # the first window
    assert takeoffs["takeoff_iterations"] == [None] * 3 + [first_block] * 3
    assert takeoffs["takeoff_env_steps"][3] == first_block * cfg.num_envs * cfg.rollout_steps
    assert summary["command"] == "the command"
    assert summary["provenance"] == {  # fake runs: no records behind them
        "training_runs": {},
        "unrecorded": [str(d) for dirs in runs.seed_dirs.values() for d in dirs],
    }


def test_cli_rejects_bad_input(tmp_path, capsys):
    with pytest.raises(SystemExit):
        cli.main(["run", "nonexistent"])
    with pytest.raises(SystemExit):
        cli.main(["run", "h1", "--seeds", "0"])
    with pytest.raises(SystemExit, match="no metrics for any condition of h1"):
        cli.main(["figure", "h1", "--scale", "tiny", "--runs-dir", str(tmp_path)])
    assert not any(tmp_path.iterdir())  # nothing written


@pytest.fixture(scope="module")
def mixing_runs(tmp_path_factory):
    """The mixing recipe at the tiny scale, one seed: social PPO + pred with evaluation during training,
    and the same with the switch to 75% solo episodes at a fixed iteration and on the return."""
    root = tmp_path_factory.mktemp("experiments")
    cli.main(["run", "fig6_mixing", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(root)])
    return root


@pytest.mark.slow
def test_recipe_runs_evaluates_and_skips_finished_runs(mixing_runs, capsys):
    scale = recipes.TINY
    cfg = recipes.condition_config(scale, "social_pred_mixed", 0, 1, str(mixing_runs))
    (run_dir,) = runner.config_seed_dirs(cfg)
    rows = rundir.read_metrics(run_dir)
    assert [r["iteration"] for r in rows] == list(range(1, scale.iterations + 1))
    switch = round(scale.iterations / 3)
    assert [r["stage"] for r in rows] == [-1] * switch + [0] * (scale.iterations - switch)
    evals = {r["iteration"]: r for r in rows if "eval/goalcycle3-solo:width=7,height=7,max_steps=20" in r}
    assert sorted(evals) == list(range(scale.eval_every, scale.iterations + 1, scale.eval_every))
    for r in evals.values():
        assert {k for k in r if k.startswith("eval/")} == {
            "eval/goalcycle3-solo:width=7,height=7,max_steps=20",
            "eval/goalcycle4:width=7,height=7,max_steps=20",
        }
    before = (run_dir / rundir.METRICS_FILE).stat().st_mtime_ns
    capsys.readouterr()
    cli.main(["run", "fig6_mixing", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(mixing_runs)])
    assert capsys.readouterr().out.count(": finished") == 3
    assert (run_dir / rundir.METRICS_FILE).stat().st_mtime_ns == before  # not retrained


@pytest.mark.slow
def test_figure_summarises_the_runs(mixing_runs, tmp_path):
    cli.main(["figure", "fig6_mixing", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(mixing_runs),
              "--out-dir", str(tmp_path)])  # fmt: skip
    summary = json.loads((tmp_path / "fig6_mixing-tiny.json").read_text())
    assert (tmp_path / "fig6_mixing-tiny.png").stat().st_size > 1000
    assert summary["command"] == (
        "python -m jaxsocial.experiments figure fig6_mixing --scale tiny --seed 0 --seeds 1 "
        f"--runs-dir {mixing_runs} --out-dir {tmp_path}"
    )
    assert summary["provenance"]["unrecorded"] == [
        str(d) for dirs in summary["seed_dirs"].values() for d in dirs
    ]
    taken = summary["time_to_learning"]["conditions"]
    assert set(taken) == set(summary["conditions"]) and all(t["seeds"] == 1 for t in taken.values())
    assert set(summary["conditions"]) == {"social_pred", "social_pred_mixed", "social_pred_mixed_learned"}
    switches = {name: entry["switch_iterations"] for name, entry in summary["conditions"].items()}
    # the fixed switch at a third of training; the learned one waits for a return of 10, never reached here
    assert switches == {
        "social_pred": [None],
        "social_pred_mixed": [round(recipes.TINY.iterations / 3) + 1],
        "social_pred_mixed_learned": [None],
    }
    for name, entry in summary["conditions"].items():
        cfg = recipes.condition_config(recipes.TINY, name, 0, 1, str(mixing_runs))
        rows = rundir.read_metrics(runner.config_seed_dirs(cfg)[0])
        assert entry["final_returns"] == [round(metrics.final_return(rows), 4)]
        assert entry["seeds_above_one_tile"] == int(metrics.final_return(rows) > metrics.LEARNED_RETURN)
        key = "eval/goalcycle4:width=7,height=7,max_steps=20"
        assert entry[key]["final_returns"] == [round(rows[-1][key], 4)]
    assert summary["experts"]["mean"] > 0  # the scripted experts collect tiles


def test_conditions_with_other_experts_report_their_own(tmp_path):
    """The recipe's `experts` are the first social condition's; imperfect experts and a world with
    distractors report their experts' returns (the expert slots only) beside their condition."""
    from types import SimpleNamespace

    def rows(*slot_returns):
        row = {}
        for slot, r in enumerate(slot_returns):
            row |= {f"return/{slot}": r, f"episodes/{slot}": 2}
        return [{"iteration": i + 1, **row} for i in range(10)]

    returns = {  # the learner, its two experts, and the distractors where there are any
        "solo_pred": (0.9,),
        "social_pred": (10.0, 40.0, 42.0),
        "social_pred_imperfect": (8.0, 20.0, 22.0),
        "social_pred_distractors": (6.0, 38.0, 40.0, -3.0, -5.0),
    }
    configs = {c: recipes.condition_config(recipes.TINY, c, 0, 1, str(tmp_path)) for c in returns}
    seed_rows = {c: [rows(*r)] for c, r in returns.items()}
    runs = SimpleNamespace(recipe=recipes.RECIPES["imperfect"], rows=seed_rows, configs=configs)
    summary = kinds.summarise_curves(runs)
    assert summary["experts"]["final_returns"] == [41.0]
    assert "experts" not in summary["conditions"]["social_pred"]
    assert "experts" not in summary["conditions"]["solo_pred"]
    assert summary["conditions"]["social_pred_imperfect"]["experts"]["final_returns"] == [21.0]
    assert summary["conditions"]["social_pred_distractors"]["experts"]["final_returns"] == [39.0]
    plt = plot_figures.pyplot()
    fig, ax = plt.subplots()
    plot_figures.draw_finals(ax, runs, summary, plt.get_cmap("tab10").colors)
    assert [t.get_text() for t in ax.get_xticklabels()][-3:] == [
        "its scripted experts",
        "experts: social PPO + aux pred, imperfect experts",
        "experts: social PPO + aux pred, 2 random distractors",
    ]
    plt.close(fig)


def test_a_curves_recipe_with_transfer_envs_summarises_its_zero_shot_returns(tmp_path):
    """`distractors` plays every trained seed zero-shot in 4-goal Goal Cycle with and without two random
    distractors: its summary holds, per environment, each condition's per-seed learner returns and the
    experts' (the expert slots only, not the distractors), and its figure draws one panel for each."""
    from types import SimpleNamespace

    recipe, scale = recipes.RECIPES["distractors"], recipes.TINY
    specs = kinds.transfer_specs(recipe, scale)
    assert specs == [
        f"{name}:width=7,height=7,max_steps=20"
        for name in ("goalcycle4", "goalcycle4-distractors", "goalcycle3-distractors")
    ]
    learner = {"solo_pred": [0.5, -1.0], "social_pred": [12.0, 14.0], "social_pred_distractors": [3.0, 9.0]}
    seed_dirs, rows = {}, {}
    for c, returns in learner.items():
        seed_dirs[c] = [tmp_path / c / f"s{seed}" for seed in range(len(returns))]
        rows[c] = [_rows([r] * 10, [2] * 10) for r in returns]
        for seed_dir, r in zip(seed_dirs[c], returns, strict=True):
            for spec in specs:
                others = [("expert", 40.0, [39.0, 41.0]), ("expert", 44.0, [43.0, 45.0])]
                if "distractors" in spec:
                    others += [("random", -2.0, [-3.0, -1.0])] * 2
                results = [
                    {"kind": k, "mean_return": m, "ci95": ci} for k, m, ci in [("learner", r, None)] + others
                ]
                kinds.eval_path(seed_dir, spec).parent.mkdir(parents=True, exist_ok=True)
                jsonio.write_json(kinds.eval_path(seed_dir, spec), {"results": results})
    configs = {c: recipes.condition_config(scale, c, 0, 1, str(tmp_path)) for c in learner}
    runs = SimpleNamespace(
        recipe=recipe, scale=scale, rows=rows, configs=configs, seed_dirs=seed_dirs, lenders={}
    )
    summary = kinds.summarise_curves(runs)
    assert list(summary)[-2:] == ["zero_shot", "conditions"]
    for spec in specs:
        per_cond = summary["zero_shot"][spec]
        for c, returns in learner.items():
            assert per_cond[c]["final_returns"] == returns
            assert per_cond[c]["mean"] == pytest.approx(np.mean(returns))
        assert per_cond["experts"]["mean"] == 42.0
        assert [slot["mean"] for slot in per_cond["experts"]["per_slot"]] == [40.0, 44.0]
    assert "zero_shot" not in kinds.summarise_curves(
        SimpleNamespace(**{**vars(runs), "recipe": recipes.RECIPES["imperfect"]})
    )
    plt = plot_figures.pyplot()
    fig, axes = plt.subplots(1, 3)
    colors = plt.get_cmap("tab10").colors
    drawn = [
        "social_pred",
        "solo_pred",
        "social_pred_distractors",
    ]  # the other panels' order, not the summary's
    plot_figures.draw_zero_shot(axes, summary["zero_shot"], drawn, colors)
    faces = [tuple(p.get_facecolor()[:3]) for p in axes[0].patches]  # the bars in the summary's order
    shown = [*learner, "experts"]
    assert faces == [tuple(colors[drawn.index(n)]) if n in drawn else (0.3, 0.3, 0.3) for n in shown]
    assert [ax.get_title() for ax in axes] == [
        "4-goal Goal Cycle, 7x7, max steps 20",
        "4-goal Goal Cycle with distractors, 7x7, max steps 20",
        "3-goal Goal Cycle with distractors, 7x7, max steps 20",
    ]
    assert [t.get_text() for t in axes[1].get_xticklabels()][-1] == "its scripted experts"
    plt.close(fig)


@pytest.mark.slow
def test_figure_leaves_out_conditions_not_run(mixing_runs, tmp_path):
    """h1 shares social_pred with mixing; its other conditions were not run here."""
    cli.main(["figure", "h1", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(mixing_runs),
              "--out-dir", str(tmp_path)])  # fmt: skip
    summary = json.loads((tmp_path / "h1-tiny.json").read_text())
    assert summary["missing_conditions"] == ["solo_pred", "social_none", "social_rec"]
    assert list(summary["conditions"]) == ["social_pred"]
    assert (tmp_path / "h1-tiny.png").stat().st_size > 1000


def test_no_train_trains_nothing_and_says_what_it_skipped(tmp_path, capsys):
    cli.main(
        ["run", "fig5_transfer", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(tmp_path), "--no-train"]
    )
    out = capsys.readouterr().out
    for name in recipes.RECIPES["fig5_transfer"].conditions:
        assert f"{name}: not trained (--no-train); its unfinished seeds are not evaluated" in out
    figure = f"figure fig5_transfer --scale tiny --seed 0 --seeds 1 --runs-dir {tmp_path}"
    assert f"next: python -m jaxsocial.experiments {figure}" in out
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_no_train_evaluates_the_conditions_trained_elsewhere(mixing_runs, capsys):
    """transfer's social_pred was trained by the mixing recipe; its solo_pred and bc were not."""
    cli.main(
        [
            "run",
            "fig5_transfer",
            "--scale",
            "tiny",
            "--seeds",
            "1",
            "--runs-dir",
            str(mixing_runs),
            "--no-train",
        ]
    )
    out = capsys.readouterr().out
    assert "solo_pred: not trained" in out and "bc: not trained" in out
    cfg = recipes.condition_config(recipes.TINY, "social_pred", 0, 1, str(mixing_runs))
    (seed_dir,) = runner.config_seed_dirs(cfg)
    for spec in kinds.transfer_specs(recipes.RECIPES["fig5_transfer"], recipes.TINY):
        result = json.loads(kinds.eval_path(seed_dir, spec).read_text())
        assert result["checkpoints"] == [str(seed_dir)]
        assert f"social_pred {seed_dir.name} in {spec}" in out


@pytest.mark.slow
def test_ct_recipe_trains_evaluates_and_summarises(mixing_runs, tmp_path):
    """The ct recipe reuses mixing's social PPO + pred run, trains the three others, writes each seed's CT
    evaluation and summarises the scores from those files."""
    cli.main(["run", "ct", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(mixing_runs)])
    cli.main(["figure", "ct", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(mixing_runs),
              "--out-dir", str(tmp_path)])  # fmt: skip
    summary = json.loads((tmp_path / "ct-tiny.json").read_text())
    assert (tmp_path / "ct-tiny.png").stat().st_size > 1000
    assert list(summary["conditions"]) == list(recipes.RECIPES["ct"].conditions)
    for name, entry in summary["conditions"].items():
        cfg = recipes.condition_config(recipes.TINY, name, 0, 1, str(mixing_runs))
        (seed_dir,) = runner.config_seed_dirs(cfg)
        result = json.loads(kinds.ct_path(seed_dir, recipes.TINY).read_text())
        assert result["protocol"] == "ct" and result["checkpoints"] == [str(seed_dir)]
        assert entry["ct"]["final_returns"] == [round(result["ct"]["mean"], 4)]
        assert entry["recall"]["final_returns"] == [round(result["recall"]["mean"], 4)]
        assert entry["final_returns"] == [round(metrics.final_return(rundir.read_metrics(seed_dir)), 4)]
    medal = recipes.condition_config(recipes.TINY, "social_medal", 0, 1, str(mixing_runs))
    assert "attention_loss/0" in rundir.read_metrics(runner.config_seed_dirs(medal)[0])[-1]
    assert set(summary["separated_ci95"]) == {"final", "ct", "recall"}


def test_figures_name_environments_and_scales_for_people():
    assert plot_figures.env_title("goalcycle4:width=9,height=9") == "4-goal Goal Cycle, 9x9"
    assert (
        plot_figures.env_title("goalcycle3-solo:penalty=0,max_steps=20")
        == "3-goal Goal Cycle alone, penalty 0, max steps 20"
    )
    assert plot_figures.env_title("fourrooms") == "Four Rooms"

    class Runs:  # what `scale_title` reads of a RecipeRuns
        scale, seed, seeds = recipes.TINY, 0, 2
        configs = {"a": recipes.condition_config(recipes.TINY, "social_pred", 0, 2, "runs")}

    assert plot_figures.scale_title(Runs) == (
        "tiny scale (plumbing only: it learns nothing): 256 env-steps per seed, seeds 0-1"
    )


def test_time_to_learning_and_run_in_cpu_minutes_where_the_record_says_the_cores(tmp_path):
    """A seed's CPU-minutes to takeoff: its training seconds (from the logged env-steps/s) to the takeoff
    times its recorded cores; None for a seed whose record does not say them."""
    seed_rows = [
        {"iteration": i + 1, "env_steps_per_s": 5.0, "return/0": 0.0 if i < 50 else 5.0, "episodes/0": 1}
        for i in range(100)
    ]  # 10 env-steps an iteration at 5 a second: 2 s an iteration
    recorded, unrecorded = tmp_path / "a", tmp_path / "b"
    recorded.mkdir()
    jsonio.write_json(recorded / "provenance.json", {"run": {"cores": 2}})

    class Runs:  # what `takeoffs` reads of a RecipeRuns
        rows = {"social_rec": [seed_rows, seed_rows]}
        configs = {"social_rec": dataclasses.replace(config.TrainConfig(), num_envs=2, rollout_steps=5)}
        seed_dirs = {"social_rec": [recorded, unrecorded]}

    entry = kinds.takeoffs(Runs)["social_rec"]
    lift = entry["takeoff_iterations"][0]
    assert lift > 50 and entry["takeoff_env_steps"][0] == lift * 10
    assert entry["takeoff_cpu_minutes"] == [pytest.approx(lift * 2.0 * 2 / 60, abs=0.01), None]
    assert entry["cores"] == [2, None]
    assert entry["cpu_minutes"] == [pytest.approx(100 * 2.0 * 2 / 60, abs=0.01), None]  # the whole run


@pytest.mark.parametrize("scale", [s for s in recipes.SCALES.values() if s.rate is not None])
def test_a_scales_rate_is_read_from_its_single_core_benchmark(scale):
    """The rate a cost estimate rests on is the one its committed benchmark JSON measured (HEAD tree), in a
    single-core process."""
    rate = read_rate(scale.rate)
    data = json.loads((Path(__file__).resolve().parents[1] / scale.rate.path).read_text())
    rows = [r for r in data["sections"]["recipe"]["rows"] if r.get("recipe") == scale.rate.row]
    assert rate.env_steps_per_s == rows[0]["best_env_steps_per_s"] and rows[0].get("tree", "HEAD") == "HEAD"
    assert rate.machine.startswith("one core of an ")


def test_run_states_its_cost_before_training_and_ends_with_the_figure_command(tmp_path, capsys):
    cost = recipes.cost(recipes.LAPTOP, 4, 21_351 * 60, 2)
    assert cost.startswith("4 runs x 1.28M env-steps: about 5 CPU-minutes, 2 minutes on 2 core(s)")
    cli.main(["run", "h1", "--scale", "laptop", "--seeds", "2", "--runs-dir", str(tmp_path), "--dry-run",
              "--cores", "0", "1"])  # fmt: skip
    assert "[h1/laptop] to train: 8 runs x 20.00M env-steps" in capsys.readouterr().out
    assert recipes.cost(recipes.TINY, 1, 100, 1) is None


def test_a_run_that_another_process_trains_is_left_to_it(tmp_path, capsys):
    """Two runners on one recipe (a core freed while the other trains): a run whose lock a live process holds,
    begun or only just started, is neither started, resumed nor counted by the second; released, a begun
    run is resumed as before. A job whose run another process took after it was planned is not started."""
    solo = tmp_path / "tiny" / "solo_pred_nopenalty-s0-0"
    begun = tmp_path / "tiny" / "social_pred_nopenalty-s0-0"
    begun.mkdir(parents=True)
    (begun / rundir.CONFIG_FILE).write_text("{}")
    argv = ["run", "no_penalty", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(tmp_path), "--dry-run"]
    with RunLock(begun), RunLock(solo):  # `solo` only just started: no config yet
        cli.main([*argv, "--cores", "0"])
    out = capsys.readouterr().out
    assert (
        f"social_pred_nopenalty: {rundirs.TRAINING}\n" in out
        and f"solo_pred_nopenalty: {rundirs.TRAINING}\n" in out
    )
    assert "[no_penalty/tiny] to train:" not in out, out
    cli.main([*argv, "--cores", "0"])
    out = capsys.readouterr().out
    assert "social_pred_nopenalty: partial\n" in out and "[no_penalty/tiny] to train: 2 runs" in out

    fresh = pinned.Job("fresh", ("-c", "pass"), begun, afresh=True)  # planned before `begun` was begun
    held = pinned.Job("held", ("-c", "pass"), solo)
    with RunLock(solo):
        assert pinned.run([fresh, held], [0]) == [None, None]
    out = capsys.readouterr().out
    assert "fresh: begun by another process since this run was planned, left to it" in out
    assert "held: training now in another process, left to it" in out
    assert not fresh.log.exists() and not held.log.exists()


def test_figure_compares_ones_runs_with_the_committed_summary():
    def condition(k, finals, mean, ci):
        return {"seeds_above_one_tile": k, "final_returns": finals, "mean": mean, "ci95": ci}

    mine = {"conditions": {"social_pred": condition(0, [0.1, 0.3, 0.4], 0.255, [-0.1, 0.6])}}
    committed = {"conditions": {"social_pred": condition(0, [0.0, 0.9, 0.2], 0.38, [-0.12, 0.87]),
                                "solo_pred": condition(1, [3.0], 3.0, None)}}  # fmt: skip
    (line,) = summaries.against_committed(mine, committed)
    assert line == (
        "social PPO + aux pred: yours 0 of 3 past the plateau, final return 0.255; committed 0 of 3, 0.38 "
        "[-0.12, 0.87]: yours is inside its 95% interval"
    )
    mine["conditions"]["social_pred"]["mean"] = 2.0
    assert summaries.against_committed(mine, committed)[0].endswith("yours is outside its 95% interval")


@pytest.mark.slow
def test_vmapped_seed_programs_write_one_record_per_seed(tmp_path, capsys):
    """--vmap-seeds 2 over 3 seeds: programs s0-1 (vmapped) and s2-2; every seed is read, recorded and
    summarised on its own, as with one program per seed."""
    runs, out = tmp_path / "runs", tmp_path / "records"
    cli.main(["run", "predictions", "--scale", "tiny", "--seeds", "3", "--vmap-seeds", "2",
              "--runs-dir", str(runs)])  # fmt: skip
    dirs = runner.condition_seed_dirs(recipes.TINY, "social_pred", 0, 3, str(runs))
    assert dirs == [runs / "tiny/social_pred-s0-1/s0", runs / "tiny/social_pred-s0-1/s1",
                    runs / "tiny/social_pred-s2-2"]  # fmt: skip
    assert rundir.read_config(runs / "tiny/social_pred-s0-1")["seed_batching"] == "vmap"
    log = tmp_path / "commands.log"
    log.write_text("".join(
        f"2026-01-01T00:00:00 {'a' * 40} python -m jaxsocial.train --run-name tiny/social_pred-{name}\n"
        for name in ("s0-1", "s2-2")
    ))  # fmt: skip
    record = ["record", "predictions", "--scale", "tiny", "--seeds", "3", "--runs-dir", str(runs)]
    cli.main([*record, "--out-dir", str(out), "--commands-log", str(log), "--device", "test", "--jax", "0",
              "--allow-dirty"])  # fmt: skip
    for seed, record in enumerate([out / "tiny/social_pred-s0-1/s0", out / "tiny/social_pred-s0-1/s1",
                                   out / "tiny/social_pred-s2-2"]):  # fmt: skip
        assert rundir.read_config(record)["seed"] == seed and len(rundir.read_metrics(record)) == 4
    with pytest.raises(SystemExit):
        cli.main(["run", "predictions", "--scale", "tiny", "--vmap-seeds", "0", "--dry-run"])


@needs_records("records/tiny")
def test_a_designs_evaluations_are_written_blind(tmp_path, capsys):
    """A design at its own scale (runs under `<scale>/prereg-<design>/`) evaluates its finished seeds without
    showing a score: the committed tiny records, one seed's evaluations deleted, as a design's runs."""
    recipe = dataclasses.replace(recipes.RECIPES["no_penalty"], design="h1_laptop")
    scale = dataclasses.replace(recipes.TINY, runs_subdir="prereg-test")
    records = Path(__file__).parents[1] / paths.RECORDS / "tiny"
    shutil.copytree(records, tmp_path / scale.runs_root)
    seed_dir = tmp_path / scale.runs_root / "solo_pred_nopenalty-s0-1" / "s1"
    shutil.rmtree(seed_dir / "eval")
    runner.run(recipe, scale, 0, 2, str(tmp_path), train_missing=False)
    out = capsys.readouterr().out
    (evaluation, spec, written), *_ = kinds.evaluation_outputs(recipe, scale, seed_dir)
    assert written.exists()
    assert f"solo_pred_nopenalty s1 in {spec} ({evaluation.protocol}): written (blind" in out
    assert not re.search(r"\): -?\d", out)  # no score printed, for any seed
