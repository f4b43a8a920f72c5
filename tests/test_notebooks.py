"""Every notebook's code runs top to bottom, from notebooks/ as Jupyter starts it, writing nothing into the
repository; the social-learning notebook finds the repository, the committed results and existing runs, and
trains only when asked."""

import json
import subprocess
from pathlib import Path

import imageio.v3 as iio
import matplotlib
import numpy as np
import pytest

from jaxsocial.experiments.analyse import verdicts
from jaxsocial.run.metrics import final_return

REPO = Path(__file__).parent.parent
NOTEBOOKS = sorted((REPO / "notebooks").glob("*.ipynb"))
SOCIAL = REPO / "notebooks" / "social_learning.ipynb"


def run_notebook(path: Path) -> dict:
    """Execute a notebook's code cells in one namespace and return it."""
    matplotlib.use("Agg")
    cells = json.loads(path.read_text())["cells"]
    source = "\n\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
    namespace = {"__name__": "__notebook__"}
    exec(compile(source, str(path), "exec"), namespace)
    return namespace


def git_status() -> str:
    return subprocess.run(["git", "status", "--porcelain"], cwd=REPO, capture_output=True, text=True).stdout


@pytest.fixture
def from_notebooks_dir(monkeypatch):
    """Run as Jupyter does (in notebooks/); afterwards `git status` must be as before."""
    before = git_status()
    monkeypatch.chdir(REPO / "notebooks")
    yield
    assert git_status() == before


@pytest.mark.slow  # notebook execution (compiles its own environment programs)
@pytest.mark.parametrize("path", [p for p in NOTEBOOKS if p != SOCIAL], ids=lambda p: p.name)
def test_notebook_runs(path, from_notebooks_dir):
    run_notebook(path)


def test_social_learning_notebook_shows_committed_results_without_training(
    tmp_path, monkeypatch, capsys, from_notebooks_dir
):
    monkeypatch.setenv("JAXSOCIAL_RUNS_DIR", str(tmp_path / "runs"))  # none there
    monkeypatch.setenv("JAXSOCIAL_RECORD", str(tmp_path / "no-record"))
    monkeypatch.delenv("JAXSOCIAL_TRAIN", raising=False)
    ns = run_notebook(SOCIAL)
    printed = capsys.readouterr().out
    assert ns["REPO"] == REPO.resolve() and not ns["TRAIN"]
    h1 = json.loads((REPO / "benchmarks/results/science/h1-gpu.json").read_text())
    assert ns["committed"]["h1-gpu"] == h1
    mean, (low, high) = h1["conditions"]["social_rec"]["mean"], h1["conditions"]["social_rec"]["ci95"]
    assert f"{mean:6.2f} [{low:6.2f}, {high:6.2f}]" in printed
    for summary in ("h1_laptop-laptop", "h1_early-laptop", "h1_sooner-laptop", "pred8-laptop8"):
        laptop = json.loads((REPO / f"benchmarks/results/science/{summary}.json").read_text())
        result = laptop["preregistered"]["result"]  # the design's test, as the summary carries it
        assert (
            f"treatment {result['treatment_learned']}/{result['treatment_seeds']} learned, control "
            f"{result['control_learned']}/{result['control_seeds']}, p = {result['p']:.4g}"
        ) in printed
    readme = (REPO / "README.md").read_text()
    findings = readme[readme.index("## The paper, finding by finding") :]
    findings = findings[: findings.index("\n## ", 1)]
    rows = [line for line in findings.splitlines() if line.startswith("| ") and "| verdict |" not in line]
    assert len(ns["findings"]) == len(rows) > 10
    for line in rows:  # the README's row, claim first and verdict last, as the notebook prints it
        cells = [cell.strip("| ").replace("**", "").replace("`", "") for cell in line.split(" | ")]
        claim, verdict = cells[0], cells[-1]
        assert f"{claim}\n    ours: " in printed and f"    verdict: {verdict}\n" in printed
    experts = json.loads((REPO / "benchmarks/results/science/experts-laptop.json").read_text())
    for test, result in experts["preregistered"]["result"]["primary"].items():  # takeoff, then 4-goal returns
        assert f"primary {test}: p = {result['p']:.4g}" in printed
    for condition, c in experts["conditions"].items():
        mean, (low, high) = c["goalcycle4"]["mean"], c["goalcycle4"]["ci95"]
        assert f"{condition:<24} beside new experts, 4 goals: {mean:6.2f} [{low:6.2f}, {high:6.2f}]" in (
            printed
        )
    mixing = json.loads((REPO / "benchmarks/results/science/mixing.json").read_text())
    assert ns["committed"]["mixing"] == mixing and verdicts.verdict(mixing) in printed
    assert f"No committed learner at {tmp_path / 'no-record'}" in printed and ns["record_episode"] is None
    hint = "run predictions --scale laptop --seeds 2 --cores 0 1"  # the scale where learners learn
    assert "No laptop-scale runs under" in printed and hint in printed
    assert ns["runs"] is None and not (tmp_path / "runs").exists()


@pytest.mark.slow  # trains a tiny run (about a minute of compiling), then plays it as the record
def test_social_learning_notebook_trains_when_asked_then_finds_the_runs(tmp_path, monkeypatch, capsys):
    # A repository of its own (pyproject.toml, jaxsocial/, notebooks/), started in notebooks/ as Jupyter does.
    repo = tmp_path / "repo"
    (repo / "jaxsocial").mkdir(parents=True)
    (repo / "notebooks").mkdir()
    (repo / "pyproject.toml").write_text("")
    monkeypatch.chdir(repo / "notebooks")
    monkeypatch.setenv("JAXSOCIAL_SCALE", "tiny")
    monkeypatch.setenv("JAXSOCIAL_SEEDS", "2")
    monkeypatch.delenv("JAXSOCIAL_RUNS_DIR", raising=False)
    monkeypatch.delenv("JAXSOCIAL_RECORD", raising=False)
    monkeypatch.setenv("JAXSOCIAL_TRAIN", "1")
    trained = run_notebook(SOCIAL)
    assert trained["RUNS_DIR"] == repo / "runs" / "experiments"
    printed = capsys.readouterr().out
    assert "No committed summary" in printed  # this repository has no benchmarks/results
    assert f"No table of findings: {repo / 'README.md'} is missing." in printed and trained["findings"] == []
    tiny = trained["recipes"].TINY
    assert len(trained["curves"]) == 2
    for x, y in trained["curves"]:
        assert x[-1] == tiny.iterations and np.isfinite(y).all()

    # Again without training: it finds those runs, and plays one seed as the committed learner.
    monkeypatch.delenv("JAXSOCIAL_TRAIN")
    record = trained["runs"].seed_dirs["social_pred"][0]
    monkeypatch.setenv("JAXSOCIAL_RECORD", str(record))
    ns = run_notebook(SOCIAL)
    printed = capsys.readouterr().out
    assert "found tiny/" in printed and "compiling" not in printed  # nothing trained
    finals = ns["summary"]["conditions"]["social_pred"]["final_returns"]
    assert finals == [round(final_return(rows), 4) for rows in ns["runs"].rows["social_pred"]]
    # The GIF: one frame per step (60 asked for, at most the episode's length), the learner's predicted view
    # beside its own.
    episode = ns["record_episode"]
    steps = min(60, episode["env_params"].max_steps)
    frames = iio.imread(ns["gif_bytes"], extension=".gif", index=None)
    assert frames.shape[0] == len(ns["frames"]) == steps and ns["predicted"].shape == (steps, 21, 21, 3)
    assert episode["obs"].shape == (steps, 3, 21, 21, 3)
    # Predictions: one frame per movement action, in [0, 1], from the step with the most agent pixels.
    pred = ns["pred"]
    assert set(pred["predicted"]) == {"left", "right", "forward"}
    for frame in pred["predicted"].values():
        assert frame.shape == (21, 21, 3) and frame.min() >= 0.0 and frame.max() <= 1.0
    np.testing.assert_array_equal(pred["observed"], episode["obs"][pred["step"], 0])
