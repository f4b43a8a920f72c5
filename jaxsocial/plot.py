"""Learning curves of training runs: every slot's return on one axis first (the learner against its experts),
then one row of panels per learner slot and the other slots' returns below.

    python -m jaxsocial.plot runs/goalcycle3-s0-2                     # runs/goalcycle3-s0-2/curves.png
    python -m jaxsocial.plot runs/a-s0 runs/a-s1 runs/b-s0 --out compare.pdf

A learner's row shows its episode return (episode-weighted, in `--points` blocks of iterations) and the
losses it logged per iteration (auxiliary, attention, behaviour cloning), KL and entropy, against env steps;
the other slots' (experts', distractors') returns sit side by side below. Seeds of the same config (every
setting but the seed and the driver's, e.g. `iterations`) form one group, whether they come from one
`--seeds N` run or from separate runs, and are labelled by the runs' name without its seed part and by their
seeds ('social_rec (seeds 0-3)'): each seed is a faint line, the mean a thick one, with a 95% Student-t band
over the seeds.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import sys
from pathlib import Path
from typing import Any

from jaxsocial import specs, stats
from jaxsocial.agents import population
from jaxsocial.env import registry
from jaxsocial.plot_parts import band, steps_axis
from jaxsocial.run import metrics, rundir

PANELS = {
    "return": "episode return",
    "aux_loss": "auxiliary loss",
    "bc_loss": "behaviour-cloning loss",
    "attention_loss": "attention loss",
    "kl": "KL",
    "entropy": "entropy",
}
"""Metric name prefixes (metrics.jsonl keys are 'NAME/SLOT') and their panel titles, in column order."""
Y_LABELS = {
    "return": "return per episode",
    "aux_loss": "mean absolute error",
    "bc_loss": "cross-entropy (nats)",
    "attention_loss": "cross-entropy (nats)",
    "kl": "KL (nats)",
    "entropy": "entropy (nats)",
}
"""Each panel's y-axis label."""

NOT_GROUPED = frozenset(
    {
        # `config.DriverConfig`'s: they do not change what is trained
        "iterations", "stop_at_return", "resume", "overwrite", "progress", "blind", "logger",
        "checkpoint_every", "keep_checkpoints", "run_name", "runs_dir", "devices", "coordinator",
        "num_processes", "process_id", "compile_cache", "eval_envs", "eval_every", "eval_episodes",
        "on_nonfinite", "init_from",
        # the seeds' and how they are batched
        "seed", "seeds", "seed_batching",
    }
)  # fmt: skip
"""Config fields that may differ between the seeds of one group (kept equal to `config.DriverConfig`'s fields
and the seed fields by a test, so this module needs no training code)."""


@dataclasses.dataclass
class Group:
    """Seeds of one config: their run directories, metrics rows (one list per seed) and slot labels."""

    label: str
    seed_dirs: list[Path]
    rows: list[list[dict[str, Any]]]
    slots: list[str]
    steps_per_iteration: int
    seeds: list[int]

    @property
    def legend(self) -> str:
        """'social_rec (seeds 0-3)', 'tiny (seeds 0, 1)', 'goalcycle3 (seed 0)': the runs and their seeds."""
        return f"{self.label} ({seed_list(self.seeds)})"


def seed_list(seeds: list[int]) -> str:
    """'seed 3', 'seeds 0, 1', 'seeds 300-339', 'seeds 0, 2-4': consecutive seeds as a range."""
    ordered, spans = sorted(seeds), []
    for seed in ordered:
        if spans and seed == spans[-1][1] + 1:
            spans[-1][1] = seed
        else:
            spans.append([seed, seed])
    text = ", ".join(str(a) if a == b else f"{a}, {b}" if b == a + 1 else f"{a}-{b}" for a, b in spans)
    return f"seed{'s' if len(ordered) > 1 else ''} {text}"


def slot_labels(config: dict[str, Any]) -> list[str]:
    """Each slot's label ('learner', 'expert:explorer', ...) from a run's config."""
    _, env_params = registry.make(config["env"], **dict(specs.ENV_ARGS.parse(config.get("env_args", ""))))
    text = config.get("slots") or population.default_slots(env_params)
    return [s.label for s in population.parse_slots(text, env_params.n_agents, need_learner=False)]


def _group_key(config: dict[str, Any]) -> str:
    return json.dumps({k: v for k, v in config.items() if k not in NOT_GROUPED}, sort_keys=True)


SEED_SUFFIX = re.compile(r"(/s\d+|-s\d+(-\d+)?)$")
"""What names a run's seeds: '/s3' (one seed of a multi-seed run), '-s0' (train's default name), '-s0-5'
(the experiments' `<condition>-s<first>-<last>`)."""


def _label(run_dir: Path) -> str:
    """A run's name in legends, without what names its seeds: 'social_rec' for 'social_rec-s0-0' and for
    one seed of it, 'social_rec-s0-5/s3'."""
    one_seed = rundir.one_seed_of_many(rundir.read_config(run_dir))
    run_dir = run_dir.resolve()
    name = f"{run_dir.parent.name}/{run_dir.name}" if one_seed else run_dir.name
    while SEED_SUFFIX.search(name):
        name = SEED_SUFFIX.sub("", name)
    return name


def load_groups(run_dirs: list[str | Path]) -> list[Group]:
    """Every seed's config and metrics, grouped by config (in order of first appearance; a seed given twice
    counts once). ValueError for a directory that is not a run, a seed without metrics, or two copies of the
    same seed of a config."""
    found: dict[str, list[tuple[str, Path, dict[str, Any]]]] = {}  # group key -> (label, seed dir, config)
    seen = set()
    for run_dir in map(Path, run_dirs):
        for d in rundir.written_seed_dirs(run_dir):
            if d.resolve() in seen:
                continue
            seen.add(d.resolve())
            config = rundir.read_config(d)
            members = found.setdefault(_group_key(config), [])
            for _, other, c in members:
                if c["seed"] == config["seed"]:
                    raise ValueError(
                        f"{other} and {d} are seed {c['seed']} of the same config: pass each once"
                    )
            members.append((_label(run_dir), d, config))
    groups = []
    for members in found.values():
        labels = list(dict.fromkeys(label for label, _, _ in members))
        rows = []
        for _, d, _ in members:
            rows.append(rundir.read_metrics(d))
            if not rows[-1]:
                raise ValueError(f"no metrics yet in {d} ({rundir.METRICS_FILE} is missing or empty)")
        config = members[0][2]
        groups.append(
            Group(
                label=" / ".join(labels),
                seed_dirs=[d for _, d, _ in members],
                rows=rows,
                slots=slot_labels(config),
                steps_per_iteration=metrics.steps_per_iteration(config),
                seeds=[c["seed"] for _, _, c in members],
            )
        )
    return groups


def _logged(group: Group, name: str, slot: int) -> bool:
    """Whether the group's first seed logged metric `name` of `slot`."""
    return metrics.logged(group.rows[0][0], name, slot)


def panels(groups: list[Group]) -> list[list[str]]:
    """Per slot, the PANELS keys some group logged for it (the return always)."""
    n_slots = max(len(g.slots) for g in groups)
    return [
        [k for k in PANELS if k == metrics.RETURN or any(_logged(g, k, slot) for g in groups)]
        for slot in range(n_slots)
    ]


def grid(layout: list[list[str]]) -> list[list[tuple[int, str]]]:
    """The figure's rows of (slot, panel key): a row per slot with more panels than its return (learners),
    then the return-only slots (experts, distractors) side by side, as many a row as the widest row holds."""
    ncols = max(len(p) for p in layout)
    rows = [[(slot, k) for k in keys] for slot, keys in enumerate(layout) if len(keys) > 1]
    alone = [(slot, keys[0]) for slot, keys in enumerate(layout) if len(keys) == 1]
    return rows + [alone[i : i + ncols] for i in range(0, len(alone), ncols)]


TOGETHER = -1
"""The slot index of the panel with every slot's return on one axis (`draw(..., together=True)`)."""


def draw(groups: list[Group], points: int = metrics.CURVE_POINTS, together: bool = False):
    """The curves as a matplotlib Figure (not managed by pyplot): a row of panels per learner slot, the other
    slots' returns side by side below (`grid`; no empty axes); with `together`, first a panel of every slot's
    return on one axis, so the gap between the learner and the experts shows. Returns are episode-weighted
    means over `points` blocks of iterations; losses are per iteration."""
    import matplotlib
    from matplotlib.figure import Figure

    rows = [[(TOGETHER, metrics.RETURN)]] * together + grid(panels(groups))
    ncols = max(len(r) for r in rows)
    fig = Figure(figsize=(4 * ncols, 3 * len(rows)))
    axes = fig.subplots(len(rows), ncols, squeeze=False)
    colors = matplotlib.colormaps["tab10"].colors
    for cells, row_axes in zip(rows, axes, strict=True):
        for ax in row_axes[len(cells) :]:
            fig.delaxes(ax)
        for (slot, key), ax in zip(cells, row_axes, strict=False):
            if slot == TOGETHER:
                _draw_together(ax, groups, points, colors)
                continue
            for i, g in enumerate(groups):
                if slot >= len(g.slots) or (key != metrics.RETURN and not _logged(g, key, slot)):
                    continue
                if key == metrics.RETURN:
                    xs, ys = zip(*(metrics.curve(r, slot, points) for r in g.rows), strict=True)
                else:
                    k = metrics.key(key, slot)
                    xs, ys = zip(*(metrics.metric_curve(r, k) for r in g.rows), strict=True)
                xs = [x * g.steps_per_iteration for x in xs]
                band(ax, xs, list(ys), g.legend, colors[i % len(colors)])
            names = sorted({g.slots[slot] for g in groups if slot < len(g.slots)})
            ax.set_title(f"slot {slot} ({' / '.join(names)}): {PANELS[key]}", fontsize=9)
            ax.set_ylabel(Y_LABELS[key], fontsize=8)
            steps_axis(ax)
            ax.tick_params(labelsize=7)
    axes[int(together), 0].legend(fontsize=7)  # the runs and their seeds (the together panel has its own)
    fig.tight_layout()
    return fig


def _draw_together(ax, groups: list[Group], points: int, colors) -> None:
    """Every group's every slot's return on `ax`: a colour per group and slot, the learner's lines solid."""
    styles = ("-", "--", ":", "-.")
    n = 0
    for g in groups:
        for slot, name in enumerate(g.slots):
            xs, ys = zip(*(metrics.curve(r, slot, points) for r in g.rows), strict=True)
            xs = [x * g.steps_per_iteration for x in xs]
            band(ax, xs, list(ys), f"{g.label}: slot {slot} {name}", colors[n % len(colors)])
            ax.lines[-1].set_linestyle(styles[min(slot, len(styles) - 1)])
            n += 1
    ax.set_title("every slot's episode return, one axis", fontsize=9)
    ax.set_ylabel(Y_LABELS[metrics.RETURN], fontsize=8)
    steps_axis(ax)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7)


def final_return_lines(groups: list[Group]) -> list[str]:
    """Lines with each group's final return per slot: mean and 95% CI over seeds (`metrics.final_return`)."""
    lines = []
    for g in groups:
        shortest, longest = min(map(len, g.rows)), max(map(len, g.rows))
        iterations = f"{shortest}" if shortest == longest else f"{shortest} to {longest}"
        lines.append(f"{g.legend}: {iterations} iterations")
        for slot, name in enumerate(g.slots):
            s = stats.summary([metrics.final_return(r, slot) for r in g.rows])
            if s["mean"] is None:
                final = "no episode ended"
            else:
                lo, hi = s["ci95"]
                final = f"{s['mean']:+.3f}" + (f" (95% CI {lo:+.3f} to {hi:+.3f})" if len(g.rows) > 1 else "")
            lines.append(f"  slot {slot} {name}: final return {final}")
    return lines


def _parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m jaxsocial.plot", description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR", help="runs of python -m jaxsocial.train")
    parser.add_argument(
        "--out",
        help="output image, e.g. curves.png (.pdf, .svg, ...); default: the first run's own directory, "
        "RUN_DIR/curves.png, so no two runs' pictures collide",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    parser.add_argument(
        "--together",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="a first panel with every slot's return on one axis, so the gap between the learner and the "
        "experts shows (default; --no-together leaves it out)",
    )
    parser.add_argument(
        "--points",
        type=int,
        default=metrics.CURVE_POINTS,
        help="blocks the returns are averaged in (default 50)",
    )
    args = parser.parse_args(argv)

    # Everything is checked before plotting.
    from matplotlib.backend_bases import FigureCanvasBase

    if args.out is None:
        args.out = os.path.join(args.runs[0], "curves.png")
    formats = FigureCanvasBase.get_supported_filetypes()
    ext = os.path.splitext(args.out)[1].lower().lstrip(".")
    if ext not in formats:
        parser.error(f"unsupported output file {args.out!r}: use one of .{', .'.join(sorted(formats))}")
    if os.path.exists(args.out) and not args.overwrite:
        parser.error(f"{args.out} already exists; pass --overwrite to replace it")
    if args.points < 1:
        parser.error(f"--points {args.points} must be >= 1")
    try:
        args.groups = load_groups(args.runs)
    except ValueError as err:
        parser.error(str(err))
    return args


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    fig = draw(args.groups, args.points, together=args.together)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    print("\n".join(final_return_lines(args.groups)))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
