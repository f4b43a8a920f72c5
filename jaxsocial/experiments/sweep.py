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
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import shutil
import sys
from pathlib import Path
from typing import Any

from jaxsocial.experiments.analyse import plot_figures, records, rundirs, takeoff
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan import conditions, paths, recipes
from jaxsocial.run import jsonio, metrics, provenance, rundir
from jaxsocial.run.metrics import LEARNED_RETURN

RECORDS_SUBDIR = "sweep"
STOP_RETURN = 5.0
"""A seed stops once a chunk's mean learner return reaches this (`--stop-at-return`): clearly past the
one-tile plateau (about 1) and the takeoff threshold (`LEARNED_RETURN`), so its remaining budget is saved."""


SETTINGS_DIR = Path(__file__).parent / "sweeps"
"""`<name>.json` per setting: the fields of `Setting`."""


@dataclasses.dataclass(frozen=True)
class Setting:
    """One point of the sweep: `condition` at the cpu scale with `flags` on top, for `iterations`."""

    name: str
    condition: str
    flags: tuple[str, ...]
    iterations: int
    why: str


FIELDS = {
    "name": ("a string, the file's name", lambda v: isinstance(v, str)),
    "condition": (
        "one of conditions.CONDITIONS",
        lambda v: isinstance(v, str) and v in conditions.CONDITIONS,
    ),
    "flags": ("a list of strings", lambda v: isinstance(v, list) and all(isinstance(f, str) for f in v)),
    "iterations": ("a whole number >= 1", lambda v: type(v) is int and v >= 1),
    "why": ("a string", lambda v: isinstance(v, str)),
}
"""Each field of a setting's file: what it must be, and the check."""


def load_setting(path: Path) -> Setting:
    """The setting in `path`, a JSON object of `FIELDS` (ValueError naming the file and the field if a field
    is missing, unknown or not what `FIELDS` says, or `name` is not the file's stem; naming the file if it
    is not JSON)."""
    try:
        raw = jsonio.read_json(path)
    except json.JSONDecodeError as err:
        raise ValueError(f"sweep setting {path}: not JSON ({err})") from err
    if not isinstance(raw, dict):
        raise ValueError(f"sweep setting {path}: not a JSON object of the fields {list(FIELDS)}")
    for field in (*FIELDS, *raw):
        if field not in raw or field not in FIELDS:
            what = "missing" if field not in raw else "unknown"
            raise ValueError(f"sweep setting {path}: {what} field {field!r}; the fields are {list(FIELDS)}")
    for field, (must, ok) in FIELDS.items():
        if not ok(raw[field]) or field == "name" and raw[field] != path.stem:
            raise ValueError(f"sweep setting {path}: field {field!r} is {raw[field]!r}, not {must}")
    return Setting(**{**raw, "flags": tuple(raw["flags"])})


def load_settings(directory: Path = SETTINGS_DIR) -> dict[str, Setting]:
    """Every setting of `directory`, by name (`load_setting`)."""
    return {path.stem: load_setting(path) for path in sorted(directory.glob("*.json"))}


SETTINGS = load_settings()


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


def seed_state(setting: Setting, seed: int, runs_dir: str) -> str:
    """`rundirs.FINISHED` (every iteration of `setting` logged, or stopped early past the plateau), PARTIAL
    (its run directory exists: training resumes it) or MISSING."""
    directory = run_dir(setting, seed, runs_dir)
    if not (directory / rundir.CONFIG_FILE).is_file():
        return rundirs.MISSING
    rows = rundir.read_metrics(directory) if rundir.has_metrics(directory) else []
    finished = len(rows) >= setting.iterations or records.stopped_early(rundir.read_config(directory), rows)
    return rundirs.FINISHED if finished else rundirs.PARTIAL


def run(setting: Setting, seeds: list[int], runs_dir: str, cores: list[int]) -> list[int]:
    """Train `seeds` of `setting` that have not finished, each in its own process pinned to one of `cores`
    (`pinned.run`); an unfinished seed (a sitting stopped it, or `extend` started it) resumes from its latest
    checkpoint. Returns the exit codes of the processes run."""
    jobs = []
    for seed in seeds:
        state = seed_state(setting, seed, runs_dir)
        print(f"{setting.name} seed {seed}: {state}")
        if state != rundirs.FINISHED:
            flags = train_flags(setting, seed, runs_dir) + rundirs.resume_flags(state)
            label = f"{setting.name} seed {seed}"
            jobs.append(pinned.Job(label, pinned.train_command(flags), run_dir(setting, seed, runs_dir)))
    return pinned.run(jobs, cores) if jobs else []


def extend(shorter: Setting, setting: Setting, seeds: list[int], runs_dir: str) -> None:
    """Start each seed of `setting` as the continuation of its finished run in `shorter`, the same setting
    with a smaller budget (training has no schedule over iterations, so the continued run is the longer one,
    bit for bit on one CPU model): the shorter run's directory is copied under `setting`'s name, with its
    process file, which the record's provenance then lists under `earlier`. `run` trains the rest.
    ValueError, before anything is copied, if the settings differ otherwise, or a seed's shorter run is
    unfinished or stopped past the plateau, or its longer run exists."""
    if (shorter.condition, shorter.flags) != (setting.condition, setting.flags):
        raise ValueError(f"{setting.name} is not {shorter.name} with another budget: their flags differ")
    if shorter.iterations >= setting.iterations:
        raise ValueError(f"{shorter.name} has {shorter.iterations} iterations: not fewer than {setting.name}")
    pairs = [(run_dir(shorter, seed, runs_dir), run_dir(setting, seed, runs_dir)) for seed in seeds]
    for seed, (source, target) in zip(seeds, pairs, strict=True):
        if target.exists():
            raise ValueError(f"{target} exists: extend only starts a run")
        finished = seed_state(shorter, seed, runs_dir) == rundirs.FINISHED
        if not finished or not (source / provenance.RUN_FILE).is_file():
            raise ValueError(f"{source}: not a finished run of {shorter.name} by `run`; nothing to extend")
        if records.stopped_early(rundir.read_config(source), rundir.read_metrics(source)):
            raise ValueError(f"{source} stopped early past the plateau: nothing to extend")
    for seed, (source, target) in zip(seeds, pairs, strict=True):
        shutil.copytree(source, target)
        print(f"{setting.name} seed {seed}: starts from {source}")


def record(setting: Setting, seeds: list[int], runs_dir: str, device: str, jax_version: str) -> None:
    """Pack each seed's run directory into its record (`records.pack`), with the runner's provenance."""
    for seed in seeds:
        source = run_dir(setting, seed, runs_dir)
        run = pinned.run_provenance(source, device, jax_version)
        target = paths.RECORDS / RECORDS_SUBDIR / setting.name / rundir.seed_name(seed)
        records.pack(source, target, run, f"{RECORDS_SUBDIR}/{setting.name}/{rundir.seed_name(seed)}")
        print(f"recorded {target}")


def seed_summary(seed_dir: Path) -> dict[str, Any]:
    """One seed's takeoff (env-steps and CPU-minutes; None if it stayed on the plateau), final return and
    cost, from its record or run directory."""
    config = rundir.read_config(seed_dir)
    rows = rundir.read_metrics(seed_dir)
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


MAP_PAIRS = (
    ("7x7, 4 goals, rec", "map_g4_rec_7x7", "map_g4_solo_rec_7x7"),
    ("7x7, 4 goals, rec, 40.0M env-steps", "map_g4_40m_rec_7x7", "map_g4_40m_solo_rec_7x7"),
    ("7x7, 4 goals, rec, 80.0M env-steps", "map_g4_80m_rec_7x7", "map_g4_80m_solo_rec_7x7"),
    ("7x7, 4 goals, penalty 1.0, rec", "map_g4_pen1_rec_7x7", "map_g4_pen1_solo_rec_7x7"),
    ("7x7, 5 goals, rec", "map_g5_rec_7x7", "map_g5_solo_rec_7x7"),
    ("7x7, 125-step episodes, rec", "map_g3_steps125_rec_7x7", "map_g3_steps125_solo_rec_7x7"),
    ("7x7, clutter 0.3, rec", "map_g3_clutter03_rec_7x7", "map_g3_clutter03_solo_rec_7x7"),
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
    """Per map setting with records, the social and solo seeds' takeoffs (env-steps, None: never), budgets
    and final returns (the experts' too, per seed: one per expert slot), from the sweep's summary."""
    out = {"window_env_steps": summary["window_env_steps"], "learned_return": summary["learned_return"]}
    cells = {}
    for label, social, solo in MAP_PAIRS:
        if social not in summary["settings"] or solo not in summary["settings"]:
            continue
        cells[label] = {}
        for who, name in (("social", social), ("solo", solo)):
            seeds = summary["settings"][name]["seeds"]
            experts = [r for x in seeds for r in x["expert_final_return"]]
            cells[label][who] = {
                "setting": name,
                "seeds": [x["seed"] for x in seeds],
                "takeoff_env_steps": [x["takeoff_env_steps"] for x in seeds],
                "env_steps": [x["env_steps"] for x in seeds],
                "final_return": [x["final_return"] for x in seeds],
                "expert_final_return": [x["expert_final_return"] for x in seeds],
                "expert_mean_final_return": sum(experts) / len(experts) if experts else None,
                "took_off": summary["settings"][name]["took_off"],
                "n": summary["settings"][name]["n"],
            }
    out["cells"] = cells
    return out


def map_table(found: dict[str, Any]) -> list[str]:
    """The map (`summarise_map`) as Markdown table lines: per cell, each arm's seeds past the plateau, each
    seed's takeoff in env-steps ("-": not within its budget), the budget, and the experts' mean final return
    beside the social learners. (Final returns of learners are left out: a seed past the plateau stops at
    return `STOP_RETURN`.)"""
    lines = [
        "| setting | social learned | solo learned | takeoffs (env-steps): social; solo | budget | experts |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for label, cell in found["cells"].items():
        social, solo = cell["social"], cell["solo"]
        lifts = "; ".join(
            ", ".join("-" if t is None else f"{t / 1e6:.2f}M" for t in arm["takeoff_env_steps"])
            for arm in (social, solo)
        )
        budget = max(max(arm["env_steps"]) for arm in (social, solo))
        experts = social["expert_mean_final_return"]
        lines.append(
            f"| {label} | {social['took_off']} of {social['n']} | {solo['took_off']} of {solo['n']} "
            f"| {lifts} | {budget / 1e6:.1f}M | {'-' if experts is None else f'{experts:.1f}'} |"
        )
    return lines


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
        import jax

        record(SETTINGS[args.setting], args.seeds, args.runs_dir, args.device, jax.__version__)
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
