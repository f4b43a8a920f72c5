"""The exploratory sample-efficiency sweep: which settings make auxiliary-loss learners leave the one-tile
plateau early on a 2-core CPU (exploration only: seeds below 100, no confirmatory result).

A *setting* is a condition of `recipes.CONDITIONS` at the cpu scale with some flags changed, a budget and
the reason it is tried. Each seed trains in a process of its own pinned to one core (`pinned`), and its
record goes to
``benchmarks/results/records/sweep/<setting>/s<seed>/``. The summary (`summarise`) gives per setting each
seed's takeoff (`takeoff.seed_takeoff`: the end of the first window of about 200k env-steps whose mean
learner return exceeds `metrics.LEARNED_RETURN`) in env-steps and in CPU-minutes on the machine that ran
it, the fraction of seeds past the plateau against both, and the final returns.

    python -m jaxsocial.experiments.sweep list
    python -m jaxsocial.experiments.sweep run mb8k8_rec --seeds 0 1 --cores 0 1   # one process a core
    python -m jaxsocial.experiments.sweep record mb8k8_rec --seeds 0 1 --device "AMD EPYC, 2 cores"
    python -m jaxsocial.experiments.sweep figure                         # every recorded setting
    python -m jaxsocial.experiments.sweep map                            # social against solo, per setting
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial.experiments import figures, paths, pinned, recipes, records, takeoff
from jaxsocial.run import logs, metrics, rundir
from jaxsocial.run.metrics import LEARNED_RETURN

RECORDS_SUBDIR = "sweep"
STOP_RETURN = 5.0
"""A seed stops once a chunk's mean learner return reaches this (`--stop-at-return`): clearly past the
one-tile plateau (about 1) and the takeoff threshold (`LEARNED_RETURN`), so its remaining budget is saved."""


@dataclasses.dataclass(frozen=True)
class Setting:
    """One point of the sweep: `condition` at the cpu scale with `flags` on top, for `iterations`."""

    name: str
    condition: str
    flags: tuple[str, ...]
    iterations: int
    why: str


def _flags(text: str) -> tuple[str, ...]:
    return tuple(shlex.split(text))


ONE_SAMPLE = _flags("--ppo.num-minibatches 8 --ppo.recompute-every 8")
"""One gradient sample per env-step, the targets of the rollout only (no recompute): 2.2x the env-steps/s of
the cpu scale's two samples with a recompute every 2 minibatches (docs/performance.md)."""
TWENTY_M = 2442
"""Iterations of 8,192 env-steps: 20.0M, the sweep goal's horizon."""

SETTINGS = {
    s.name: s
    for s in (
        Setting(
            "mb8k8_rec",
            "social_rec",
            ONE_SAMPLE,
            TWENTY_M,
            "The cpu scale (128 envs: 8x the gpu scale's updates per env-step, at the same env-steps/s) with "
            "the cheapest PPO (1 gradient sample per env-step, no recompute), and the reconstruction loss "
            "that took off early in the one unseen gpu-scale seed.",
        ),
        Setting(
            "mb8k8_rec_pen1",
            "social_rec",
            (*ONE_SAMPLE, "--env-args", "width=9,height=9,penalty=1.0"),
            TWENTY_M,
            "mb8k8_rec with the wrong-tile penalty at 1.0 instead of 1.5: a shallower one-tile plateau, so "
            "following the experts pays sooner (the baselines must then be checked to stay on it).",
        ),
        Setting(
            "mb8k8_solo_pred_pen1",
            "solo_pred",
            (*ONE_SAMPLE, "--env-args", "width=9,height=9,penalty=1.0"),
            TWENTY_M,
            "Baseline for mb8k8_rec_pen1: a solo learner with the prediction loss at penalty 1.0. Social "
            "learning at that penalty needs it to stay on the plateau.",
        ),
        Setting(
            "mb8k8_none_pen1",
            "social_none",
            (*ONE_SAMPLE, "--env-args", "width=9,height=9,penalty=1.0"),
            TWENTY_M,
            "Baseline for mb8k8_rec_pen1: a social learner without an auxiliary loss at penalty 1.0 (the "
            "paper's vanilla PPO, which did not learn from the experts).",
        ),
        Setting(
            "mb8k8_pred_pen1",
            "social_pred",
            (*ONE_SAMPLE, "--env-args", "width=9,height=9,penalty=1.0"),
            TWENTY_M,
            "mb8k8_rec_pen1 with the paper's prediction loss instead of reconstruction.",
        ),
        Setting(
            "mb8k8_rec_pen125",
            "social_rec",
            (*ONE_SAMPLE, "--env-args", "width=9,height=9,penalty=1.25"),
            TWENTY_M,
            "Between 1.0, where both social (rec) and solo (pred) learners left the plateau by 8M env-steps, "
            "and 1.5, where rec stayed on it for 20M: a penalty at which following the experts may still "
            "pay before individual exploration does.",
        ),
        Setting(
            "mb8k8_solo_pred_pen125",
            "solo_pred",
            (*ONE_SAMPLE, "--env-args", "width=9,height=9,penalty=1.25"),
            TWENTY_M,
            "Baseline for mb8k8_rec_pen125: the solo learner with the prediction loss at penalty 1.25.",
        ),
        Setting(
            "mb8k8_none_pen125",
            "social_none",
            (*ONE_SAMPLE, "--env-args", "width=9,height=9,penalty=1.25"),
            TWENTY_M,
            "The other baseline for mb8k8_rec_pen125: social vanilla PPO (no auxiliary loss) at 1.25.",
        ),
        Setting(
            "mb8k8_pred_pen125",
            "social_pred",
            (*ONE_SAMPLE, "--env-args", "width=9,height=9,penalty=1.25"),
            TWENTY_M,
            "mb8k8_rec_pen125 with the paper's prediction loss instead of reconstruction.",
        ),
        Setting(
            "mb8k8_rec_7x7",
            "social_rec",
            (*ONE_SAMPLE, "--env-args", "width=7,height=7"),
            TWENTY_M,
            "mb8k8_rec in a 7x7 grid (5x5 interior) instead of 9x9: the 7x7 view then covers most of the "
            "grid, so the experts and the goals they visit are in view far more often, and an expert's "
            "path to the next goal is shorter to follow.",
        ),
        Setting(
            "mb8k8_solo_pred_7x7",
            "solo_pred",
            (*ONE_SAMPLE, "--env-args", "width=7,height=7"),
            TWENTY_M,
            "Baseline for mb8k8_rec_7x7: the solo learner with the prediction loss in the 7x7 grid, where "
            "individual exploration also finds the goals sooner; social learning there needs it to stay on "
            "the plateau.",
        ),
        Setting(
            "mb8k8_none_7x7",
            "social_none",
            (*ONE_SAMPLE, "--env-args", "width=7,height=7"),
            TWENTY_M,
            "The other baseline for mb8k8_rec_7x7: social vanilla PPO (no auxiliary loss) in the 7x7 grid.",
        ),
        Setting(
            "mb8k8_pred_7x7",
            "social_pred",
            (*ONE_SAMPLE, "--env-args", "width=7,height=7"),
            TWENTY_M,
            "mb8k8_rec_7x7 with the paper's prediction loss: whether the 7x7 grid frees the paper's own "
            "social learner too, so a pre-registered H1 can pool both auxiliary losses as the paper does.",
        ),
        Setting(
            "mb8k8_rec_8x8",
            "social_rec",
            (*ONE_SAMPLE, "--env-args", "width=8,height=8"),
            TWENTY_M,
            "After h1_early and h1_sooner: in the 7x7 grid a solo learner with the reconstruction loss "
            "leaves the plateau nearly as often and as soon as a social one (6 of 10 against 8 of 10 by "
            "8.0M; 3 of 15 against 5 of 15 by 6.0M), and in the 9x9 grid the social one stayed on it for "
            "20M (mb8k8_rec). Between them, an 8x8 grid (6x6 interior) may make individual exploration "
            "slow enough that following the experts pays: the grid at which to test whether they matter.",
        ),
        Setting(
            "mb8k8_solo_rec_8x8",
            "solo_rec",
            (*ONE_SAMPLE, "--env-args", "width=8,height=8"),
            TWENTY_M,
            "Baseline for mb8k8_rec_8x8: the same learner alone in the 8x8 grid. The setting is worth a "
            "pre-registered test only if this one stays on the plateau far more often than the social one.",
        ),
        Setting(
            "mb8k8_rec_8x8_pen2",
            "social_rec",
            (*ONE_SAMPLE, "--env-args", "width=8,height=8,penalty=2.0"),
            TWENTY_M,
            "After the 8x8 grid's seven seeds a condition (social 6 of 7, solo 4 of 7 by 20M, solo's first "
            "the earliest): a harsher penalty for a wrong tile makes solo's trial and error dearer, "
            "while a learner that follows the experts steps on tiles in their order. Worth a design only if "
            "solo learners stay on the plateau far more often than social ones.",
        ),
        Setting(
            "mb8k8_solo_rec_8x8_pen2",
            "solo_rec",
            (*ONE_SAMPLE, "--env-args", "width=8,height=8,penalty=2.0"),
            TWENTY_M,
            "Baseline for mb8k8_rec_8x8_pen2: the same learner alone in the 8x8 grid at penalty 2.0.",
        ),
        Setting(
            "mb8k8_pred_8x8",
            "social_pred",
            (*ONE_SAMPLE, "--env-args", "width=8,height=8"),
            TWENTY_M,
            "With the reconstruction loss the 8x8 grid's solo learners left the plateau nearly as often as "
            "social ones (4 of 7 against 6 of 7), and a penalty of 2.0 kept both on it. The paper's claim is "
            "for the next-frame prediction loss, which models the experts' moves (in 7x7: social 1 of 2, "
            "solo 0 of 2): whether it separates social from solo learners in the 8x8 grid.",
        ),
        Setting(
            "mb8k8_solo_pred_8x8",
            "solo_pred",
            (*ONE_SAMPLE, "--env-args", "width=8,height=8"),
            TWENTY_M,
            "Baseline for mb8k8_pred_8x8: the same learner alone in the 8x8 grid.",
        ),
        Setting(
            "mb8k8_pred",
            "social_pred",
            ONE_SAMPLE,
            TWENTY_M,
            "mb8k8_rec with the paper's next-frame prediction loss, which it found stronger than "
            "reconstruction: predicting the next frame models the experts' moves.",
        ),
        Setting(
            "mb16k2_rec",
            "social_rec",
            (),
            TWENTY_M,
            "The cpu scale's PPO unchanged (2 gradient samples per env-step, a recompute every 2 "
            "minibatches), to tell whether mb8k8's cheaper update costs sample efficiency (2.2x the CPU "
            "per env-step).",
        ),
        Setting(
            "map_g4_rec_7x7",
            "social_rec",
            (*ONE_SAMPLE, "--env-args", "width=7,height=7,n_goals=4"),
            TWENTY_M,
            "The map of where solo learners fail (issue 46), more goals: the laptop learner (PPO + rec, 7x7) "
            "beside the experts in a 4-goal cycle. With 4 tiles blind search meets a wrong tile more often "
            "before it finds the order, while the experts walk it in view.",
        ),
        Setting(
            "map_g4_solo_rec_7x7",
            "solo_rec",
            (*ONE_SAMPLE, "--env-args", "width=7,height=7,n_goals=4"),
            TWENTY_M,
            "Baseline for map_g4_rec_7x7: the same learner alone in the 7x7 4-goal cycle.",
        ),
    )
}


def train_flags(setting: Setting, seed: int, runs_dir: str) -> list[str]:
    """The `python -m jaxsocial.train` flags of one seed of `setting` (later flags override earlier)."""
    base = recipes.condition_flags(recipes.CPU, setting.condition, seed, 1, runs_dir)
    return [
        *base,
        *setting.flags,
        "--iterations",
        str(setting.iterations),
        "--run-name",
        f"{setting.name}-s{seed}",
        "--stop-at-return",
        str(STOP_RETURN),
    ]


def run_dir(setting: Setting, seed: int, runs_dir: str) -> Path:
    return Path(runs_dir) / f"{setting.name}-s{seed}"


def run(setting: Setting, seeds: list[int], runs_dir: str, cores: list[int]) -> list[int]:
    """Train `seeds` of `setting`, each in its own process pinned to one of `cores` (`pinned.run`).
    Returns the exit codes."""
    jobs = [
        pinned.Job(f"{setting.name} seed {seed}", pinned.train_command(train_flags(setting, seed, runs_dir)),
                   run_dir(setting, seed, runs_dir))
        for seed in seeds
    ]  # fmt: skip
    return pinned.run(jobs, cores)


def record(setting: Setting, seeds: list[int], runs_dir: str, device: str, jax_version: str) -> None:
    """Pack each seed's run directory into its record (`records.pack`), with the runner's provenance."""
    for seed in seeds:
        source = run_dir(setting, seed, runs_dir)
        provenance = pinned.run_provenance(source, device, jax_version)
        target = paths.RECORDS / RECORDS_SUBDIR / setting.name / rundir.seed_name(seed)
        records.pack(source, target, provenance, f"{RECORDS_SUBDIR}/{setting.name}/{rundir.seed_name(seed)}")
        print(f"recorded {target}")


def seed_summary(seed_dir: Path) -> dict[str, Any]:
    """One seed's takeoff (env-steps and CPU-minutes; None if it stayed on the plateau), final return and
    cost, from its record or run directory."""
    config = logs.read_config(seed_dir)
    rows = metrics.read_rows(seed_dir)
    prov = records.read_provenance(seed_dir) or {}
    cores = (prov.get("run") or {}).get("cores") or 1
    per_iteration = metrics.steps_per_iteration(config)
    iterations, returns = takeoff.window_curve(rows, per_iteration)
    lift = takeoff.takeoff(iterations, returns, LEARNED_RETURN)
    return {
        "seed": config["seed"],
        "iterations": len(rows),
        "env_steps": len(rows) * per_iteration,
        "cpu_minutes": metrics.cpu_minutes(rows, per_iteration, cores),
        "takeoff_env_steps": None if lift is None else lift * per_iteration,
        "takeoff_cpu_minutes": None
        if lift is None
        else metrics.cpu_minutes(rows, per_iteration, cores, lift),
        "stopped_early": bool((prov.get("record") or {}).get("stopped_early")),
        "final_return": metrics.final_return(rows),  # the last 10% of its iterations (until its stop)
        "expert_final_return": [metrics.final_return(rows, s) for s in metrics.slots(rows[-1]) if s != 0],
        "curve": {"env_steps": (iterations * per_iteration).tolist(), "return": returns.tolist()},
    }


def summarise(records_root: Path) -> dict[str, Any]:
    """Every recorded setting's seeds (`seed_summary`) and how many took off."""
    out: dict[str, Any] = {"learned_return": LEARNED_RETURN, "window_env_steps": takeoff.WINDOW_STEPS}
    out["settings"] = {}
    for setting_dir in sorted(p for p in (records_root / RECORDS_SUBDIR).glob("*") if p.is_dir()):
        seeds = [seed_summary(d) for d in sorted(setting_dir.glob("s*"), key=lambda d: int(d.name[1:]))]
        setting = SETTINGS.get(setting_dir.name)
        out["settings"][setting_dir.name] = {
            "why": setting.why if setting else None,
            "flags": list(setting.flags) if setting else None,
            "condition": setting.condition if setting else None,
            "seeds": seeds,
            "took_off": sum(s["takeoff_env_steps"] is not None for s in seeds),
            "n": len(seeds),
        }
    return out


def draw(summary: dict[str, Any], path: Path) -> None:
    """The fraction of seeds past the plateau against env-steps and against CPU-minutes, per setting, and
    each seed's learning curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 5.2))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (name, s) in enumerate(summary["settings"].items()):
        color, ls = colors[i % len(colors)], ("-", "--", ":")[i // len(colors) % 3]  # a style per setting
        for ax, unit, scale in ((axes[0], "env_steps", 1e6), (axes[1], "cpu_minutes", 1.0)):
            lifts = [
                None if x[f"takeoff_{unit}"] is None else x[f"takeoff_{unit}"] / scale for x in s["seeds"]
            ]
            end = max(x[unit] for x in s["seeds"]) / scale
            takeoff.draw(ax, lifts, end, name, color, ls)
        for j, seed in enumerate(s["seeds"]):
            axes[2].plot(
                np.array(seed["curve"]["env_steps"]) / 1e6,
                seed["curve"]["return"],
                color=color,
                ls=ls,
                lw=1,
                label=name if j == 0 else None,
            )
    axes[0].set(xlabel="env-steps (M)", ylabel="fraction of seeds past the plateau", ylim=(-0.02, 1.02))
    axes[1].set(xlabel="CPU-minutes (1 core per seed)", ylim=(-0.02, 1.02))
    axes[2].axhline(LEARNED_RETURN, color="grey", ls=":", lw=1)
    axes[2].set(xlabel="env-steps (M)", ylabel="learner return (per 200k-step window)")
    handles, labels = axes[0].get_legend_handles_labels()  # one legend for the three panels, below them
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f"Exploratory sweep (seeds < 100): takeoff = return > {LEARNED_RETURN:g} in a window")
    figures.save_png(fig, path, rect=(0, 0.12, 1, 1))


MAP_PAIRS = (
    ("7x7, 4 goals, rec", "map_g4_rec_7x7", "map_g4_solo_rec_7x7"),
    ("7x7, 3 goals, pred", "mb8k8_pred_7x7", "mb8k8_solo_pred_7x7"),
    ("8x8, 3 goals, rec", "mb8k8_rec_8x8", "mb8k8_solo_rec_8x8"),
    ("8x8, 3 goals, pred", "mb8k8_pred_8x8", "mb8k8_solo_pred_8x8"),
    ("8x8, penalty 2.0, rec", "mb8k8_rec_8x8_pen2", "mb8k8_solo_rec_8x8_pen2"),
    ("9x9, penalty 1.0, rec / solo pred", "mb8k8_rec_pen1", "mb8k8_solo_pred_pen1"),
    ("9x9, penalty 1.25, rec / solo pred", "mb8k8_rec_pen125", "mb8k8_solo_pred_pen125"),
)
"""The map of where solo learners fail (issue 46): per setting, (what it varies, the social learners' sweep
setting, the solo learners' one with the same loss where there is one)."""


def summarise_map(summary: dict[str, Any]) -> dict[str, Any]:
    """Per map setting with records, the social and solo seeds' takeoffs (env-steps, None: never) and
    budgets, from the sweep's summary."""
    out = {"window_env_steps": summary["window_env_steps"], "learned_return": summary["learned_return"]}
    cells = {}
    for label, social, solo in MAP_PAIRS:
        if social not in summary["settings"] or solo not in summary["settings"]:
            continue
        cells[label] = {
            who: {
                "setting": name,
                "takeoff_env_steps": [x["takeoff_env_steps"] for x in summary["settings"][name]["seeds"]],
                "env_steps": [x["env_steps"] for x in summary["settings"][name]["seeds"]],
                "took_off": summary["settings"][name]["took_off"],
                "n": summary["settings"][name]["n"],
            }
            for who, name in (("social", social), ("solo", solo))
        }
    out["cells"] = cells
    return out


def draw_map(summary: dict[str, Any], path: Path) -> None:
    """One panel per map setting: the fraction of its social and solo seeds past the plateau against
    env-steps (a seed stopped early at return 5 stays counted past the plateau)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cells = summary["cells"]
    cols = min(4, len(cells))
    rows = -(-len(cells) // cols)
    fig, grid = plt.subplots(rows, cols, figsize=(4.4 * cols, 3.6 * rows + 0.8), squeeze=False)
    for ax in list(grid.flat)[len(cells) :]:
        fig.delaxes(ax)
    for ax, (label, cell) in zip(grid.flat, cells.items(), strict=False):
        end = max(max(cell[who]["env_steps"]) for who in ("social", "solo")) / 1e6
        for who, color, ls in (("social", "C0", "-"), ("solo", "C1", "--")):
            lifts = [None if t is None else t / 1e6 for t in cell[who]["takeoff_env_steps"]]
            name = f"{who}: {cell[who]['took_off']} of {cell[who]['n']}"
            takeoff.draw(ax, lifts, end, name, color, ls)
        ax.set(title=label, xlabel="env-steps (M)", ylim=(-0.03, 1.03))
        ax.legend(fontsize=7, loc="upper left")
    grid[0, 0].set_ylabel("fraction of seeds past the plateau")
    fig.suptitle("Where solo learners fail (exploratory, seeds < 100): social (beside experts) against solo, "
                 f"takeoff = return > {summary['learned_return']:g} in a window")  # fmt: skip
    figures.save_png(fig, path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m jaxsocial.experiments.sweep", description=__doc__.split("\n")[0]
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the settings and why each is tried")
    for name in ("run", "record"):
        p = sub.add_parser(name)
        p.add_argument("setting", choices=sorted(SETTINGS))
        p.add_argument("--seeds", type=int, nargs="+", required=True, help="seeds, each below 100")
        p.add_argument("--runs-dir", default=str(paths.SWEEP_RUNS))
        if name == "run":
            p.add_argument(
                "--cores",
                type=int,
                nargs="+",
                default=list(range(os.cpu_count() or 1)),
                help="the CPU cores to pin the seeds' processes to, one process a core (default: all)",
            )
        else:
            p.add_argument("--device", required=True, help="the machine the runs trained on, in words")
    p = sub.add_parser("map", help="the map of where solo learners fail, from the sweep's summary")
    p.add_argument(
        "--summary",
        default=str(paths.SWEEP_SUMMARY.with_suffix(".json")),
        help="the sweep's summary (`figure` writes it)",
    )
    p.add_argument("--out", default=str(paths.MAP_SUMMARY), help="path without suffix")
    p = sub.add_parser("figure", help="summary JSON and figure of every recorded setting")
    p.add_argument("--records-dir", default=str(paths.RECORDS))
    p.add_argument("--out", default=str(paths.SWEEP_SUMMARY), help="path without suffix")
    args = parser.parse_args(argv)
    if args.command == "list":
        for s in SETTINGS.values():
            print(f"{s.name}: {s.condition} {shlex.join(s.flags)}, {s.iterations} iterations\n  {s.why}")
        return
    if args.command in ("run", "record") and any(not 0 <= s < 100 for s in args.seeds):
        parser.error("the sweep is exploratory: seeds must be in 0-99 (confirmatory designs use 200 and up)")
    setting = SETTINGS.get(getattr(args, "setting", None))
    if args.command == "run":
        codes = run(setting, args.seeds, args.runs_dir, args.cores)
        sys.exit(max(codes))
    if args.command == "record":
        import jax

        record(setting, args.seeds, args.runs_dir, args.device, jax.__version__)
        return
    if args.command == "map":
        found = summarise_map(logs.read_json(Path(args.summary)))
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        logs.write_json(out.with_suffix(".json"), found)
        draw_map(found, out.with_suffix(".png"))
        for label, cell in found["cells"].items():
            social, solo = cell["social"], cell["solo"]
            counts = f"social {social['took_off']} of {social['n']}, solo {solo['took_off']} of {solo['n']}"
            print(f"{label}: {counts}")
        print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.png')}")
        return
    summary = summarise(Path(args.records_dir))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    logs.write_json(out.with_suffix(".json"), summary)
    draw(summary, out.with_suffix(".png"))
    for name, s in summary["settings"].items():
        lifts = [x["takeoff_env_steps"] for x in s["seeds"]]
        print(f"{name}: {s['took_off']} of {s['n']} seeds past the plateau; takeoffs (env-steps) {lifts}")
    print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
