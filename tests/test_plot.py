"""Learning curves (`python -m jaxsocial.plot`) of a real tiny two-seed run: panels, bands, groups, errors."""

import json
import shutil
import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest
from conftest import TINY_ENV_ARGS

from jaxsocial import plot, plot_parts
from jaxsocial.run import metrics, rundir


@pytest.fixture
def run_dir(two_seed_run):
    """TINY's two-seed run: run_dir/s0 and run_dir/s1."""
    return two_seed_run


def copy_seed(src, dst, **changes):
    """A run of its own with one seed's config and metrics, and config `changes`."""
    dst.mkdir(parents=True)
    shutil.copy(src / rundir.METRICS_FILE, dst)
    rundir.write_config(dst, {**rundir.read_config(src), "run_name": None, **changes})
    return dst


def test_two_seeds_panels_mean_and_band(run_dir):
    (group,) = plot.load_groups([run_dir])
    assert group.slots == ["learner", "random", "random"] and len(group.rows) == 2
    assert group.seed_dirs == [run_dir / "s0", run_dir / "s1"] and group.steps_per_iteration == 32
    fig = plot.draw([group])
    titles = [ax.get_title() for ax in fig.axes]
    assert titles == [
        "slot 0 (learner): episode return",
        "slot 0 (learner): auxiliary loss",
        "slot 0 (learner): KL",
        "slot 0 (learner): entropy",
        "slot 1 (random): episode return",
        "slot 2 (random): episode return",
    ]
    assert [ax.get_ylabel() for ax in fig.axes[:4]] == [
        "return per episode", "mean absolute error", "KL (nats)", "entropy (nats)"
    ]  # fmt: skip
    rows = sorted({round(ax.get_position().y0, 3) for ax in fig.axes})
    assert len(rows) == 2  # the two distractors' returns share the second row: no rows of empty panels
    for ax in fig.axes:  # two faint seed lines, the mean, and the CI band
        assert len(ax.lines) == 3 and len(ax.collections) == 1
    returns = fig.axes[0]
    curves = [metrics.curve(rows, 0) for rows in group.rows]
    np.testing.assert_allclose(returns.lines[2].get_xdata(), curves[0][0] * 32)
    mean = np.mean([y for _, y in curves], axis=0)
    np.testing.assert_allclose(returns.lines[2].get_ydata(), mean)
    band = returns.collections[0].get_paths()[0].vertices
    assert band[:, 1].min() <= mean.min() and band[:, 1].max() >= mean.max()
    kl = [r["kl/0"] for r in group.rows[1]]
    np.testing.assert_allclose(fig.axes[2].lines[1].get_ydata(), kl)  # seed 1's KL, per iteration
    assert [t.get_text() for t in returns.get_legend().get_texts()] == ["tiny (seeds 0, 1)"]
    # env steps on every x axis, as "64k", "1.2M", at most nbins + 1 = 6 ticks so their labels do not overlap
    assert all(ax.xaxis.get_major_formatter().func is plot_parts.format_steps for ax in fig.axes)
    assert all(len(ax.get_xticks()) <= 6 for ax in fig.axes)


@pytest.mark.parametrize(
    ("value", "text"),
    [(0, "0"), (800, "800"), (64_000, "64k"), (1_200_000, "1.2M"), (375_000_000, "375M"), (3.75e9, "3.75G")],
)
def test_env_steps_read_as_people_write_them(value, text):
    assert plot_parts.format_steps(value) == text


def test_seeds_group_by_config(run_dir, tmp_path):
    other = copy_seed(run_dir / "s0", tmp_path / "other", env_args=f"{TINY_ENV_ARGS},penalty=0.5")
    # The whole run, one of its seeds again (counted once) and a run of another config.
    groups = plot.load_groups([run_dir / "s1", run_dir, other])
    assert [(g.legend, len(g.rows)) for g in groups] == [("tiny (seeds 0, 1)", 2), ("other (seed 0)", 1)]
    fig = plot.draw(groups)
    returns = fig.axes[0]
    assert len(returns.lines) == 3 + 2 and len(returns.collections) == 1  # one seed: no band
    twin = copy_seed(run_dir / "s0", tmp_path / "twin")
    with pytest.raises(ValueError, match="seed 0 of the same config"):
        plot.load_groups([run_dir, twin])


def test_runs_of_one_condition_are_labelled_by_it_and_their_seeds(run_dir, tmp_path):
    runs = [copy_seed(run_dir / f"s{s}", tmp_path / f"social_rec_pen1-s{s}-{s}", seed=s) for s in (0, 1)]
    (group,) = plot.load_groups(runs)
    assert group.legend == "social_rec_pen1 (seeds 0, 1)"
    assert [plot.seed_list(s) for s in ([3], [1, 0], [*range(300, 340)], [0, 2, 3, 4, 9])] == [
        "seed 3", "seeds 0, 1", "seeds 300-339", "seeds 0, 2-4, 9"
    ]  # fmt: skip


def test_a_zoomed_panel_spans_the_means_not_the_seeds():
    from matplotlib.figure import Figure

    ax = Figure().subplots()
    x = np.arange(5.0)
    plot_parts.band(ax, [x, x], [np.full(5, -10.0), np.full(5, 12.0)], "wide", "C0")  # mean 1
    plot_parts.band(ax, [x], [np.linspace(0.0, 2.0, 5)], "narrow", "C1")
    assert ax.get_ylim()[0] < -10 and ax.get_ylim()[1] > 12
    plot_parts.zoom_to_means(ax)
    np.testing.assert_allclose(ax.get_ylim(), (-0.2, 2.2))


def test_together_puts_every_slots_return_on_one_axis(run_dir):
    groups = plot.load_groups([run_dir])
    first = plot.draw(groups, together=True).axes[0]
    assert first.get_title() == "every slot's episode return, one axis"
    labels = [line.get_label() for line in first.lines if not line.get_label().startswith("_")]
    assert labels == [f"tiny: slot {i} {name}" for i, name in enumerate(groups[0].slots)]
    together = plot.draw(groups, together=True).axes
    assert len(together) == len(plot.draw(groups).axes) + 1
    assert [t.get_text() for t in together[1].get_legend().get_texts()] == ["tiny (seeds 0, 1)"]


def test_cli_writes_into_the_first_run_by_default(run_dir, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(run_dir, run)
    done = subprocess.run([sys.executable, "-m", "jaxsocial.plot", str(run)], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert iio.imread(run / "curves.png").ndim == 3


def test_cli_writes_image_and_refuses_to_overwrite(run_dir, tmp_path):
    out = tmp_path / "curves.png"
    cmd = [sys.executable, "-m", "jaxsocial.plot", str(run_dir), "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "tiny (seeds 0, 1): 4 iterations" in done.stdout and "slot 0 learner: final return" in done.stdout
    image = iio.imread(out)
    assert image.ndim == 3 and image.shape[1] > image.shape[0] > 100
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert again.returncode == 2 and "--overwrite" in again.stderr and "Traceback" not in again.stderr
    assert np.array_equal(iio.imread(out), image)


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("missing", "does not exist"),
        ("not_a_run", "is not a run directory"),
        ("bad_config", "not the config of a training run"),
        ("missing_seed", "trained with --seeds 2"),
        ("no_metrics", "no metrics yet"),
        ("exists", "already exists; pass --overwrite"),
        ("extension", "unsupported output file"),
    ],
)
def test_cli_errors_before_plotting(run_dir, tmp_path, capsys, case, message):
    out = tmp_path / ("curves.txt" if case == "extension" else "curves.png")
    target = tmp_path / "run"
    if case == "not_a_run":
        target.mkdir()
    elif case == "bad_config":
        target.mkdir()
        (target / rundir.CONFIG_FILE).write_text(json.dumps({"env": "goalcycle3"}))
    elif case == "missing_seed":
        shutil.copytree(run_dir, target)
        shutil.rmtree(target / "s1")
    elif case == "no_metrics":
        copy_seed(run_dir / "s0", target)
        (target / rundir.METRICS_FILE).write_text("")
    elif case in ("exists", "extension"):
        target = run_dir
    if case == "exists":
        out.write_bytes(b"keep me")
    with pytest.raises(SystemExit) as e:
        plot.main([str(target), "--out", str(out)])
    assert e.value.code == 2 and message in capsys.readouterr().err
    assert out.read_bytes() == b"keep me" if case == "exists" else not out.exists()
