"""Summaries (JSON) and figures (PNG) of a recipe, read from its run directories or their records.

Every number comes from the runs' metrics and post-training evaluations; nothing is hard-coded. A
condition's *final return* is, per seed, the learner's episode-weighted mean return over the last 10% of
training iterations (the issue's measure); the 95% confidence interval is Student t over seeds. A seed has
*learned* if its final return exceeds `LEARNED_RETURN`; learned counts are compared with one-sided exact
tests (`stats`), and each seed's takeoff (`takeoff`) gives the time-to-learning curve (`time_to_learning`,
with each seed's CPU-minutes of training and their sum where every record names its cores). Every summary
says how it was made (`provenance`: the command that re-creates it, and each seed's recorded training
command, commit, device and jax version; seeds without a record are listed) and, for a recipe with a design,
what was pre-registered and what its tests found (`design_results`). What a summary and figure hold besides
depends on the recipe's kind (`kinds.KINDS`); the metrics rows are read through `jaxsocial.run.metrics`.
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

from jaxsocial.experiments.analyse import design_results, kinds, records, rundirs
from jaxsocial.experiments.analyse.kinds import takeoffs
from jaxsocial.experiments.plan import paths, prereg, recipes
from jaxsocial.experiments.plan.conditions import CONDITIONS
from jaxsocial.experiments.plan.recipes import Recipe, Scale
from jaxsocial.run import jsonio, provenance, rundir
from jaxsocial.run.flags import config_flags
from jaxsocial.run.metrics import LEARNED_RETURN


class RecipeRuns:
    """The run directories of a recipe at a scale and seed range, with their metrics. Seeds without metrics
    are left out of their condition (`missing_seeds`), and conditions without any are left out (`missing`);
    FileNotFoundError if all are. A design's arm borrowed from another design (`Design.borrowed`, at the
    design's scale) is read from that design's records at its seeds: its conditions join the recipe's,
    `lenders` names their design, and `borrowed_scores` the evaluation design that scored them, if any."""

    def __init__(
        self, recipe: Recipe, scale: Scale, seed: int, seeds: int, runs_dir: str, pick: tuple[str, ...] = ()
    ):
        self.recipe, self.scale = recipe, scale
        self.configs, self.seed_dirs, self.rows, self.missing_seeds, self.dirs_by_seed = {}, {}, {}, {}, {}
        for c in recipe.conditions:
            self._read(c, scale, seed, seeds, runs_dir, pick)
        self.lenders = lenders(recipe, scale)
        self.borrowed_scores = borrowed_scores(recipe) if self.lenders else None
        for c, lender in self.lenders.items():
            lent_scale = prereg.recipe_scale(design_recipe(lender.name), recipes.SCALES[lender.scale])
            self._read(c, lent_scale, lender.seed, lender.seeds, runs_dir, pick)
        self.missing = [c for c, seed_rows in self.rows.items() if not seed_rows]
        if len(self.missing) == len(self.configs):
            where = Path(runs_dir) / scale.runs_root
            raise FileNotFoundError(
                paths.missing_records(where)
                or f"no metrics for any condition of {recipe.name} under {where}: run `python -m "
                f"jaxsocial.experiments run {recipe.name} --scale {scale.name} --seeds {seeds}` first"
            )
        for c in self.missing:  # drawn without them; the summary lists them
            del self.configs[c], self.seed_dirs[c], self.rows[c]
        self.seed, self.seeds, self.runs_dir = seed, seeds, runs_dir

    def _read(
        self, c: str, scale: Scale, seed: int, seeds: int, runs_dir: str, pick: tuple[str, ...]
    ) -> None:
        """Read condition `c`'s seeds seed..seed+seeds-1 at `scale`: its first program's config (a condition
        trained one program per seed: the first seed's), its seed directories and metrics rows."""
        self.configs[c] = recipes.condition_programs(scale, c, seed, seeds, runs_dir)[0]
        dirs = rundirs.condition_seed_dirs(scale, c, seed, seeds, runs_dir, pick)
        rows = [rundir.read_metrics(d) for d in dirs]
        self.dirs_by_seed[c] = [d if r else None for d, r in zip(dirs, rows, strict=True)]
        self.seed_dirs[c] = [d for d, r in zip(dirs, rows, strict=True) if r]
        self.rows[c] = [r for r in rows if r]
        absent = [s for s, r in zip(range(seed, seed + seeds), rows, strict=True) if not r]
        if absent and self.rows[c]:
            self.missing_seeds[c] = absent

    def flags(self, condition: str) -> list[str]:
        """The training command line of a condition's (first) program."""
        return config_flags(self.configs[condition])

    def command(self, out_dir: str | None = None) -> str:
        """The `figure` command that re-creates this summary (written into `out_dir`, default the CLI's)."""
        argv = ["figure", self.recipe.name, "--scale", self.scale.name, "--seed", str(self.seed)]
        argv += ["--seeds", str(self.seeds), "--runs-dir", self.runs_dir]
        argv += ["--out-dir", out_dir] if out_dir is not None else []
        return "python -m jaxsocial.experiments " + shlex.join(argv)

    def provenance(self) -> dict[str, Any]:
        """How the runs were made: per condition, the recorded training commands (`records.read_provenance`)
        with the seeds each trained, its commit, device, jax version, start, end and exit status; seeds
        without a record are listed under 'unrecorded'."""
        runs: dict[str, list[dict[str, Any]]] = {}
        unrecorded = []
        for c, dirs in self.seed_dirs.items():
            for d in dirs:
                prov = records.read_provenance(d)
                if prov is None:
                    unrecorded.append(str(d))
                    continue
                run = prov.get("run", prov)
                seed = rundir.read_config(d).get("seed")
                same = [r for r in runs.setdefault(c, []) if r["command"] == run.get("command")]
                if same:
                    same[0]["seeds"].append(seed)
                    continue
                runs[c].append({"seeds": [seed], **{k: run.get(k) for k in provenance.RUN_FIELDS}})
        return {"training_runs": runs, "unrecorded": unrecorded}

    def commits(self) -> dict[str, str | None]:
        """Each seed directory's recorded training commit (None: no record), borrowed conditions aside (they
        were trained for their own design)."""
        return {
            str(d): records.run_field(d, "commit")
            for c, dirs in self.seed_dirs.items()
            if c not in self.lenders
            for d in dirs
        }

    def of_design(self, name: str) -> RecipeRuns:
        """Design `name`'s runs at its own scale and seeds, under the same runs folder (`design_runs`)."""
        return design_runs(name, self.runs_dir)

    def header(self, command: str) -> dict[str, Any]:
        def short(seed_dir: Path, rows: list[dict[str, Any]], iterations: int) -> bool:
            return len(rows) < iterations and not records.stopped_early(rundir.read_config(seed_dir), rows)

        unfinished = {
            c: [len(r) for r in rows]
            for c, rows in self.rows.items()
            if any(
                short(d, r, self.configs[c].iterations) for d, r in zip(self.seed_dirs[c], rows, strict=True)
            )
        }
        cfg = next(iter(self.configs.values()))
        return {
            "recipe": self.recipe.name,
            "title": self.recipe.title,
            "scale": self.scale.name,
            "scale_note": self.scale.note,
            "command": command,
            "provenance": self.provenance(),
            "config": {
                c: {
                    "flags": shlex.join(self.flags(c)),
                    "label": CONDITIONS[c].label,
                    "program_per_seed": CONDITIONS[c].program_per_seed,
                }
                for c in self.configs
            },
            "seed_dirs": {c: [str(d) for d in dirs] for c, dirs in self.seed_dirs.items()},
            "env_steps_per_run": cfg.iterations * cfg.num_envs * cfg.rollout_steps,
            "unfinished_runs": unfinished,
            "missing_conditions": self.missing,
            "missing_seeds": self.missing_seeds,
            **({"borrowed": {c: lender.name for c, lender in self.lenders.items()}} if self.lenders else {}),
        }


def design_recipe(name: str) -> Recipe:
    """The recipe that carries design `name`."""
    return next(r for r in recipes.RECIPES.values() if r.design == name)


def lenders(recipe: Recipe, scale: Scale) -> dict[str, prereg.TrainingDesign]:
    """The conditions the recipe's design borrows at its own scale, each with the design it borrows from
    ({} for a recipe without a design or at another scale)."""
    if recipe.design is None:
        return {}
    design = prereg.TrainingDesign.read(recipe.design)
    if design.scale != scale.name:
        return {}
    return {
        c: prereg.TrainingDesign.read(name)
        for arm, name in design.borrowed.items()
        for c in getattr(design, arm)
    }


def borrowed_scores(recipe: Recipe) -> Path | None:
    """The folder of the evaluation design that scored the borrowed arm of the recipe's 'zero_shot' design
    (its `tests['borrowed_scores']`, under `paths.SCIENCE`); None for another design."""
    design = prereg.TrainingDesign.read(recipe.design)
    name = design.tests.get("borrowed_scores") if design.analysis == "zero_shot" else None
    return None if name is None else paths.SCIENCE / name


def outcome_lines(summary: dict[str, Any]) -> list[str]:
    """What a summary found, a line per condition: its final return (mean and 95% interval over seeds,
    where the summary has one) and how many seeds left the one-tile plateau, and when the first did."""
    finals = {**summary.get("training", {}), **summary.get("conditions", {})}
    lines = []
    for c, t in summary.get("time_to_learning", {}).get("conditions", {}).items():
        label = CONDITIONS[c].label if c in CONDITIONS else c
        text = f"{label}: {t['took_off']} of {t['seeds']} seeds past the one-tile plateau"
        steps = [s for s in t["takeoff_env_steps"] if s is not None]
        text += f" (the first at {min(steps):,} env-steps)" if steps else ""
        final = finals.get(c, {})
        if isinstance(final, dict) and final.get("mean") is not None:
            lo, hi = final["ci95"]
            text += f"; final return {final['mean']:.3g} [{lo:.3g}, {hi:.3g}]"
        lines.append(text)
    return lines


def summarize(runs: RecipeRuns, command: str | None = None) -> dict[str, Any]:
    """The JSON summary of a recipe (see the module docstring for the measures; the kind's part from
    `kinds.KINDS`); `command` re-creates it (default: `runs.command()`)."""
    out = runs.header(runs.command() if command is None else command)
    out.update(kinds.kind_of(runs.recipe).summarise(runs))
    conditions = takeoffs(runs)
    minutes = [m for c in conditions.values() for m in c["cpu_minutes"]]
    out["time_to_learning"] = {
        "learned_return": LEARNED_RETURN,
        "conditions": conditions,
        "cpu_minutes": None if None in minutes else round(sum(minutes), 1),
    }
    if runs.recipe.design is not None:
        out["preregistered"] = design_results.preregistered(runs, out)
    return out


def design_runs(name: str, runs_dir: str) -> RecipeRuns:
    """The runs of design `name` at its own scale and seeds, under `runs_dir`."""
    design, recipe = prereg.TrainingDesign.read(name), design_recipe(name)
    scale = prereg.recipe_scale(recipe, recipes.SCALES[design.scale])
    return RecipeRuns(recipe, scale, design.seed, design.seeds, runs_dir)


def incomplete_design(runs: RecipeRuns) -> str | None:
    """For the runs of a pre-registered design at its own scale (which read exactly the design's seeds) that
    lack a finished run of some design seed, what is in ('design experts: 12 of 80 runs finished'); None
    otherwise (no design, another scale, or every seed finished)."""
    if runs.recipe.design is None:
        return None
    design = prereg.TrainingDesign.read(runs.recipe.design)
    if runs.scale.name != design.scale:
        return None
    arms = design.trained_conditions

    def over(c: str, rows: list[dict[str, Any]]) -> bool:  # every iteration logged, or the design's stop
        if len(rows) >= design.iterations or design.stop_at_return is None:
            return len(rows) >= design.iterations
        stop = {"stop_at_return": design.stop_at_return, "chunk_iterations": runs.configs[c].chunk_iterations}
        return records.stopped_early(stop, rows)

    finished = sum(over(c, rows) for c in arms for rows in runs.rows.get(c, []))
    total = design.seeds * len(arms)
    return None if finished == total else f"design {design.name}: {finished} of {total} runs finished"


def draw(runs: RecipeRuns, summary: dict[str, Any], path: Path) -> None:
    """The recipe's figure as a PNG (the kind's `draw`)."""
    kinds.kind_of(runs.recipe).draw(runs, summary, path)


def write(runs: RecipeRuns, out_dir: str) -> tuple[Path, Path]:
    """Write `<recipe>-<scale>.json` and `.png` into `out_dir`; returns their paths. The summary records
    the command that re-creates them (`RecipeRuns.command`)."""
    summary = summarize(runs, runs.command(out_dir))
    out_dir = Path(out_dir)
    stem = out_dir / f"{runs.recipe.name}-{runs.scale.name}"
    json_path, png_path = stem.with_suffix(".json"), stem.with_suffix(".png")
    out_dir.mkdir(parents=True, exist_ok=True)
    jsonio.write_json(json_path, summary, indent=1)
    draw(runs, summary, png_path)
    return json_path, png_path


def against_committed(summary: dict[str, Any], committed: dict[str, Any]) -> list[str]:
    """How a summary of one's own runs compares with the committed summary of the same recipe and scale, a
    line per condition both have: seeds past the plateau in each, and whether one's mean final return lies
    inside the committed 95% interval."""
    lines = []
    for c, mine in summary.get("conditions", {}).items():
        theirs = committed.get("conditions", {}).get(c)
        if theirs is None or "seeds_above_one_tile" not in mine or mine.get("mean") is None:
            continue
        label = CONDITIONS[c].label if c in CONDITIONS else c
        seeds = lambda x: sum(v is not None for v in x["final_returns"])  # noqa: E731
        text = (
            f"{label}: yours {mine['seeds_above_one_tile']} of {seeds(mine)} past the plateau, final return "
            f"{mine['mean']:.3g}; committed {theirs['seeds_above_one_tile']} of {seeds(theirs)}, "
            f"{theirs['mean']:.3g}"
        )
        if theirs.get("ci95"):
            lo, hi = theirs["ci95"]
            where = "inside" if lo <= mine["mean"] <= hi else "outside"
            text += f" [{lo:.3g}, {hi:.3g}]: yours is {where} its 95% interval"
        lines.append(text)
    return lines
