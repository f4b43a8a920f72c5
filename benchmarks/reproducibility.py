"""Do CPU models agree bit for bit, and which XLA setting makes them? (issue 50, item 2)

Trains the first K iterations of a reference record's config (`REFERENCE`: the laptop recipe's social PPO +
rec, seed 210 of `h1_early`, trained on an AMD EPYC family 25 model 17 with the default single-core flags)
once per setting, each in a single-core process as the designs train (`pinned.SINGLE_CORE_XLA_FLAGS`, then
the setting's flags, the process pinned to one core as `pinned.run` pins the records': XLA's bits depend on
the cores a process sees), and keeps every metrics field but the timings. Each setting's rows are compared
with the record's (the first row and field that differ, `verify.first_difference`) and go to one JSON per
machine kind (`benchmarks/results/reproducibility/<cpu>.json`, named from the CPU's model and family/model
numbers, each setting with the cores its process saw: `visible_cores`); each run also compares its rows with
every other kind's committed file, setting by setting where both saw one core: a setting with no
difference across the kinds seen makes the laptop recipe bitwise reproducible across them. The env-steps/s
of each setting is recorded with the load average, so the speed cost is read on a quiet machine only.

    python benchmarks/reproducibility.py                     # every setting, 10 iterations
    python benchmarks/reproducibility.py --settings default max_isa_avx2 --iterations 20
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import tempfile
from pathlib import Path

from run_info import REPO, metadata, portable, write_json

from jaxsocial.experiments.launch import pinned, verify
from jaxsocial.run import autotune, config, cpuinfo, jsonio, metrics, rundir

NO_YNN = "-individual_dot,-individual_convolution,-dot,-eltwise,-reduce"
"""Every YNNPACK fusion type removed from XLA's default list: jaxlib 0.10.2 sends dots and reductions to
YNNPACK by default (139 fusions in the laptop recipe's program), which picks its kernels for the CPU at run
time; without them, dots go to Eigen and reductions to XLA's own code."""
SETTINGS = {
    "default": "",
    "max_isa_avx2": "--xla_cpu_max_isa=AVX2",
    "max_isa_avx512_bf16": "--xla_cpu_max_isa=AVX512_BF16",
    "no_platform_math": pinned.CROSS_CPU_XLA_FLAGS,  # the pre-registered designs' since 2026-11-28
    "vector_width_256": "--xla_cpu_prefer_vector_width=256",
    "no_xnnpack": "--xla_cpu_use_xnnpack=false",
    "strict_math": "--xla_cpu_strict_dot_conv_math=true --xla_cpu_enable_fast_math=false",
    "no_ynn": f"--xla_cpu_experimental_ynn_fusion_type={NO_YNN}",
    "portable": "--xla_cpu_max_isa=AVX2 --xla_cpu_use_xnnpack=false --xla_cpu_strict_dot_conv_math=true "
    "--xla_cpu_enable_fast_math=false --xla_cpu_enable_platform_dependent_math=false "
    f"--xla_cpu_experimental_ynn_fusion_type={NO_YNN}",
}
"""Setting name -> XLA flags added to the single-core ones: the candidates of issue 50 (the host's instruction
set, capped at AVX2 or at AVX512_BF16, the ceiling of an AMD Zen 4; the kernel library chosen at run time;
fast-math and FMA contraction in dots and convolutions; XLA's "platform dependent math", which its help says
trades consistent results across CPUs for speed; the vector width LLVM prefers; dots and reductions out of
YNNPACK, which XLA calls for them by default)."""
OUT_DIR = REPO / "benchmarks/results/reproducibility"
REFERENCE = REPO / "benchmarks/results/records/laptop/prereg-h1_early/social_rec-s210-210"
ONE_CORE = verify.retraining_cores(1)
"""The core each setting's process is pinned to, as verify pins the re-training of a one-core record."""


def kind_file(cpu: str, out_dir: Path = OUT_DIR) -> Path:
    """A machine kind's JSON in `out_dir`: the CPU description as a file name."""
    return out_dir / (cpuinfo.slug(cpu) + ".json")


def kind_arguments(parser: argparse.ArgumentParser, committed: Path) -> None:
    """The options of a per-kind benchmark whose kinds' files are committed in `committed`."""
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument(
        "--out-dir",
        default=str(committed),
        help="where this kind's JSON goes (e.g. $OUT on a device machine's CPU); other kinds' files are read "
        f"from {committed.relative_to(REPO)}",
    )


def this_kind(out_dir: str) -> tuple[Path, dict]:
    """This machine kind's JSON in `out_dir` and what it holds ({"cpu", "settings": {}} where it is new),
    without the settings that `SETTINGS` no longer has, whose flags have changed since they ran, or that ran
    seeing other than one core (before 2026-11-28 they ran seeing every core)."""
    cpu = cpuinfo.model()
    path = kind_file(cpu, Path(out_dir))
    found = jsonio.read_json(path) if path.exists() else {"cpu": cpu, "settings": {}}
    found["settings"] = {
        name: entry
        for name, entry in found["settings"].items()
        if name in SETTINGS and entry["xla_flags"] == setting_flags(name) and seen_one_core(entry)
    }
    return path, found


def seen_one_core(entry: dict) -> bool:
    """Whether a setting's entry was measured by a process that saw one core, as the records trained."""
    return entry.get("visible_cores") == 1


def describe_kind(found: dict, args: argparse.Namespace) -> None:
    """Add to a kind's JSON the instruction sets present (`autotune.MACHINE_FLAGS`) and the run's metadata."""
    found["cpu_flags"] = sorted(f for f in autotune.MACHINE_FLAGS if f in cpuinfo.flags())
    found["metadata"] = metadata(args)


def other_kinds(path: Path, committed: Path) -> list[dict]:
    """Every committed kind's JSON in `committed` but the one named as `path`."""
    return [jsonio.read_json(other) for other in sorted(committed.glob("*.json")) if other.name != path.name]


def setting_flags(setting: str) -> str:
    """The $XLA_FLAGS a setting trains with: the single-core ones, then the setting's."""
    return f"{pinned.SINGLE_CORE_XLA_FLAGS} {SETTINGS[setting]}".strip()


def rows_of(setting: str, iterations: int) -> tuple[list[dict], float]:
    """The reference record's first `iterations` rows re-trained under `setting`, timings removed, and the
    median env-steps/s of its rows."""
    cfg = config.config_from_dict(rundir.read_config(REFERENCE))
    chunk = min(cfg.chunk_iterations, iterations)
    cfg = dataclasses.replace(cfg, iterations=iterations, chunk_iterations=chunk)
    with tempfile.TemporaryDirectory(prefix="jaxsocial-repro-") as tmp:
        rows = rundir.read_metrics(verify.train_in_process(cfg, Path(tmp), setting_flags(setting), ONE_CORE))
    speed = statistics.median(r[metrics.SPEED] for r in rows)
    return [without_timings(r) for r in rows], speed


def without_timings(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in verify.TIMING_FIELDS}


def compare(mine: dict, other: dict) -> dict:
    """Per setting both kinds ran seeing one core: 'exact' or the first difference
    (`verify.first_difference`)."""
    out = {}
    for name, entry in mine["settings"].items():
        theirs = other["settings"].get(name)
        if theirs is None or not seen_one_core(theirs):
            continue
        n = min(len(entry["rows"]), len(theirs["rows"]))
        difference = verify.first_difference(theirs["rows"][:n], entry["rows"][:n])
        out[name] = {"rows": n, "exact": difference is None, "first_difference": difference}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    kind_arguments(parser, OUT_DIR)
    parser.add_argument("--iterations", type=int, default=10)
    args = parser.parse_args()
    if args.iterations < 1:
        parser.error(f"--iterations {args.iterations} must be >= 1")
    path, found = this_kind(args.out_dir)
    if found.get("reference") != portable(str(REFERENCE)):  # rows of another reference do not compare
        found = {"cpu": found["cpu"], "settings": {}}
    found["reference"] = portable(str(REFERENCE))
    for name in args.settings:
        rows, speed = rows_of(name, args.iterations)
        recorded = [without_timings(r) for r in rundir.read_metrics(REFERENCE)[: len(rows)]]
        found["settings"][name] = {
            "xla_flags": setting_flags(name),
            "visible_cores": pinned.cores_seen(ONE_CORE),
            "against_reference": verify.first_difference(recorded, rows),
            "env_steps_per_s_median": round(speed, 1),
            "load_average": list(os.getloadavg()),
            "rows": rows,
        }
        d = found["settings"][name]["against_reference"]
        against = "exact" if d is None else f"differs from iteration {d['iteration']} ({d['field']})"
        load = os.getloadavg()[0]
        print(f"{name}: {speed:,.0f} env-steps/s (load {load:.2f}); against the record: {against}")
    describe_kind(found, args)
    found["against"] = {}
    for other in other_kinds(path, OUT_DIR):
        found["against"][other["cpu"]] = compare(found, other)
        for name, c in found["against"][other["cpu"]].items():
            d = c["first_difference"]
            verdict = "exact" if c["exact"] else f"differs from iteration {d['iteration']} ({d['field']})"
            print(f"against {other['cpu']}, {name}: {verdict}")
    write_json(path, portable(found))


if __name__ == "__main__":
    sys.exit(main())
