"""Every notebook's code runs top to bottom; the social-learning notebook (at the tiny scale) is checked for
what it computed."""

import json
from pathlib import Path

import imageio.v3 as iio
import matplotlib
import numpy as np
import pytest

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


def run_notebook(path: Path) -> dict:
    """Execute a notebook's code cells in one namespace and return it."""
    matplotlib.use("Agg")
    cells = json.loads(path.read_text())["cells"]
    source = "\n\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")
    namespace = {"__name__": "__notebook__"}
    exec(compile(source, str(path), "exec"), namespace)
    return namespace


@pytest.mark.slow  # notebook execution (compiles its own environment programs)
@pytest.mark.parametrize(
    "path", [p for p in NOTEBOOKS if p.name != "social_learning.ipynb"], ids=lambda p: p.name
)
def test_notebook_runs(path):
    run_notebook(path)


@pytest.mark.slow  # trains a tiny run (about a minute of compiling)
def test_social_learning_notebook(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXSOCIAL_SCALE", "tiny")
    monkeypatch.setenv("JAXSOCIAL_SEEDS", "2")
    monkeypatch.setenv("JAXSOCIAL_RUNS_DIR", str(tmp_path))
    ns = run_notebook(Path(__file__).parent.parent / "notebooks" / "social_learning.ipynb")
    # Curves: one per seed, over the tiny scale's iterations; the summary is of those runs.
    tiny = ns["recipes"].TINY
    assert len(ns["curves"]) == 2
    for x, y in ns["curves"]:
        assert x[-1] == tiny.iterations and np.isfinite(y).all()
    finals = ns["summary"]["conditions"]["social_pred"]["final_returns"]
    assert finals == [round(ns["figures"].final_return(rows), 4) for rows in ns["runs"].rows["social_pred"]]
    # The GIF: one frame per step (60 asked for, at most the episode's length), each the map beside the views.
    steps = min(60, ns["episode"]["env_params"].max_steps)
    frames = iio.imread(ns["gif_bytes"], extension=".gif", index=None)
    assert frames.shape[0] == len(ns["frames"]) == steps
    assert frames.shape[1:3] == ns["frames"][0].shape[:2]
    assert ns["episode"]["obs"].shape == (steps, 3, 21, 21, 3)
    # Predictions: one frame per movement action, in [0, 1], from the step with the most agent pixels.
    pred = ns["pred"]
    assert set(pred["predicted"]) == {"left", "right", "forward"}
    for frame in pred["predicted"].values():
        assert frame.shape == (21, 21, 3) and frame.min() >= 0.0 and frame.max() <= 1.0
    np.testing.assert_array_equal(pred["observed"], ns["episode"]["obs"][pred["step"], 0])
