"""The cultural-transmission evaluation (`jaxsocial.evaluate --protocol ct`): its three presence cases, exact
scores on synthetic episodes, paired episodes, and bad input."""

import dataclasses

import jax
import numpy as np
import pytest
from conftest import TINY
from test_regimes import save_policy

import jaxsocial
from jaxsocial import evaluate
from jaxsocial.agents import population
from jaxsocial.agents.episodes import Episodes, play_episodes
from jaxsocial.env import registry
from jaxsocial.evaluate import EvalConfig
from jaxsocial.run import policy_io
from jaxsocial.specs import EnvSpec


def test_ct_cases_set_presence_only():
    params = jaxsocial.make("goalcycle3", solo_prob=0.3, dropout_prob=0.2)[1]
    cases = evaluate.ct_cases(params)
    assert (cases["with"].solo_prob, cases["with"].dropout_prob, cases["with"].dropin_prob) == (0, 0, 0)
    dropout = cases["dropout"]
    assert (dropout.dropout_prob, dropout.dropout_min_step, dropout.dropout_max_step) == (1.0, 125, 125)
    assert cases["solo"].solo_prob == 1.0 and cases["solo"].dropout_prob == 0.0
    assert all(c.replace(solo_prob=0.0, dropout_prob=0.0, dropout_min_step=1, dropout_max_step=0) ==
               params.replace(solo_prob=0.0, dropout_prob=0.0) for c in cases.values())  # fmt: skip


def episodes(learner, learner_late, experts, experts_late):
    """Episodes of 2 slots (learner, one expert), all present."""
    returns = np.stack([learner, experts], -1).astype(np.float32)
    late = np.stack([learner_late, experts_late], -1).astype(np.float32)
    return Episodes(returns, late, np.ones_like(returns, bool))


def test_scores_are_the_normalised_gains():
    played = {
        "with": [episodes([4, 6], [1, 3], [10, 10], [4, 6]), episodes([2, 2], [0, 0], [8, 12], [5, 5])],
        "dropout": [episodes([3, 5], [2, 2], [5, 5], [0, 0]), episodes([1, 1], [1, 1], [4, 4], [0, 0])],
        "solo": [episodes([1, 1], [0, 0], [0, 0], [0, 0]), episodes([0, 0], [0, 0], [0, 0], [0, 0])],
    }
    result = evaluate.cultural_transmission(played, (1,))
    # seed 0: (5 - 1) / 10 and (2 - 0) / 5; seed 1: (2 - 0) / 10 and (1 - 0) / 5
    np.testing.assert_allclose(result["per_seed"]["ct"], [0.4, 0.2])
    np.testing.assert_allclose(result["per_seed"]["recall"], [0.4, 0.2])
    assert result["ci_over"] == "seeds" and result["ct"]["mean"] == pytest.approx(0.3)
    assert result["expert_return"] == {"episode": 10.0, "second_half": 5.0}
    assert result["learner_returns"]["dropout"]["second_half"]["mean"] == pytest.approx(1.5)
    one = evaluate.cultural_transmission({k: v[:1] for k, v in played.items()}, (1,))
    assert one["ci_over"] == "episodes"  # per-episode gains (0.3, 0.5) / 10 -> mean 0.4, t interval
    t_975_df1 = np.tan(np.pi * 0.475)  # Student t at 1 degree of freedom is Cauchy: tan(pi (p - 1/2))
    np.testing.assert_allclose(one["ct"]["ci95"], 0.4 + np.array([-1, 1]) * t_975_df1 * 0.1, rtol=1e-6)
    played["with"][0] = episodes([4, 6], [1, 3], [0, 0], [0, 0])
    with pytest.raises(ValueError, match="must be > 0"):
        evaluate.cultural_transmission(played, (1,))


CT_ENV = "goalcycle3"
CT_ARGS = "width=7,height=7,n_goals=2,max_steps=20"
CT_SLOTS = "learner,expert:oracle,expert:oracle"
CT_EPISODES = 8
"""Episodes per case in both tests below (one compiled program per case)."""


@pytest.fixture(scope="module")
def saved_learner(tmp_path_factory):
    return str(save_policy(tmp_path_factory.mktemp("ct") / "s0", TINY.net))


def test_cases_play_the_same_episodes_until_the_experts_leave(saved_learner):
    net = TINY.net
    spec = EnvSpec.parse(f"{CT_ENV}:{CT_ARGS}")
    env_params = registry.env_params(spec.name, spec.args)
    pop = population.Population(population.parse_slots(CT_SLOTS, 3))
    params = population.stack([policy_io.load_policy(saved_learner, net)])
    cases = evaluate.ct_cases(env_params)
    out = {
        name: jax.device_get(play_episodes(jax.random.key(3), pop, net, case, params, CT_EPISODES))
        for name, case in cases.items()
    }
    first_half = {name: r.returns - r.late_returns for name, r in out.items()}
    np.testing.assert_array_equal(first_half["with"], first_half["dropout"])  # same episodes, experts present
    assert np.all(out["dropout"].late_returns[:, 1:] == 0) and np.all(out["solo"].returns[:, 1:] == 0)
    assert out["with"].late_returns[:, 1:].mean() > 0  # oracles keep scoring when they stay


def test_ct_protocol_end_to_end(saved_learner):
    cfg = EvalConfig(
        ckpt=(saved_learner,),
        env=CT_ENV,
        env_args=CT_ARGS,
        slots=CT_SLOTS,
        episodes=CT_EPISODES,
        protocol="ct",
    )
    result = evaluate.evaluate(cfg)
    assert result["protocol"] == "ct" and result["ci_over"] == "episodes"
    assert result["expert_return"]["episode"] > result["expert_return"]["second_half"] > 0
    for name in ("ct", "recall"):
        low, high = result[name]["ci95"]
        assert low <= result[name]["mean"] <= high
    assert set(result["learner_returns"]) == {"with", "dropout", "solo"}


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"protocol": "cultural"}, "unknown --protocol"),
        ({"slots": "expert:oracle,learner,expert:oracle"}, "learner first"),
        ({"env": "goalcycle3-solo", "slots": "learner"}, "at least 2 agent slots"),
    ],
)
def test_bad_ct_input_fails_before_playing(saved_learner, changes, message):
    cfg = EvalConfig(ckpt=(saved_learner,), env=CT_ENV, env_args=CT_ARGS, slots=CT_SLOTS, protocol="ct")
    with pytest.raises(ValueError, match=message):
        evaluate._setup(dataclasses.replace(cfg, **changes))
