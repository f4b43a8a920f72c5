"""Refusals answer at once (issue 84, item 5): an argument error, an unknown name or a taken run directory is
refused before JAX is imported, and before any of the training's heavy modules, the cost line or a write.
How long they take is `benchmarks/refusal_times.py`'s to measure; this checks what makes them quick."""

import json
import subprocess
import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parents[1] / "benchmarks"))  # the script and its `run_info`
import refusal_times  # noqa: E402

HEAVY = ("jax", "jaxlib", "flax", "orbax", "optax", "scipy", "jaxsocial.run.driver", "jaxsocial.run.loop")
"""Modules (with their submodules) a refusal imports none of."""
REFUSE = """
import importlib, json, sys
heavy = sys.argv[2].split(",")
for module, argv in json.loads(sys.argv[1]):
    try:
        importlib.import_module(module if module.endswith("train") else module + ".__main__").main(argv)
    except SystemExit as exit:
        imported = [m for m in sorted(sys.modules) if any(m == h or m.startswith(h + ".") for h in heavy)]
        print(json.dumps({"refused": str(exit.code), "imported": imported}))
"""
"""The `main` of each (module, argv) of its first argument (`python -m MODULE ARGV`), in one process: as each
is refused, its message (or exit status) and the modules of its second argument imported by then."""


def snapshot(runs) -> dict:
    """Every path under `runs` but the lock files, with a file's bytes."""
    return {p: p.is_file() and p.read_bytes() for p in runs.rglob("*") if p.suffix != ".lock"}


def test_refusals_come_before_jax_is_imported(tmp_path):
    """The refusals `benchmarks/refusal_times.py` times (training: an unknown --env, a bad flag value, a
    setting out of range, a run directory with metrics, with a compile cache too, one of another config, one
    a live process holds; experiments: an unknown recipe or design, a design's seed changed, an unknown option
    of a recipe's verb and of a design kind's, a delegated command's unknown verb, a verify of no record),
    each refused with its message while `jax` is not in `sys.modules`, with nothing written and no cost
    line."""
    runs = tmp_path / "runs"
    lock = refusal_times.make_runs(runs)  # 'live' held by this process
    refusals = {
        message: refusal_times.command(module, flags, runs)[1:]
        for module, flags, message in refusal_times.REFUSALS.values()
    }
    argvs = [(module, argv) for module, *argv in refusals.values()]
    before = snapshot(runs)
    try:
        out = subprocess.run(
            [sys.executable, "-c", REFUSE, json.dumps(argvs), ",".join(HEAVY)],
            capture_output=True,
            text=True,
            timeout=300,
        )
    finally:
        lock.release()
    outcomes = [json.loads(line) for line in out.stdout.splitlines() if line.startswith('{"refused"')]
    assert len(outcomes) == len(refusals), out.stdout + out.stderr
    for message, outcome in zip(refusals, outcomes, strict=True):
        tyro = outcome["refused"] == "2"  # a bad flag value: tyro printed why and exited with status 2
        said = out.stdout + out.stderr if tyro else outcome["refused"]
        assert message in said and outcome["imported"] == [], (message, outcome)
    assert "cost:" not in out.stdout + out.stderr
    assert snapshot(runs) == before


def test_a_deferred_module_is_imported_at_its_first_attribute_read():
    """`lazy.module` (how `stats` holds scipy's tests): nothing imported until an attribute is read, then the
    module's own answer."""
    script = """
import sys
from jaxsocial import lazy
deferred = lazy.module("colorsys")
before = "colorsys" in sys.modules
hsv = deferred.rgb_to_hsv(1.0, 0.0, 0.0)
print(before, "colorsys" in sys.modules, hsv == sys.modules["colorsys"].rgb_to_hsv(1.0, 0.0, 0.0))
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert out.stdout.split() == ["False", "True", "True"], out.stderr
