"""Pre-registered designs over committed records (`experiments.evaluation_design`): loading, the tests and
their Holm correction, the checks that make a summary valid, the power simulation, and the blind run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import needs_records
from scipy import stats as scipy_stats

from jaxsocial import stats
from jaxsocial.experiments.analyse import evaluation_results as er
from jaxsocial.experiments.analyse import power, verdicts
from jaxsocial.experiments.launch import evaluation_play
from jaxsocial.experiments.plan import catalogue, designs, paths
from jaxsocial.experiments.plan import evaluation_design as ed


def design_file(tmp_path, **changes) -> ed.EvaluationDesign:
    """A small design 'tiny_transfer' in `tmp_path` (catalogue.DESIGNS_DIR must point there), loaded."""
    raw = {
        "name": "tiny_transfer",
        "records": "laptop/prereg-h1_early",
        "treatment": "social_rec",
        "control": "solo_rec",
        "seed": 210,
        "seeds": 2,
        "episodes": 2,
        "eval_seed": 0,
        "alpha": 0.05,
        "primary": {
            "fourrooms": {"env": "fourrooms:width=9,height=9,max_steps=12", "alternative": "greater"},
        },
        "secondary": {
            "fourrooms_solo": {
                "env": "fourrooms-solo:width=9,height=9,max_steps=12",
                "alternative": "greater",
            }
        },
        "references": {"random": {"slot": "random"}},
        "power": 0.5,
        "power_simulation": {},
        "rationale": "",
    } | changes
    (tmp_path / "tiny_transfer.json").write_text(json.dumps(raw))
    return designs.load("tiny_transfer")


@pytest.fixture
def designs_dir(tmp_path, monkeypatch):
    monkeypatch.setattr(catalogue, "DESIGNS_DIR", tmp_path)
    return tmp_path


def test_a_bad_design_fails_on_load_before_anything_plays(designs_dir):
    with pytest.raises(ValueError, match="unknown environment|fourroom"):
        design_file(designs_dir, primary={"x": {"env": "fourroom", "alternative": "greater"}})
    with pytest.raises(ValueError, match="alternative must be one of"):
        design_file(designs_dir, primary={"x": {"env": "maze", "alternative": "larger"}})
    with pytest.raises(ValueError, match="exactly one of ckpt and slot"):
        design_file(designs_dir, references={"both": {"ckpt": "a", "slot": "random"}})
    with pytest.raises(ValueError, match="two different arms"):
        design_file(designs_dir, control="social_rec")
    with pytest.raises(FileNotFoundError, match="no design .*the designs are"):
        designs.load("no_such_design")


def test_each_family_is_holm_corrected_on_its_own(designs_dir):
    """The primary tests are one family, the secondary another; p-values are scipy's one-sided Mann-Whitney
    U, the smaller doubled and the larger kept at least that (Holm's step-down)."""
    design = design_file(
        designs_dir,
        primary={
            "a": {"env": "fourrooms", "alternative": "greater"},
            "b": {"env": "maze", "alternative": "greater"},
        },
        secondary={"c": {"env": "maze-solo", "alternative": "two-sided"}},
    )
    rng = np.random.default_rng(1)
    by_player = {}
    for env, shift in (("fourrooms", 1.5), ("maze", 0.4), ("maze-solo", 0.0)):
        by_player[env, "social_rec"] = list(rng.normal(shift, 1.0, 12))
        by_player[env, "solo_rec"] = list(rng.normal(0.0, 1.0, 12))
    primary = er.tested(design, design.primary, by_player)
    p = {
        env: scipy_stats.mannwhitneyu(
            by_player[env, "social_rec"], by_player[env, "solo_rec"], alternative="greater"
        ).pvalue
        for env in ("fourrooms", "maze")
    }
    low, high = sorted(p.values())
    assert primary["a"]["p"] == stats.round_p(p["fourrooms"], catalogue.P_DECIMALS)  # a summary's 6 decimals
    assert sorted(e["p_holm"] for e in primary.values()) == [
        stats.round_p(min(1.0, 2 * low), catalogue.P_DECIMALS),
        stats.round_p(max(min(1.0, 2 * low), high), catalogue.P_DECIMALS),
    ]
    assert all(e["rejected"] == (e["p_holm"] <= 0.05) for e in primary.values())
    secondary = er.tested(design, design.secondary, by_player)  # alone in its family: not adjusted
    assert secondary["c"]["p_holm"] == secondary["c"]["p"]
    missing = er.tested(design, design.primary, by_player | {("maze", "solo_rec"): None})
    assert missing["b"]["p"] is None and not missing["b"]["rejected"]
    assert missing["a"]["p_holm"] == missing["a"]["p"]  # a family of one played test


def fake_result(ckpts: list[str], per_seed: list[float], episodes: int, experts: float | None) -> dict:
    slots = [
        {"slot": 0, "kind": "learner", "mean_return": float(np.mean(per_seed)), "per_seed_mean": per_seed}
    ]
    if experts is not None:
        slots.append({"slot": 1, "kind": "expert", "mean_return": experts, "per_seed_mean": [experts]})
    return {"checkpoints": ckpts, "episodes_per_checkpoint": episodes, "seed": 0, "results": slots}


def test_a_summary_is_valid_only_when_played_as_designed_after_a_committed_design(designs_dir, tmp_path):
    design = design_file(designs_dir)
    out = ed.out_dir(design, tmp_path / "science")
    out.mkdir(parents=True)
    for e in ed.evaluations(design, tmp_path / "records"):
        n = max(1, len(e.ckpts))
        result = fake_result(list(e.ckpts), [0.5] * n, design.episodes, None if "solo" in e.env else 0.9)
        e.path(out).write_text(json.dumps(result))
    summary = er.summarise(design, tmp_path / "records", tmp_path / "science")
    block = summary["preregistered"]
    assert block["checks"]["played_as_designed"]
    assert not block["checks"]["design_committed"] and not block["valid"]  # the tmp design is not committed
    env = design.primary["fourrooms"].env
    assert summary["environments"][env]["experts"] == 0.9
    assert summary["environments"][env]["social_rec"]["final_returns"] == [0.5, 0.5]
    assert summary["environments"][env]["random"]["final_returns"] == [0.5]
    assert "NOT VALID" in verdicts.verdict(summary)

    first = ed.evaluations(design, tmp_path / "records")[0]
    fewer = fake_result(list(first.ckpts), [0.5, 0.5], design.episodes + 1, 0.9)  # other episodes
    first.path(out).write_text(json.dumps(fewer))
    assert not er.summarise(design, tmp_path / "records", tmp_path / "science")["preregistered"]["checks"][
        "played_as_designed"
    ]
    first.path(out).unlink()  # not played: no test, and not as designed
    summary = er.summarise(design, tmp_path / "records", tmp_path / "science")
    assert summary["preregistered"]["primary"]["fourrooms"]["p"] is None
    assert not summary["preregistered"]["checks"]["played_as_designed"]


def test_power_grows_with_the_effect_and_vanishes_without_one():
    rng = np.random.default_rng(0)
    strong = {"treatment": list(rng.normal(2.0, 1.0, 20)), "control": list(rng.normal(0.0, 1.0, 20))}
    table = power.power_table(
        {"a": strong, "b": strong}, seeds=20, alpha=0.05, discounts=(1.0, 0.0), reps=200
    )
    assert table["discount 1"]["a"] > 0.95 and table["discount 1"]["all"] > 0.9
    assert table["discount 0"]["a"] < 0.1  # no effect left: about alpha / 2 under Holm, or less
    assert table["discount 1"]["all"] <= min(table["discount 1"]["a"], table["discount 1"]["b"])


@needs_records("records/laptop/prereg-h1_early")
def test_run_plays_what_is_missing_blind_and_logs_its_machine(designs_dir, tmp_path, capsys):
    """Two records of each arm and a random walker in a small Four Rooms beside its experts."""
    design = design_file(designs_dir, secondary={})
    science = tmp_path / "science"
    evaluation_play.run(design, paths.RECORDS, science)
    said = capsys.readouterr().out
    out = ed.out_dir(design, science)
    assert sorted(p.name for p in out.glob("*.json")) == sorted(
        e.path(out).name for e in ed.evaluations(design, paths.RECORDS)
    )
    assert "3 of 3 evaluations to play" in said and "return" not in said  # blind: no score shown
    lines = er.read_play_log(out)
    assert len(lines) == 3 and all(line["cpu"] and "visible_cores" in line for line in lines)
    summary = er.summarise(design, paths.RECORDS, science)
    assert summary["preregistered"]["checks"]["played_as_designed"]
    rows = summary["environments"][design.primary["fourrooms"].env]
    assert rows["experts"] > 0 and len(rows["social_rec"]["final_returns"]) == 2
    assert len(rows["random"]["final_returns"]) == 1
    evaluation_play.run(design, paths.RECORDS, science)
    assert "0 of 3 evaluations to play" in capsys.readouterr().out


def test_run_refuses_a_design_whose_records_are_missing(designs_dir, tmp_path):
    design = design_file(designs_dir, seed=900)
    with pytest.raises(FileNotFoundError, match="material is incomplete.*social_rec-s900-900"):
        evaluation_play.run(design, tmp_path / "records", tmp_path / "science")
    assert not (tmp_path / "science").exists()


@pytest.mark.parametrize("name", catalogue.design_names("evaluation"))
def test_a_committed_design_names_its_material_and_its_pilot(name):
    design = designs.load(name)
    if not (paths.RECORDS / design.records).is_dir():
        pytest.skip(f"needs the committed records {paths.RECORDS / design.records}")
    assert er.absent_records(design, paths.RECORDS) == []
    pilot = power.pilot_scores(design)
    assert set(pilot) == set(design.primary) and all(
        len(p["treatment"]) and len(p["control"]) for p in pilot.values()
    )


@pytest.mark.slow
@needs_records("records/laptop/prereg-h1_early", "records/laptop/prereg-experts")  # the pilots
@pytest.mark.parametrize("name", catalogue.design_names("evaluation"))
def test_a_committed_design_has_the_power_it_states(name):
    """The whole power table, recomputed from the committed pilot with the design's seed of the simulation."""
    design = designs.load(name)
    if not Path(design.power_simulation["pilot"]).is_dir():
        pytest.skip(f"needs the committed pilot {design.power_simulation['pilot']}")
    table = power.stated_power(design)
    assert table == design.power_simulation["power"]
    assert design.power == table[f"discount {design.power_simulation['planning_discount']:g}"]["any"]


def test_a_weighted_pool_draws_each_group_with_its_weight():
    pool = power.weighted_pool(
        [(np.array([1.0, 2.0]), 0.775), (np.array([5.0, 6.0, 7.0]), 0.225), (np.array([9.0]), 0.0)]
    )
    values = np.array(pool)
    assert np.mean(values < 3) == pytest.approx(0.775) and 9.0 not in values
    assert np.sum(values == 1.0) == np.sum(values == 2.0)  # uniform within a group
    assert np.sum(values == 5.0) == np.sum(values == 7.0)
