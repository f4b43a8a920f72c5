"""`python -m jaxsocial.train` states its cost before it compiles: from the committed benchmark rate of its
preset where one measured these settings, and says so where none did."""

import json
from pathlib import Path

import pytest
from conftest import TINY_RUN_FLAGS

from jaxsocial import train
from jaxsocial.run import cost, loop

REPO = Path(__file__).resolve().parents[1]


def committed(preset: str) -> tuple[float, float]:
    """The preset's env-steps/s and compile seconds as its benchmark JSON holds them (the HEAD tree's row)."""
    measured = cost.MEASURED[preset]
    rows = json.loads((REPO / measured.path).read_text())["sections"][measured.section]["rows"]
    row = next(r for r in rows if r[measured.key] == measured.row and r.get("tree", "HEAD") == "HEAD")
    compile_s = row["compile_s"]
    return row["best_env_steps_per_s"], compile_s["full"] if isinstance(compile_s, dict) else compile_s


@pytest.mark.parametrize("preset", sorted(cost.MEASURED))
def test_a_presets_run_is_costed_at_its_committed_rate(preset):
    cfg = train.parse_args(["--preset", preset, "--iterations", "3000"])
    line = cost.estimate(cfg)
    steps = 3000 * cfg.num_envs * cfg.rollout_steps
    rate, compile_s = committed(preset)
    assert line.startswith(
        f"cost: 3,000 iterations x {cfg.num_envs * cfg.rollout_steps:,} env-steps = {steps:,}"
    )
    seconds = steps / rate + compile_s
    assert (
        f"about {cost.duration(seconds)} at {rate:,.0f} env-steps/s, the rate of the {preset} preset" in line
    )
    assert cost.MEASURED[preset].path in line
    assert ("over an hour" in line) == (seconds > cost.LONG_S)


def test_the_paper_preset_says_it_is_days_and_what_to_do_instead():
    line = cost.estimate(train.parse_args(["--preset", "paper"]))
    rate, compile_s = committed("paper")
    assert f"about {(11445 * 128 * 256 / rate + compile_s) / 86400:.1f} days" in line
    assert "over an hour" in line and "--preset small or laptop" in line and "GPU" in line


@pytest.mark.parametrize(
    "argv",
    [
        ["--slots", "learner,learner,learner"],
        ["--preset", "paper", "--net.dtype", "auto"],
        ["--env", "goalcycle3:width=9"],
        ["--seeds", "2"],
    ],
)
def test_settings_no_benchmark_measured_get_no_invented_time(argv):
    line = cost.estimate(train.parse_args(argv))
    assert "no time estimate: no committed benchmark measured these settings" in line
    assert "about" not in line


def test_a_resumed_run_is_costed_for_what_is_left(tmp_path):
    cfg = train.parse_args(["--preset", "laptop", "--iterations", "3000"])
    line = cost.estimate(cfg, trained=2000)
    rate, compile_s = committed("laptop")
    steps = 1000 * cfg.num_envs * cfg.rollout_steps
    assert line.startswith(f"cost: 1,000 iterations (of 3,000: 2,000 done) x 8,192 env-steps = {steps:,}")
    assert f"about {cost.duration(steps / rate + compile_s)} at" in line
    assert cost.trained_iterations(cfg, tmp_path) == 0  # a new run


def test_a_checkout_without_the_benchmarks_says_so(tmp_path):
    line = cost.estimate(train.parse_args([]), repo=tmp_path)
    assert f"no time estimate: this checkout lacks {cost.MEASURED['small'].path}" in line


def test_durations_read_at_a_glance():
    assert [cost.duration(s) for s in (40, 720, 12600, 4.2 * 86400)] == [
        "40 s",
        "12 min",
        "3.5 hours",
        "4.2 days",
    ]


class Compiled(Exception):
    """Raised where the training program would compile."""


def test_the_cost_line_comes_before_compiling(tmp_path, capsys, monkeypatch):
    def stop(*args, **kwargs):
        print("COMPILING")
        raise Compiled

    monkeypatch.setattr(loop, "compiled", stop)
    with pytest.raises(Compiled):
        train.main([*TINY_RUN_FLAGS, "--runs-dir", str(tmp_path), "--run-name", "x"])
    out = capsys.readouterr().out
    assert out.startswith("cost: 4 iterations x 32 env-steps = 128 env-steps; no time estimate")
    assert out.index("cost:") < out.index("COMPILING")
