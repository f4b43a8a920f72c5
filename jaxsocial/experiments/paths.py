"""Where the experiments read and write, relative to the repository root: the committed results under
`RESULTS` (records, summaries, deviations, evidence) and the default scratch directories under `RUNS`.

Every other module of `jaxsocial.experiments` names these paths through this one; a command-line default
is the path as a string (`str(paths.RECORDS)`), since commands are written into the summaries."""

from __future__ import annotations

from pathlib import Path

RESULTS = Path("benchmarks/results")
"""The repository's committed results."""
RECORDS = RESULTS / "records"
"""The runs' records (`records.pack`), mirroring the run directories."""
SCIENCE = RESULTS / "science"
"""The committed summaries and figures (`figure --out-dir benchmarks/results/science`)."""
DEVIATIONS = RESULTS / "deviations"
"""`<design>.json`: what happened to a design's runs that its rules did not foresee (`prereg.deviations`)."""
EVIDENCE = SCIENCE / "experts-evidence"
"""The committed evaluations a takeoff design's power is simulated from (`takeoff_power`)."""
POOLED_SUMMARY = SCIENCE / "laptop-pooled.json"
"""The pooled laptop seeds' summary (`takeoff_power.pooled_summary`): the designs that chose `experts`."""
POOLED_ALL_SUMMARY = SCIENCE / "laptop-pooled-all.json"
"""The same over every laptop design's fresh PPO + rec seeds, `experts` included."""
SWEEP_SUMMARY = SCIENCE / "sweep"
"""The exploratory sweep's summary and figure, without their suffix (.json, .png)."""
MAP_SUMMARY = SCIENCE / "map"
"""The map of where solo learners fail, without its suffix (.json, .png)."""
RECIPE_SPS = RESULTS / "recipe_sps.json"
"""The measured single-core training rates of the cpu scale's conditions (`recipes.Rate`)."""
RECIPE_SPS_LAPTOP = RESULTS / "recipe_sps_laptop.json"
"""The same at the laptop scale."""

RUNS = Path("runs")
"""The default root of everything trained or written here that is not committed."""
EXPERIMENT_RUNS = RUNS / "experiments"
"""The recipes' and follow-ups' run directories (`--runs-dir`)."""
FIGURES = EXPERIMENT_RUNS / "figures"
"""Where `figure` writes by default."""
RECORDS_OUT = RUNS / "records"
"""Where `record` writes by default (the repository's records: `--out-dir benchmarks/results/records`)."""
SWEEP_RUNS = RUNS / "sweep"
"""The exploratory sweep's run directories."""


def require_checkout() -> None:
    """Stop with a clear error, before anything is read or written, where the working directory holds no
    `RESULTS`: the experiments work on a checkout of the repository, from its root."""
    if not RESULTS.is_dir():
        raise SystemExit(
            f"error: no {RESULTS}/ in {Path.cwd()}: the experiments read and write the committed results "
            "of a checkout of the repository; run them from the root of a clone (an installed jaxsocial "
            "package holds the library, not the experiments' records)"
        )
