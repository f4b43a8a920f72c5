"""`benchmarks/gpu_learning.py`: a run's seeds beside the pooled CPU laptop seeds, on a hand-made run whose
takeoffs are known."""

import json
import sys
from pathlib import Path

import pytest
from conftest import needs_records

from jaxsocial.experiments.analyse import takeoff_power
from jaxsocial.experiments.plan import paths

REPO = Path(__file__).resolve().parents[1]
sys.path.append(str(REPO / "benchmarks"))  # the script and its `run_info`
import gpu_learning  # noqa: E402

ITERATIONS = 1464  # `experts`' budget: 11,993,088 env-steps at 8,192 an iteration


def fake_run(root: Path, returns: dict[int, list[float]], preset: str = "laptop") -> Path:
    """A run directory with one seed folder per entry of `returns` (seed -> the learner's return per
    iteration, 4 episodes each), the laptop recipe's sizes."""
    config = {
        "env": "goalcycle3",
        "preset": preset,
        "net": {"aux": "rec"},
        "num_envs": 128,
        "rollout_steps": 64,
    }
    run = root / "run"
    for seed, curve in returns.items():
        (run / f"s{seed}").mkdir(parents=True)
        (run / f"s{seed}" / "config.json").write_text(json.dumps(config | {"seed": seed}))
        rows = [
            {"iteration": i + 1, "env_steps_per_s": 1, "return/0": r, "episodes/0": 4}
            for i, r in enumerate(curve)
        ]
        (run / f"s{seed}" / "metrics.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    (run / "config.json").write_text(json.dumps(config | {"seed": min(returns)}))
    return run


@needs_records(*(f"records/laptop/prereg-{d}" for d in takeoff_power.POOLED[paths.POOLED_ALL_SUMMARY.name]))
def test_takeoffs_and_kaplan_meier_beside_the_pooled_cpu_seeds(tmp_path, capsys):
    plateau = [0.5] * ITERATIONS
    learns = [0.5] * 30 + [5.0] * (ITERATIONS - 30)  # the second 24-iteration window is above 2
    run = fake_run(tmp_path, {0: learns, 1: plateau})
    gpu_learning.main([str(run), "--out", str(tmp_path / "out.json")])
    result = json.loads((tmp_path / "out.json").read_text())["sections"]["gpu_learning"]
    device = result["device"]
    assert [s["takeoff"] for s in device["seed_list"]] == [48 * 8192, None]
    assert [s["end"] for s in device["seed_list"]] == [ITERATIONS * 8192] * 2
    assert device["took_off"] == 1 and device["kaplan_meier"]["4000000"]["kaplan_meier"] == 0.5
    assert "20000000" not in device["kaplan_meier"]  # past the run's end: not read
    pooled = json.loads((REPO / "benchmarks/results/science/laptop-pooled-all.json").read_text())
    social = pooled["conditions"]["social_rec"]
    cpu = result["cpu_pooled"]
    assert (cpu["seeds"], cpu["took_off"]) == (social["seeds"], social["took_off_within_budget"])
    assert cpu["kaplan_meier"]["6000000"] == {k: social["at"]["6000000"][k] for k in ("kaplan_meier", "ci95")}
    assert 0 <= result["logrank_two_sided"]["p"] <= 1
    assert "device: 1 of 2 took off" in capsys.readouterr().out


def test_a_run_of_another_recipe_is_refused(tmp_path):
    run = fake_run(tmp_path, {0: [0.5] * 10}, preset="cpu")
    with pytest.raises(SystemExit, match="not a laptop social PPO \\+ rec run"):
        gpu_learning.main([str(run)])
