"""Branch designs (`experiments.branch_design`): the committed `mixing` design, its runs' commands, the
analysis of recorded branches against scipy, and a refused design."""

import dataclasses
import datetime
import json
import math
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import TINY, TINY_ENV_ARGS, needs_records
from scipy import stats as scipy_stats

from jaxsocial import stats, train
from jaxsocial.experiments import kind_commands
from jaxsocial.experiments.analyse import branch_results as br
from jaxsocial.experiments.analyse import kinds, power, records, rundirs, verdicts
from jaxsocial.experiments.launch import branch_runs, pinned
from jaxsocial.experiments.plan import branch_design as bd
from jaxsocial.experiments.plan import catalogue, designs, paths
from jaxsocial.run import checkout, jsonio, metrics, provenance, rundir
from jaxsocial.run.flags import config_flags
from jaxsocial.run.provenance import PARENT_WRITES
from jaxsocial.specs import CheckpointRef

MIXING = designs.load("mixing")
RUNS = Path("runs-nowhere")


@needs_records("records/laptop/prereg-experts")
def test_the_mixing_design_branches_every_experts_record_in_its_arm():
    assert not branch_runs.missing_sources(MIXING, paths.RECORDS)
    assert [MIXING.paired(t) for t in MIXING.primary.values()] == [True, False]
    for arm, k in (("mixed", 0), ("social", 7), ("alone", 39)):
        seed = MIXING.seed + k
        cfg = branch_runs.branch_config(MIXING, arm, seed, RUNS, paths.RECORDS)
        source = paths.RECORDS / "laptop/prereg-experts" / f"{MIXING.arms[arm].source}-s{seed}-{seed}"
        assert cfg.init_from == CheckpointRef(source)
        assert (cfg.seed, cfg.seeds, cfg.iterations, cfg.eval_every) == (400 + k, 1, 610, 610)
        assert cfg.blind and not cfg.resume and cfg.eval_episodes == 256
        assert cfg.run_name == f"laptop/prereg-mixing/{arm}-s{seed}"
        assert f"{cfg.env}:{','.join(f'{k}={v}' for k, v in cfg.env_args)}" == MIXING.arms[arm].env
        assert [str(e) for e in cfg.eval_envs] == list(MIXING.eval_envs)
        assert train.parse_args(config_flags(cfg)) == cfg  # the command `run` starts trains exactly this
    social = branch_runs.branch_config(MIXING, "social", MIXING.seed, RUNS, paths.RECORDS)
    mixed = branch_runs.branch_config(MIXING, "mixed", MIXING.seed, RUNS, paths.RECORDS)
    assert dataclasses.replace(mixed, env_args=social.env_args, run_name=social.run_name) == social


@pytest.mark.slow
def test_the_mixing_design_and_its_amendment_have_the_power_they_state():
    assert power.stated_power(MIXING) == MIXING.power_simulation["power"]
    planning = MIXING.power_simulation["power"][f"discount {MIXING.power_simulation['planning_discount']:g}"]
    assert MIXING.power == planning[MIXING.power_simulation["planning_test"]]
    added = MIXING.amendment
    assert power.stated_power(MIXING, amendment=True) == added.power_simulation["power"]
    planning = added.power_simulation["power"][f"discount {added.power_simulation['planning_discount']:g}"]
    assert added.power == planning[added.power_simulation["planning_test"]]


@needs_records("records/laptop/prereg-experts")
def test_where_the_branches_started_is_the_experts_designs_own_evaluation():
    """The start of every branch, alone in 3-goal and beside new experts in 4-goal, is what the committed
    experts summary says of its source record; beside the experts in 3-goal it was not evaluated."""
    started = br.start_scores(MIXING, paths.RECORDS)
    experts = jsonio.read_json(paths.SCIENCE / "experts-laptop.json")["conditions"]
    solo3, gc4, gc3 = MIXING.eval_envs
    for source in MIXING.sources():
        row = started[bd.start_row(source)]
        assert row[solo3] == [round(v, 4) for v in experts[source]["solo3"]["per_seed"]]
        assert row[gc4] == [round(v, 4) for v in experts[source]["goalcycle4"]["per_seed"]]
        assert row[gc3] == [None] * MIXING.seeds


def test_the_amendment_tests_each_branch_against_where_it_started():
    """The amendment's two tests pair a branch with its own source record; the design's tests are as
    committed, and the pilot's differences point the way each test looks."""
    assert list(MIXING.amendment.tests) == ["social_fades", "mixed_gains"]
    assert all(MIXING.paired(t) for t in MIXING.amendment.tests.values())
    fades = MIXING.amendment.tests["social_fades"]
    assert (fades.treatment, fades.control, fades.alternative) == ("social", "start", "less")
    assert MIXING.control_row(fades) == "social_rec at the branch"
    assert list(MIXING.primary) == ["mixed_vs_social", "mixed_vs_alone"] and MIXING.sources() == (
        "social_rec",
        "solo_rec",
    )
    pilot = power.pilot_scores(MIXING, amendment=True)
    follow_up = jsonio.read_json(Path(MIXING.amendment.power_simulation["pilot_branches"]))
    solo3 = fades.env
    social = [s for s in follow_up["seeds"].values() if s["condition"].startswith("social")]
    assert pilot["social_fades"]["differences"] == [
        s["zero_shot"][solo3]["learner"] - s["branches"]["social"][solo3] for s in social
    ]  # a fall is positive
    committed = catalogue.commit_time(catalogue.file_commit(catalogue.amendment_path("mixing")))
    assert datetime.datetime.fromisoformat(committed) >= datetime.datetime.fromisoformat("2026-12-01T22:44Z")
    assert catalogue.commit_time(None) is None


def test_a_design_naming_an_unknown_arm_or_environment_is_refused(tmp_path, monkeypatch):
    raw = jsonio.read_json(catalogue.path_of("mixing"))
    monkeypatch.setattr(catalogue, "DESIGNS_DIR", tmp_path)
    raw["primary"]["mixed_vs_alone"]["control"] = "solo"
    raw["secondary"]["social_skill"]["env"] = "goalcycle4"
    (tmp_path / "bad.json").write_text(json.dumps(raw | {"name": "bad"}))
    with pytest.raises(ValueError, match=r"arm 'solo' is not one of \['alone', 'mixed', 'social', 'start'\]"):
        designs.load("bad")
    with pytest.raises(FileNotFoundError, match=r"the designs are \['bad'\]"):
        designs.load("mixing")


def _fake_record(root: Path, design, arm: str, seed: int, scores: dict[str, float]) -> None:
    """A record of `arm`'s branch of `seed` with its final evaluations `scores` (env -> return) and the
    config and provenance `summarise` reads."""
    cfg = branch_runs.branch_config(design, arm, seed, RUNS, paths.RECORDS)
    directory = root / design.run_name(arm, seed)
    directory.mkdir(parents=True)
    config = {"iterations": cfg.iterations, "seed": cfg.seed, "env": cfg.env}
    config |= {
        "env_args": ",".join(f"{k}={v}" for k, v in cfg.env_args),
        "init_from": f"{cfg.init_from.run}@1464",
    }
    jsonio.write_json(directory / rundir.CONFIG_FILE, config)
    row = {metrics.ITERATION: design.iterations} | {metrics.eval_key(e): v for e, v in scores.items()}
    (directory / rundir.METRICS_FILE).write_text(json.dumps(row) + "\n")
    recorded = {"run": dict.fromkeys(provenance.RUN_FIELDS) | {"commit": "0" * 40, "device": "a CPU"}}
    jsonio.write_json(directory / records.PROVENANCE_FILE, recorded)


@needs_records("records/laptop/prereg-experts")
def test_a_paired_difference_is_the_t_interval_and_wilcoxon_of_the_differences():
    d = stats.paired_difference([1.0, 2.0, 4.0], [2.0, 4.0, 7.0], "greater")  # differences 1, 2, 3
    half = scipy_stats.t.ppf(0.975, 2) / math.sqrt(3)  # their standard deviation is 1
    assert d["n"] == 3 and d["mean"] == 2.0 and d["ci95"] == pytest.approx([2 - half, 2 + half], rel=1e-12)
    assert d["wilcoxon_p"] == scipy_stats.wilcoxon([1, 2, 3], alternative="greater").pvalue == 0.125
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no pairs: no statistics, and no warning of an empty mean
        assert stats.paired_difference([], []) == {"n": 0, "mean": None, "ci95": None, "wilcoxon_p": None}


@needs_records("records/laptop/prereg-experts")  # the branches' sources
def test_the_summary_tests_the_recorded_branches_as_scipy_does(tmp_path, monkeypatch):
    design = dataclasses.replace(MIXING, seeds=6)
    rng = np.random.default_rng(1)
    solo3, gc4, gc3 = design.eval_envs
    centres = {"mixed": 9.0, "social": 5.0, "alone": 6.0}
    values = {
        arm: {env: rng.normal(c, 3, 6).round(2) for env in design.eval_envs} for arm, c in centres.items()
    }
    for arm in design.arms:
        for k, seed in enumerate(design.seed_range):
            if (arm, k) != ("alone", 5):  # one branch not recorded yet
                _fake_record(
                    tmp_path, design, arm, seed, {e: float(values[arm][e][k]) for e in design.eval_envs}
                )
    started = rng.normal(7.0, 3, 6).round(2)  # where the social_rec records ended, alone in 3-goal
    for k, seed in enumerate(design.seed_range):
        evaluation = {"results": [{"slot": 0, "kind": "learner", "mean_return": float(started[k])}]}
        path = kinds.eval_path(design.record_of("social_rec", seed, tmp_path), solo3)
        path.parent.mkdir(parents=True)
        jsonio.write_json(path, evaluation)
    ended = {"mixed-s300": "2026-11-28T16:17:21+00:00", "social-s300": "2026-12-01T20:00:00-03:00"}
    for name, when in ended.items():  # one run ended before the amendment and one after (23:00 UTC)
        recorded = jsonio.read_json(tmp_path / design.out / name / records.PROVENANCE_FILE)
        recorded["run"]["ended"] = when
        jsonio.write_json(tmp_path / design.out / name / records.PROVENANCE_FILE, recorded)
    committed = catalogue.file_commit  # the design's commit as it is; the amendment's at 22:00 UTC
    amendment = catalogue.amendment_path(design.name)
    monkeypatch.setattr(
        catalogue, "file_commit", lambda path: "f" * 40 if path == amendment else committed(path)
    )
    monkeypatch.setattr(catalogue, "commit_time", lambda commit: "2026-12-01T22:00:00+00:00")
    summary = br.summarise(design, tmp_path)
    block = summary["preregistered"]
    paired = scipy_stats.wilcoxon(
        values["mixed"][solo3] - values["social"][solo3], alternative="greater"
    ).pvalue
    unpaired = scipy_stats.mannwhitneyu(
        values["mixed"][solo3], values["alone"][solo3][:5], alternative="greater"
    )
    assert block["primary"]["mixed_vs_social"]["p"] == pytest.approx(paired, rel=1e-5)
    assert block["primary"]["mixed_vs_alone"]["p"] == pytest.approx(unpaired.pvalue, rel=1e-5)
    assert block["primary"]["mixed_vs_alone"]["n"] == [6, 5]
    ps = sorted([paired, unpaired.pvalue])
    assert sorted(e["p_holm"] for e in block["primary"].values()) == pytest.approx(
        [min(1, 2 * ps[0]), min(1, max(2 * ps[0], ps[1]))], rel=1e-5
    )
    two_sided = scipy_stats.wilcoxon(values["mixed"][gc4] - values["social"][gc4]).pvalue
    assert block["secondary"]["social_skill"]["p"] == pytest.approx(two_sided, rel=1e-5)
    assert summary["environments"][gc3]["alone"]["per_seed"][5] is None
    assert summary["environments"][solo3]["mixed"]["mean"] == pytest.approx(
        values["mixed"][solo3].mean(), abs=1e-3
    )
    checks = block["checks"]
    assert not checks["every_branch_recorded"] and checks["branches_as_designed"] and not block["valid"]
    assert not checks["design_precedes_every_run"]  # commit 000... is no ancestor of the design
    assert "NOT VALID" in verdicts.verdict(summary)
    added = block["amendment"]
    assert added["tests"]["social_fades"]["arms"] == ["social", "social_rec at the branch"]
    fades = scipy_stats.wilcoxon(values["social"][solo3] - started, alternative="less").pvalue
    gains = scipy_stats.wilcoxon(values["mixed"][solo3] - started, alternative="greater").pvalue
    assert added["tests"]["social_fades"]["p"] == pytest.approx(fades, rel=1e-5)
    assert added["tests"]["mixed_gains"]["p"] == pytest.approx(gains, rel=1e-5)
    assert added["tests"]["social_fades"]["p_holm"] == pytest.approx(
        min(1, max(2 * min(fades, gains), fades)), rel=1e-5
    )
    assert summary["environments"][solo3]["social_rec at the branch"]["per_seed"] == list(started)
    assert summary["environments"][gc4]["solo_rec at the branch"]["per_seed"] == [None] * 6  # not evaluated
    assert added["checks"] == {
        "amendment_committed": True,
        "runs_ended_before_the_amendment": 1,
        "amendment_before_the_last_run_ended": True,
        "every_start_scored": True,
    }
    assert added["valid"] and added["committed"] == "2026-12-01T22:00:00+00:00"
    assert "amendment social_fades (wilcoxon" in verdicts.verdict(summary)
    shutil.rmtree(tmp_path / design.run_name("mixed", design.seed + 2))
    _fake_record(tmp_path, dataclasses.replace(design, iterations=5), "mixed", design.seed + 2, {solo3: 1.0})
    assert br.summarise(design, tmp_path)["preregistered"]["checks"]["differing"] == ["mixed-s302"]
    br.draw(summary, tmp_path / "mixing.png")
    assert (tmp_path / "mixing.png").stat().st_size > 0


@pytest.mark.slow
def test_a_branch_of_a_record_trains_is_recorded_and_summarised(tmp_path, capsys, monkeypatch):
    """The path a design's run takes, in this process: a TINY run packed as a record without checkpoint is
    the material; a branch trains from it with `branch_config`, and once it has the process file `pinned.run`
    writes, `record` packs it with the machine the file measured and `summarise` finds it as designed."""
    source = train.run(dataclasses.replace(TINY, runs_dir=str(tmp_path / "material-runs"), run_name="source"))
    records_root, runs_root = tmp_path / "records", tmp_path / "runs"
    run = dict.fromkeys(provenance.RUN_FIELDS)
    records.pack(source, records_root / "tiny/material/social-s0-0", run, "tiny/source")
    env, solo = f"goalcycle3:{TINY_ENV_ARGS}", f"goalcycle3-solo:{TINY_ENV_ARGS}"
    test = {"env": solo, "treatment": "mixed", "control": "social", "alternative": "greater"}
    raw = {
        "name": "tiny",
        "records": "tiny/material",
        "out": "tiny/branches",
        "seed": 0,
        "seeds": 1,
        "branch_seed": 400,
        "iterations": 2,
        "arms": {
            "mixed": {"source": "social", "env": f"{env},solo_prob=0.5"},
            "social": {"source": "social", "env": env},
        },
        "eval_envs": [solo],
        "episodes": 4,
        "alpha": 0.05,
        "primary": {"solo": test},
        "secondary": {},
        "xla_flags": "",
        "power": 0.0,
        "power_simulation": {},
        "rationale": "",
    }
    (tmp_path / "tiny.json").write_text(json.dumps(raw))
    monkeypatch.setattr(catalogue, "DESIGNS_DIR", tmp_path)
    design = designs.load("tiny")
    cfg = branch_runs.branch_config(design, "mixed", 0, runs_root, records_root)
    monkeypatch.setenv(PARENT_WRITES, "1")  # as `pinned.run` starts it: the runner writes its file
    run_dir = train.run(cfg)
    assert (
        rundir.read_config(run_dir)["init_from"]
        == f"{records_root}/tiny/material/social-s0-0@{TINY.iterations}"
    )
    capsys.readouterr()
    assert branch_runs.record(design, runs_root, records_root) == []  # no process file yet
    assert f"  1 branches not started under {runs_root}\n" in capsys.readouterr().out  # the social arm
    provenance.write_run_file(
        run_dir, "python -m jaxsocial.train", checkout.tree(), 1, provenance.now(), rc=0
    )
    assert branch_runs.record(design, runs_root, records_root) == [records_root / "tiny/branches/mixed-s0"]
    recorded = jsonio.read_json(records_root / "tiny/branches/mixed-s0" / records.PROVENANCE_FILE)
    assert recorded["run"]["device"].endswith(", one core per seed")
    summary = br.summarise(design, records_root)
    assert summary["recorded"] == 1 and summary["preregistered"]["checks"]["differing"] == []
    assert summary["environments"][solo]["mixed"]["per_seed"][0] is not None
    assert summary["environments"][solo]["social"]["per_seed"] == [None]


@needs_records("records/laptop/prereg-experts", "records/laptop/prereg-mixing")
def test_figure_stays_blind_until_every_branch_is_recorded(tmp_path, capsys):
    """With one branch short of the design (the committed records but the last), `figure` says how many are
    in and writes nothing."""
    records_root, science = tmp_path / "records", tmp_path / "science"
    (records_root / MIXING.out).mkdir(parents=True)
    (records_root / MIXING.records).symlink_to((paths.RECORDS / MIXING.records).resolve())
    committed = sorted((paths.RECORDS / MIXING.out).iterdir())
    for branch in committed[:-1]:
        (records_root / MIXING.out / branch.name).symlink_to(branch.resolve())
    kind_commands.branch_main(["figure", "mixing", "--records", str(records_root), "--science", str(science)])
    out = capsys.readouterr().out
    assert f"[mixing] {len(committed) - 1} of 120 branches recorded; the results stay blind" in out
    assert "mean" not in out and not science.exists()


@needs_records("records/laptop/prereg-experts")
def test_run_starts_only_max_runs_branches_in_seed_order(tmp_path, monkeypatch, capsys):
    """--max-runs N: the first N pending branches, each source seed's arms before the next seed's."""
    started = []
    monkeypatch.setattr(
        pinned, "run", lambda jobs, cores, flags: started.extend(j.label for j in jobs) or [0] * len(jobs)
    )
    with pytest.raises(SystemExit) as exit_:
        kind_commands.branch_main(["run", "mixing", "--runs-dir", str(tmp_path), "--max-runs", "4"])
    assert exit_.value.code == 0
    names = [f"laptop/prereg-mixing/{arm}-s{MIXING.seed + k}" for k in (0, 1) for arm in MIXING.arms]
    assert started == names[:4]
    out = capsys.readouterr().out
    assert "starting 4 of 120 pending runs (--max-runs)" in out
    pace = next(line for line in out.splitlines() if line.startswith("[mixing] at the pace of its records: "))
    assert pace.endswith(("for 4 more, 1 at a time", "whose pace may differ")), pace  # this CPU's or not


@needs_records("records/laptop/prereg-experts")  # the branches' sources
def test_run_resumes_a_begun_branch_and_skips_a_finished_one(tmp_path, monkeypatch, capsys):
    """A branch's state (`rundirs.run_state`): one that logged every iteration is not started again, one
    begun (its config written) resumes (`--resume`), one never begun starts afresh."""
    started = {}
    monkeypatch.setattr(
        pinned, "run", lambda jobs, cores, flags: started.update({j.label: j.argv for j in jobs}) or [0]
    )
    finished, begun = (tmp_path / MIXING.run_name(arm, MIXING.seed) for arm in ("mixed", "social"))
    for run_dir, rows in ((finished, MIXING.iterations), (begun, MIXING.iterations - 1)):
        run_dir.mkdir(parents=True)
        rundir.write_config(run_dir, {"iterations": MIXING.iterations})
        rundir.MetricsLog(run_dir).append({"iteration": i + 1} for i in range(rows))
    assert rundirs.run_state(tmp_path / "nowhere", MIXING.iterations) == rundirs.MISSING
    with pytest.raises(SystemExit):
        kind_commands.branch_main(["run", "mixing", "--runs-dir", str(tmp_path), "--max-runs", "2"])
    assert "[mixing] branches: 1 finished, 1 partial, 118 missing" in capsys.readouterr().out
    resumed, fresh = MIXING.run_name("social", MIXING.seed), MIXING.run_name("alone", MIXING.seed)
    assert list(started) == [resumed, fresh]
    assert "--resume" in started[resumed] and "--resume" not in started[fresh]
