"""Time to takeoff: the one window definition, the log-rank test and the Kaplan-Meier curve checked against
hand computations, and the simulated power of a time-to-takeoff design (Holm's rule, the model of the
evidence, a simulation without an effect)."""

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats as scipy_stats

from jaxsocial import stats
from jaxsocial.experiments.analyse import design_results, takeoff, takeoff_power, verdicts
from jaxsocial.experiments.plan import catalogue, designs, prereg
from jaxsocial.run.metrics import LEARNED_RETURN


def rows_of(returns, episodes=1):
    return [{"iteration": i + 1, "return/0": r, "episodes/0": episodes} for i, r in enumerate(returns)]


def test_windows_are_fixed_in_iterations_whatever_the_run_length():
    """50k env-steps an iteration: windows of 4 iterations (200k env-steps), the last one shorter."""
    assert takeoff.window_iterations(50_000) == 4 and takeoff.window_iterations(8192) == 24
    assert takeoff.window_iterations(10**7) == 1
    returns = [0.0] * 4 + [1.0, 1.0, 3.0, 3.0] + [5.0, 7.0]
    ends, means = takeoff.window_curve(rows_of(returns), 50_000)
    np.testing.assert_array_equal(ends, [4, 8, 10])
    np.testing.assert_allclose(means, [0.0, 2.0, 6.0])
    assert takeoff.seed_takeoff(rows_of(returns), 50_000) == 10  # window 2's mean is 2, not above it
    # the same seed cut at 8 iterations or run on to 40 shares its windows: the takeoff does not move
    assert takeoff.seed_takeoff(rows_of(returns[:8]), 50_000) is None
    assert takeoff.seed_takeoff(rows_of(returns + [9.0] * 30), 50_000) == 12
    assert takeoff.seed_takeoff(rows_of([0.0, 5.0, 0.0, 0.0]), 50_000) is None  # one iteration is no window


def test_window_means_are_episode_weighted():
    rows = [
        {"iteration": 1, "return/0": 0.0, "episodes/0": 3},
        {"iteration": 2, "return/0": 8.0, "episodes/0": 1},
        {"iteration": 3, "return/0": 0.0, "episodes/0": 0},
    ]
    _, means = takeoff.window_curve(rows, 100_000)  # windows of 2 iterations
    np.testing.assert_allclose(means, [2.0, np.nan])
    assert takeoff.seed_takeoff(rows, 100_000, threshold=LEARNED_RETURN) is None  # 2 is not above 2


def test_logrank_is_the_hand_computed_statistic_and_one_sided_toward_sooner():
    """a: takeoffs at 1 and 2, one censored at 3; b: one at 2, two censored at 3. At t = 1: 3 and 3 at
    risk, a's one event expected 0.5 times, variance 0.25; at t = 2: 2 and 3 at risk, two events, a's
    expected 0.8, variance 2 (2/5)(3/5)(3/4) = 0.36. Z = (2 - 1.3) / sqrt(0.61)."""
    a, b = ([1, 2, None], [3, 3, 3]), ([2, None, None], [3, 3, 3])
    z = 0.7 / math.sqrt(0.61)
    result = stats.logrank(a, b)
    assert result["statistic"] == pytest.approx(z, rel=1e-9)
    assert result["p"] == pytest.approx(scipy_stats.norm.sf(z), rel=1e-9)  # a sooner: small p
    assert stats.logrank(b, a)["p"] == pytest.approx(scipy_stats.norm.cdf(z), rel=1e-9)
    assert stats.logrank(a, b, "two-sided")["p"] == pytest.approx(2 * scipy_stats.norm.sf(z), rel=1e-9)


def test_kaplan_meier_is_the_hand_computed_curve_with_its_log_log_band():
    """Takeoffs at 1, 2, 2 and one seed censored at 1.5: S = 3/4 after t = 1, 0 after t = 2. Greenwood's
    variance at t = 1 is 1 / (4 * 3); the log-log band of S there is exp(-exp(log(-log S) -+ 1.96 se)),
    se = sqrt(1/12) / -log S."""
    curve = stats.kaplan_meier([1, None, 2, 2], [4, 1.5, 4, 4])
    assert curve["time"] == [0.0, 1.0, 1.5, 2.0]
    np.testing.assert_allclose(curve["learned"], [0.0, 0.25, 0.25, 1.0])
    s, z = 0.75, scipy_stats.norm.ppf(0.975)
    se = math.sqrt(1 / 12) / -math.log(s)
    bounds = [1 - math.exp(-math.exp(math.log(-math.log(s)) + sign * z * se)) for sign in (-1, 1)]
    np.testing.assert_allclose(curve["low"][1:3], [bounds[0]] * 2, rtol=1e-9)
    np.testing.assert_allclose(curve["high"][1:3], [bounds[1]] * 2, rtol=1e-9)
    assert curve["low"][-1] == curve["high"][-1] == 1.0  # undefined at S = 0: the estimate
    assert stats.kaplan_meier([None, None], [5, 5]) == {"time": [0.0], "learned": [0.0], "low": [0.0],
                                                          "high": [0.0]}  # fmt: skip


def test_holm_rejects_step_down():
    assert stats.holm_rejects(np.array([0.03, 0.02]), 0.05).tolist() == [True, True]
    assert stats.holm_rejects(np.array([0.03, 0.04]), 0.05).tolist() == [False, False]
    assert stats.holm_rejects(np.array([0.01, 0.2]), 0.05).tolist() == [True, False]
    assert stats.holm_rejects(np.array([0.2, 0.024]), 0.05).tolist() == [False, True]


def evidence_arm(takeoffs, end, learned_score, other_score):
    return [
        {"design": "d", "seed": i, "takeoff": t, "end": end,
         "goalcycle4": learned_score if t is not None else other_score}
        for i, t in enumerate(takeoffs)
    ]  # fmt: skip


def test_incidence_is_kaplan_meier_then_a_constant_hazard():
    step = 1_000_000
    grid = np.arange(step, 20 * step + 1, step, dtype=np.float64)
    arm = evidence_arm([4 * step, 5 * step, 6 * step, None, None, None], 8 * step, 5.0, 0.0)
    modelled = takeoff_power.incidence(arm, grid)
    np.testing.assert_allclose(modelled[:8], [0, 0, 0, 1 / 6, 2 / 6, 3 / 6, 3 / 6, 3 / 6])
    hazard = 3 / (1 + 2 + 3 + 3 * 5) / step  # takeoffs after 3M per env-step at risk after 3M
    np.testing.assert_allclose(modelled[8:], 1 - 0.5 * np.exp(-hazard * (grid[8:] - 8 * step)))


def test_without_an_effect_the_tests_reject_about_alpha_and_with_one_more_often():
    step = 196_608
    arm = evidence_arm([10 * step, 20 * step, 30 * step, None, None, None], 40 * step, 5.0, 0.0)
    for i, s in enumerate(arm):  # a spread of scores, so the rank test has no ties to lean on
        s["goalcycle4"] += 0.01 * i
    null = takeoff_power.simulate(arm, arm, 12, 40 * step, step, 1.0, 0.05, reps=300)
    se = math.sqrt(0.05 * 0.95 / 300)
    assert null["takeoff"] <= 0.05 + 3 * se and null["goalcycle4"] <= 0.05 + 3 * se
    better = evidence_arm([2 * step] * 5 + [None], 40 * step, 9.0, 0.0)
    power = takeoff_power.simulate(better, arm, 12, 40 * step, step, 1.0, 0.05, reps=300)
    assert power["takeoff"] > 0.5 and power["goalcycle4"] > 0.5
    halved = takeoff_power.simulate(better, arm, 12, 40 * step, step, 0.5, 0.05, reps=300)
    assert halved["takeoff"] < power["takeoff"] and halved["goalcycle4"] < power["goalcycle4"]


def takeoff_summary(social_lifts, solo_lifts, end, social_scores, solo_scores):
    def condition(lifts, scores):
        return {
            "run_env_steps": [end] * len(lifts),
            **{name: {"per_seed": list(scores)} for name in ("goalcycle4", "solo3", "ct")},
        }

    return {
        "env_steps_per_run": end,
        "conditions": {"social_rec": condition(social_lifts, social_scores),
                       "solo_rec": condition(solo_lifts, solo_scores)},
        "time_to_learning": {"conditions": {"social_rec": {"takeoff_env_steps": social_lifts},
                                            "solo_rec": {"takeoff_env_steps": solo_lifts}}},
    }  # fmt: skip


def test_the_takeoff_designs_block_tests_its_arms_with_holm():
    design = dataclasses.replace(designs.load("experts"), seeds=3)
    summary = takeoff_summary([1, 2, None], [2, None, None], 3, [9.0, 8.0, 7.0], [1.0, 2.0, 0.0])
    block = design_results.takeoff_block(design, summary, {})
    primary, secondary = block["result"]["primary"], block["result"]["secondary"]
    lift = stats.logrank(([1, 2, None], [3] * 3), ([2, None, None], [3] * 3))["p"]
    rank = scipy_stats.mannwhitneyu([9.0, 8.0, 7.0], [1.0, 2.0, 0.0], alternative="greater").pvalue
    assert primary["takeoff"]["p"] == pytest.approx(lift, abs=1e-6) and rank == pytest.approx(0.05)
    assert primary["takeoff"]["p_holm"] == pytest.approx(max(2 * rank, lift), abs=1e-6)  # Holm's step-down
    assert primary["goalcycle4"]["p_holm"] == pytest.approx(2 * rank, abs=1e-6)
    assert not primary["goalcycle4"]["rejected"] and not primary["takeoff"]["rejected"]
    assert secondary["counts"]["learned"] == [2, 3, 1, 3]  # takeoffs by the budget
    assert secondary["counts"]["p"] == pytest.approx(stats.boschloo(2, 3, 1, 3), abs=1e-6)
    assert block["checks"]["seeds_as_designed"]
    unscored = takeoff_summary([1, 2, None], [2, None, None], 3, [9.0, None, 7.0], [1.0, 2.0, 0.0])
    assert not design_results.takeoff_block(design, unscored, {})["checks"]["seeds_as_designed"]
    assert "primary takeoff: p = " in verdicts.verdict({"preregistered": block | {"valid": False}})


def test_a_tiny_p_value_keeps_its_digits_and_never_reads_zero():
    digits = catalogue.P_DECIMALS
    assert stats.round_p(0.000428123, digits) == 0.000428 and stats.round_p(0.0, digits) == 0.0
    assert stats.round_p(1.23456e-14, digits) == 1.23e-14 and stats.round_p(-2.5e-9, digits) == -2.5e-9
    design = dataclasses.replace(designs.load("experts"), seeds=20)
    ct = ([1.0 + i for i in range(20)], [-1.0 - i for i in range(20)])  # every social seed above every solo
    summary = takeoff_summary([1] * 20, [None] * 20, 3, [9.0] * 20, [1.0] * 20)
    for arm, scores in zip(("social_rec", "solo_rec"), ct, strict=True):
        summary["conditions"][arm]["ct"]["per_seed"] = scores
    ct_test = design_results.takeoff_block(design, summary, {})["result"]["secondary"]["ct"]
    expected = scipy_stats.mannwhitneyu(*ct, alternative="greater").pvalue
    assert 0 < expected < 1e-6 and ct_test["p"] == pytest.approx(expected, rel=1e-2)


def test_a_designs_deviations_reach_its_verdict(tmp_path):
    (tmp_path / "x.json").write_text('{"deviations": [{"date": "2026-11-27", "what": "state lost"}]}')
    assert prereg.deviations("x", tmp_path) == [{"date": "2026-11-27", "what": "state lost"}]
    assert prereg.deviations("y", tmp_path) == []
    design = dataclasses.replace(designs.load("experts"), seeds=3)
    block = design_results.takeoff_block(design, takeoff_summary([1], [None], 3, [1.0], [0.0]), {})
    said = verdicts.verdict({"preregistered": block | {"deviations": prereg.deviations("x", tmp_path)}})
    assert "deviation (2026-11-27): state lost" in said


def test_an_incomplete_design_stays_blind():
    from types import SimpleNamespace

    from jaxsocial.experiments.analyse import summaries
    from jaxsocial.experiments.plan import recipes

    design = designs.load("experts")
    done = [{"iteration": i + 1, "return/0": 0.0, "episodes/0": 1} for i in range(design.iterations)]
    unfinished = done[: design.iterations // 2]
    rows = {"social_rec": [done, unfinished], "solo_rec": []}  # what RecipeRuns read of the design's seeds
    runs = SimpleNamespace(recipe=recipes.RECIPES["experts"], scale=recipes.LAPTOP, rows=rows)
    total = design.seeds * 2
    assert summaries.incomplete_design(runs) == f"design experts: 1 of {total} runs finished"
    no_design = SimpleNamespace(recipe=recipes.RECIPES["h1"], scale=recipes.LAPTOP)
    assert summaries.incomplete_design(no_design) is None
    tiny = SimpleNamespace(recipe=recipes.RECIPES["experts"], scale=recipes.TINY, rows={})
    assert summaries.incomplete_design(tiny) is None  # not the design's scale: an ordinary recipe run


def test_evidence_evaluated_with_other_episodes_is_refused(tmp_path, monkeypatch):
    """The power model's 4-goal scores are means over `EVIDENCE_EPISODES` episodes a policy; an evidence file
    made with another count is refused before any seed is read."""
    import json

    path = tmp_path / "goalcycle4-social_rec.json"
    path.write_text(json.dumps({"episodes_per_checkpoint": 64, "checkpoints": [], "results": [{}]}))
    monkeypatch.setattr(takeoff_power, "evidence_eval_path", lambda condition: path)
    with pytest.raises(ValueError, match="64 episodes a policy; the evidence is 128"):
        takeoff_power.evidence("social_rec", tmp_path)
