"""The exploratory sample-efficiency sweep: which settings make auxiliary-loss learners leave the one-tile
plateau early on a 2-core CPU (exploration only: seeds below 100, no confirmatory result).

A *setting* is a condition of `conditions.CONDITIONS` at the cpu scale with some flags changed, a budget and
the reason it is tried. Each seed trains in a process of its own pinned to one core (`pinned`), and its
record goes to
``benchmarks/results/records/sweep/<setting>/s<seed>/``. The summary (`summarise`) gives per setting each
seed's takeoff (`takeoff.seed_takeoff`: the end of the first window of about 200k env-steps whose mean
learner return exceeds `metrics.LEARNED_RETURN`) in env-steps and in CPU-minutes on the machine that ran
it, the fraction of seeds past the plateau against both, and the final returns.

    python -m jaxsocial.experiments sweep list
    python -m jaxsocial.experiments sweep run mb8k8_rec --seeds 0 1 --cores 0 1   # one process a core
    python -m jaxsocial.experiments sweep run map_g4_40m_rec_7x7 --seeds 0 --extend map_g4_rec_7x7
    python -m jaxsocial.experiments sweep record mb8k8_rec --seeds 0 1 --device "AMD EPYC, 2 cores"
    python -m jaxsocial.experiments sweep figure                         # every recorded setting
    python -m jaxsocial.experiments sweep map                            # social against solo, per setting

The settings are data, `sweeps/<name>.json` beside this module (`load_setting`). Those named `mb8k8_*` and
`map_*` take one gradient sample per env-step, the targets of the rollout only (`--ppo.num-minibatches 8
--ppo.recompute-every 8`: 2.2x the env-steps/s of the cpu scale's two samples with a recompute every 2
minibatches, docs/performance.md); every setting runs at least 2442 iterations of 8,192 env-steps, 20.0M,
the sweep goal's horizon (`*_40m_*`: twice that). `run` again resumes the seeds a sitting stopped; with
`--extend SHORTER` a seed of a longer budget starts from its finished run of the same setting with a shorter
one (`extend`).

This module is the command; the parts are in the three layers: `plan.sweep_settings` (the settings and the
map's pairs), `launch.sweep_runs` (training, extending, recording), `analyse.sweep_results` (the summary and
the map).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

from jaxsocial.experiments.analyse import plot_figures
from jaxsocial.experiments.analyse.sweep_results import map_table, summarise, summarise_map
from jaxsocial.experiments.launch.sweep_runs import extend, record, run
from jaxsocial.experiments.plan import paths
from jaxsocial.experiments.plan.sweep_settings import SETTINGS
from jaxsocial.run import jsonio


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m jaxsocial.experiments sweep", description=__doc__.split("\n")[0]
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
                "--extend",
                choices=sorted(SETTINGS),
                help="start each seed from its finished run of this setting, the same with a smaller budget",
            )
            p.add_argument(
                "--cores",
                type=int,
                nargs="+",
                default=list(range(os.cpu_count() or 1)),
                help="the CPU cores to pin the seeds' processes to, one process a core (default: all)",
            )
        else:
            p.add_argument(
                "--device",
                default=None,
                help="the machine the runs trained on, in words (default: the CPU each process measured)",
            )
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
    return parser


def check_seeds(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The sweep is exploratory: its seeds are below 100."""
    if args.command in ("run", "record") and any(not 0 <= s < 100 for s in args.seeds):
        parser.error("the sweep is exploratory: seeds must be in 0-99 (confirmatory designs use 200 and up)")


def main(argv: list[str] | None = None) -> None:
    args = paths.parse_command(make_parser, argv, check_seeds)
    if args.command == "list":
        for s in SETTINGS.values():
            print(f"{s.name}: {s.condition} {shlex.join(s.flags)}, {s.iterations} iterations\n  {s.why}")
    elif args.command == "run":
        if args.extend:
            try:
                extend(SETTINGS[args.extend], SETTINGS[args.setting], args.seeds, args.runs_dir)
            except ValueError as err:
                raise SystemExit(f"error: {err}") from err
        sys.exit(max(run(SETTINGS[args.setting], args.seeds, args.runs_dir, args.cores), default=0))
    elif args.command == "record":
        try:
            record(SETTINGS[args.setting], args.seeds, args.runs_dir, args.device)
        except (ValueError, FileNotFoundError) as err:
            raise SystemExit(f"error: {err}") from err
    elif args.command == "map":
        found = summarise_map(jsonio.read_json(Path(args.summary)))
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        jsonio.write_json(out.with_suffix(".json"), found)
        plot_figures.draw_map(found, out.with_suffix(".png"))
        print("\n".join(map_table(found)))
        print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.png')}")
    else:
        summary = summarise(Path(args.records_dir))
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        jsonio.write_json(out.with_suffix(".json"), summary)
        plot_figures.draw_sweep(summary, out.with_suffix(".png"))
        for name, s in summary["settings"].items():
            lifts = [x["takeoff_env_steps"] for x in s["seeds"]]
            print(f"{name}: {s['took_off']} of {s['n']} seeds past the plateau; takeoffs (env-steps) {lifts}")
        print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.png')}")
