"""The exploratory sweep: settings that parse, takeoff in env-steps and CPU-minutes from a hand-built run,
and seeds outside the exploratory range refused."""

import dataclasses
import json
import shutil

import numpy as np
import pytest
from conftest import needs_records

from jaxsocial import train
from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments import sweep
from jaxsocial.experiments.analyse import records, rundirs, sweep_results, takeoff
from jaxsocial.experiments.launch import sweep_runs
from jaxsocial.experiments.plan import catalogue, paths, recipes, sweep_settings
from jaxsocial.run import checkout, jsonio, provenance, rundir
from jaxsocial.run.metrics import LEARNED_RETURN


def test_every_setting_file_loads():
    files = sorted(sweep_settings.SETTINGS_DIR.glob("*.json"))
    assert len(files) >= 23 and list(sweep_settings.SETTINGS) == [f.stem for f in files]
    assert all(sweep_settings.load_setting(f) == sweep_settings.SETTINGS[f.stem] for f in files)


@pytest.mark.parametrize(
    "change, named",
    [
        ({"flags": "--ppo.num-minibatches 8"}, "field 'flags'"),
        ({"iterations": 0}, "field 'iterations'"),
        ({"condition": "social_nothing"}, "field 'condition'"),
        ({"name": "other"}, "field 'name'"),
        ({"seeds": 3}, "unknown field 'seeds'"),
        ({"why": None}, "field 'why'"),
    ],
)
def test_a_bad_setting_file_is_refused_naming_the_file_and_field(tmp_path, change, named):
    good = jsonio.read_json(sweep_settings.SETTINGS_DIR / "mb8k8_rec.json")
    path = jsonio.write_json(tmp_path / "mb8k8_rec.json", {**good, **change})
    with pytest.raises(ValueError, match=f"{path}: .*{named}"):
        sweep_settings.load_setting(path)
    del good["why"]
    jsonio.write_json(path, good)
    with pytest.raises(ValueError, match=f"{path}: missing field 'why'"):
        sweep_settings.load_setting(path)
    path.write_text("{")
    with pytest.raises(ValueError, match=f"{path}: not JSON"):
        sweep_settings.load_setting(path)


@pytest.mark.parametrize("name", sorted(sweep_settings.SETTINGS))
def test_every_setting_parses_to_its_flags(name):
    setting = sweep_settings.SETTINGS[name]
    cfg = train.parse_args(sweep_settings.train_flags(setting, 3, "runs/x"))
    assert cfg.iterations == setting.iterations and cfg.seed == 3 and cfg.run_name == f"{name}-s3"
    assert cfg.num_envs * cfg.rollout_steps * setting.iterations >= 20_000_000  # the goal's horizon
    if "--ppo.num-minibatches" in setting.flags:
        value = setting.flags[setting.flags.index("--ppo.num-minibatches") + 1]
        assert cfg.ppo.num_minibatches == int(value)  # the setting's flag overrides the scale's


@pytest.mark.parametrize(
    "condition, setting",
    [
        ("social_rec", "mb8k8_rec_7x7"),
        ("solo_pred", "mb8k8_solo_pred_7x7"),
        ("social_none", "mb8k8_none_7x7"),
    ],
)
def test_the_laptop_scale_is_the_sweeps_7x7_setting(condition, setting):
    """What the sweep screened is what the `laptop` scale (and `--preset laptop`) trains: every field but the
    preset's name, the run's name and the sweep's early stop."""
    laptop = recipes.condition_config(recipes.LAPTOP, condition, 3, 1, "runs/x")
    swept = train.parse_args(sweep_settings.train_flags(sweep_settings.SETTINGS[setting], 3, "runs/x"))
    differ = {f.name for f in dataclasses.fields(laptop) if getattr(laptop, f.name) != getattr(swept, f.name)}
    assert differ == {"preset", "run_name", "stop_at_return"}
    assert train.parse_args(["--preset", "laptop"]).net.aux == "rec"  # the demo: social PPO + rec


def hand_built_run(path, returns, sps, cores):
    """A seed directory of 2 envs x 5 steps a row (10 env-steps), one learner episode a row."""
    path.mkdir(parents=True)
    jsonio.write_json(
        path / rundir.CONFIG_FILE, {"seed": 7, "num_envs": 2, "rollout_steps": 5, "iterations": 4}
    )
    rows = [
        {"iteration": i + 1, "env_steps_per_s": sps, "return/0": r, "episodes/0": 1, "return/1": 30.0,
         "episodes/1": 1}
        for i, r in enumerate(returns)
    ]  # fmt: skip
    (path / rundir.METRICS_FILE).write_text("".join(json.dumps(r) + "\n" for r in rows))
    jsonio.write_json(path / "provenance.json", {"run": {"cores": cores}})


def test_takeoff_in_env_steps_and_cpu_minutes(tmp_path, monkeypatch):
    monkeypatch.setattr(takeoff, "WINDOW_STEPS", 20)  # windows of 2 rows
    hand_built_run(tmp_path / "run", [0.0, 1.0, LEARNED_RETURN + 1, LEARNED_RETURN + 3], sps=0.5, cores=2)
    s = sweep_results.seed_summary(tmp_path / "run")
    # Windows: rows 1-2 (mean 0.5), rows 3-4 (mean above the threshold): takeoff at the end of row 4.
    assert s["takeoff_env_steps"] == 40 and s["env_steps"] == 40
    assert s["takeoff_cpu_minutes"] == pytest.approx(4 * 10 / 0.5 * 2 / 60)  # 4 rows of 20 s, on 2 cores
    assert s["expert_final_return"] == [30.0]
    np.testing.assert_allclose(s["curve"]["return"], [0.5, LEARNED_RETURN + 2])


def test_a_seed_on_the_plateau_has_no_takeoff(tmp_path):
    hand_built_run(tmp_path / "run", [1.0, 0.9, 1.1, LEARNED_RETURN], sps=10.0, cores=1)
    # not above the threshold
    assert sweep_results.seed_summary(tmp_path / "run")["takeoff_env_steps"] is None


def test_run_resumes_an_unfinished_seed_and_skips_a_finished_one(tmp_path, monkeypatch):
    """`run` again after a stopped sitting: a seed with a run directory resumes (`--resume`), a finished
    one (every iteration, or stopped early past the plateau) does not train, a missing one starts."""
    setting = dataclasses.replace(sweep_settings.SETTINGS["map_g4_rec_7x7"], iterations=4)
    started = []
    fake_run = lambda jobs, cores: [started.append(j.argv) or 0 for j in jobs]  # noqa: E731
    monkeypatch.setattr(sweep_runs.pinned, "run", fake_run)
    hand_built_run(tmp_path / f"{setting.name}-s0", [1.0, 1.0, 1.0, 1.0], sps=1.0, cores=1)  # done
    hand_built_run(tmp_path / f"{setting.name}-s1", [1.0, 1.0], sps=1.0, cores=1)  # partial
    assert sweep_runs.run(setting, [0, 1, 2], str(tmp_path), [0]) == [0, 0]
    assert [argv[argv.index("--seed") + 1] for argv in started] == ["1", "2"]
    assert "--resume" in started[0] and "--resume" not in started[1]
    assert sweep_runs.seed_state(setting, 2, str(tmp_path)) == "missing"


def test_extend_starts_a_longer_budget_from_the_finished_shorter_run(tmp_path, capsys):
    short = dataclasses.replace(sweep_settings.SETTINGS["map_g4_rec_7x7"], iterations=4)
    long = dataclasses.replace(sweep_settings.SETTINGS["map_g4_40m_rec_7x7"], iterations=8)
    runs = str(tmp_path)
    hand_built_run(tmp_path / f"{short.name}-s0", [1.0] * 4, sps=1.0, cores=1)
    jsonio.write_json(tmp_path / f"{short.name}-s0" / provenance.RUN_FILE, {"command": "first", "ended": "t"})
    sweep_runs.extend(short, long, [0], runs)
    copied = tmp_path / f"{long.name}-s0"
    assert jsonio.read_json(copied / provenance.RUN_FILE)["command"] == "first"  # the earlier process
    assert len(rundir.read_metrics(copied)) == 4 and sweep_runs.seed_state(long, 0, runs) == "partial"
    with pytest.raises(ValueError, match="exists: extend only starts a run"):
        sweep_runs.extend(short, long, [0], runs)
    with pytest.raises(ValueError, match="their flags differ"):
        sweep_runs.extend(sweep_settings.SETTINGS["map_g4_pen1_rec_7x7"], long, [1], runs)
    with pytest.raises(ValueError, match="not fewer than"):
        sweep_runs.extend(long, short, [1], runs)
    hand_built_run(tmp_path / f"{short.name}-s1", [1.0] * 2, sps=1.0, cores=1)  # unfinished
    with pytest.raises(ValueError, match="not a finished run"):
        sweep_runs.extend(short, long, [1], runs)
    hand_built_run(tmp_path / f"{short.name}-s2", [1.0] * 4, sps=1.0, cores=1)  # finished, but not by `run`
    with pytest.raises(ValueError, match="not a finished run"):
        sweep_runs.extend(short, long, [2], runs)
    took_off = tmp_path / f"{short.name}-s3"
    hand_built_run(took_off, [1.0, 6.0], sps=1.0, cores=1)
    config = rundir.read_config(took_off) | {"stop_at_return": 5.0, "chunk_iterations": 1}
    jsonio.write_json(took_off / rundir.CONFIG_FILE, config)
    rows = [r | {"kl/0": 0.0} for r in rundir.read_metrics(took_off)]  # slot 0 is a learner
    (took_off / rundir.METRICS_FILE).write_text("".join(json.dumps(r) + "\n" for r in rows))
    jsonio.write_json(took_off / provenance.RUN_FILE, {"command": "first", "ended": "t"})
    assert sweep_runs.seed_state(short, 3, runs) == "finished"  # stopped early at return 6 >= 5
    assert rundirs.finished(took_off, 4) and not rundirs.finished(tmp_path / f"{short.name}-s1", 4)
    # a recipe's run (its seed directories given) is not resumed past its stop either
    assert rundirs.run_state(tmp_path / long.name, long.iterations, [took_off]) == rundirs.FINISHED
    with pytest.raises(ValueError, match="stopped early past the plateau"):
        sweep_runs.extend(short, long, [3], runs)
    assert not any((tmp_path / f"{long.name}-s{s}").exists() for s in (1, 2, 3))


@pytest.mark.parametrize("command", [sweep.main, cli.main])
def test_confirmatory_seeds_are_refused(command, capsys):
    """`experiments sweep run SETTING` and `experiments run SETTING` (a sweep setting's name: its kind) are
    one command."""
    with pytest.raises(SystemExit):
        command(["run", "mb8k8_rec", "--seeds", "200"])
    assert "seeds must be in 0-99" in capsys.readouterr().err


def test_a_setting_takes_only_the_sweeps_verbs_and_no_name_is_two_things():
    with pytest.raises(SystemExit, match="the sweep setting mb8k8_rec takes run, record"):
        cli.main(["figure", "mb8k8_rec"])
    others = {*recipes.RECIPES, *catalogue.design_names()}
    assert not set(sweep_settings.SETTINGS) & others


def test_the_map_pairs_social_and_solo_settings_that_both_have_records():
    def setting(lifts, finals, experts):
        seeds = [
            {
                "seed": i,
                "takeoff_env_steps": t,
                "env_steps": 20_000_000,
                "final_return": f,
                "expert_final_return": e,
            }
            for i, (t, f, e) in enumerate(zip(lifts, finals, experts, strict=True))
        ]
        return {"seeds": seeds, "took_off": sum(t is not None for t in lifts), "n": len(lifts)}

    settings = {"map_g4_rec_7x7": setting([4_000_000, None], [9.5, 0.875], [[40.0, 42.0], [44.0, 46.0]]),
                "map_g4_solo_rec_7x7": setting([None, None], [0.5, 1.25], [[], []]),
                "mb8k8_rec_8x8": setting([60], [3.0], [[30.0, 30.0]])}  # fmt: skip
    summary = {"window_env_steps": 20, "learned_return": 2.0, "settings": settings}
    found = sweep_results.summarise_map(summary)
    assert list(found["cells"]) == ["7x7, 4 goals, rec"]  # 8x8 has no solo records here: left out
    cell = found["cells"]["7x7, 4 goals, rec"]
    assert cell["social"]["takeoff_env_steps"] == [4_000_000, None] and cell["solo"]["took_off"] == 0
    assert cell["social"]["seeds"] == [0, 1] and cell["solo"]["final_return"] == [0.5, 1.25]
    assert (
        cell["social"]["expert_mean_final_return"] == 43.0
        and cell["solo"]["expert_mean_final_return"] is None
    )
    table = sweep_results.map_table(found)
    assert table[-1] == "| 7x7, 4 goals, rec | 1 of 2 | 0 of 2 | 4.00M, -; -, - | 20.0M | 43.0 |"
    assert all(social.startswith(("map_", "mb8k8_")) and solo for _, social, solo in sweep_settings.MAP_PAIRS)
    assert {name for pair in sweep_settings.MAP_PAIRS for name in pair[1:]} <= set(sweep_settings.SETTINGS)


def test_the_experiments_command_reaches_the_sweep(capsys):
    from jaxsocial.experiments import __main__ as cli

    cli.main(["sweep", "list"])
    assert "map_g4_rec_7x7: social_rec" in capsys.readouterr().out


@needs_records("records/tiny")
def test_record_packs_each_ended_seed_once_with_what_its_process_measured(tmp_path, capsys):
    """`record` reads every seed's process file before it packs any (a failed run records none), takes the
    CPU and jax that process measured, and keeps the records already made."""
    setting = sweep_settings.SETTINGS["map_g4_rec_7x7"]
    tiny = sorted((paths.RECORDS / "tiny").rglob(records.PROVENANCE_FILE))[0].parent
    runs, out = tmp_path / "runs", tmp_path / "records"
    seed_dirs = [sweep_settings.run_dir(setting, seed, str(runs)) for seed in (0, 1)]
    for seed_dir, rc in zip(seed_dirs, (0, 1), strict=True):
        shutil.copytree(tiny, seed_dir, ignore=shutil.ignore_patterns(records.PROVENANCE_FILE))
        provenance.write_run_file(
            seed_dir, "python -m jaxsocial.train", checkout.tree(), 1, provenance.now(), rc
        )
    with pytest.raises(ValueError, match="exited with 1; not a result to record"):
        sweep_runs.record(setting, [0, 1], str(runs), None, out)
    assert not out.exists()
    provenance.write_run_file(
        seed_dirs[1], "python -m jaxsocial.train", checkout.tree(), 1, provenance.now(), 0
    )
    written = sweep_runs.record(setting, [0, 1], str(runs), None, out)
    assert written == [out / "sweep" / setting.name / f"s{seed}" for seed in (0, 1)]
    run = jsonio.read_json(written[0] / records.PROVENANCE_FILE)["run"]
    process = jsonio.read_json(seed_dirs[0] / provenance.RUN_FILE)
    assert (
        run["jax"] == process["versions"]["jax"] and run["device"] == f"{process['cpu']}, one core per seed"
    )
    assert sweep_runs.record(setting, [0, 1], str(runs), "a CPU", out) == []
    assert capsys.readouterr().out.count("already recorded, kept") == 2
