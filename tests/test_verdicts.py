"""One verdict for every kind of design (`analyse.verdicts`): the blocks of a 'zero_shot' design and of a
'counts' design's secondary tests, which earlier verdicts did not show, built by hand."""

from __future__ import annotations

from jaxsocial import stats
from jaxsocial.experiments.analyse import verdicts

CHECKS = {"design_committed": True, "design_precedes_every_run": False, "runs_not_after_design": ["a/s1"]}


def test_a_zero_shot_design_s_verdict_shows_both_arms_and_its_test():
    test = stats.mann_whitney([3.0, 4.0, 5.0], [0.0, 1.0, 2.0], "greater") | {"rejected": False}
    block = {
        "commit": "c" * 40,
        "primary": {"test": "mannwhitney-greater", "alpha": 0.05},
        "result": {
            "social_over_cloners": test,
            "scores": {"treatment": stats.summary([3.0, 4.0, 5.0]), "control": None},
        },
        "checks": CHECKS,
        "valid": False,
    }
    said = verdicts.verdict({"preregistered": block}).splitlines()
    assert (
        said[0]
        == "pre-registered (mannwhitney-greater, alpha 0.05): treatment mean 4.0 over 3 seeds, control none"
    )
    assert said[1] == f"  primary social_over_cloners: p = {test['p']:.4g}"
    assert said[2:] == [
        f"  design commit {'c' * 40}",
        "  design_committed: yes",
        "  design_precedes_every_run: NO",
        "  runs_not_after_design: a/s1",
        "NOT VALID: the result above does not test the design (see its checks and problems)",
    ]


def test_a_counts_design_s_verdict_shows_its_secondary_tests_after_its_headline():
    block = {
        "commit": None,
        "primary": {"test": "boschloo-greater", "alpha": 0.05},
        "result": {"treatment_learned": 9, "treatment_seeds": 10, "control_learned": 3, "control_seeds": 10,
                   "p": 0.003978},
        "secondary": {"above_experts": {"counts": [4, 10, 0, 40], "p": 0.0012, "p_holm": 0.0024,
                                        "rejected": True}},
        "checks": {"design_committed": False},
        "problems": ["solo_pred seed 7: missing"],
    }  # fmt: skip
    said = verdicts.verdict({"preregistered": block}).splitlines()
    assert said == [
        "pre-registered (boschloo-greater, alpha 0.05): treatment 9/10 learned, control 3/10, p = 0.003978",
        "  secondary above_experts: 4/10 against 0/40; p = 0.0012 (Holm 0.0024), rejected",
        "  design commit none (the design is not committed)",
        "  design_committed: NO",
        "  solo_pred seed 7: missing",
    ]
