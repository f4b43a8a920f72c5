"""The tests' training programs lowered to StableHLO, from a checkout: per program the seconds to trace and
lower it (Python time: the tests pay it for every program they build) and the sha256 of its text, which says
whether two checkouts build the same programs (a refactor must leave them byte-identical).

    python benchmarks/lowered_programs.py                      # this checkout
    python benchmarks/lowered_programs.py --repo ../other      # another checkout's jaxsocial and tests
    python benchmarks/lowered_programs.py --out benchmarks/results/lowered_programs.json

Programs: TINY (tests/conftest.py) in 8 variants (beside experts, attention, rec and no auxiliary loss,
bfloat16, three learners, behaviour cloning), each its initialiser and one iteration. Writes JSON with the
CPU model, the commit and the load average (`run_info.metadata`).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
EXPERTS = "learner,expert:explorer,expert:oracle:forget=0.1,epsilon=0.1"


def variants(tiny) -> dict:
    """Variant name -> its TrainConfig, from the tests' TINY."""
    net = lambda **changes: dataclasses.replace(tiny.net, **changes)  # noqa: E731
    return {
        "tiny": tiny,
        "experts": dataclasses.replace(tiny, slots=EXPERTS),
        "attention": dataclasses.replace(tiny, net=net(aux="pred+attention")),
        "rec": dataclasses.replace(tiny, net=net(aux="rec")),
        "no_aux": dataclasses.replace(tiny, net=net(aux="none")),
        "bfloat16": dataclasses.replace(tiny, net=net(dtype="bfloat16")),
        "three_learners": dataclasses.replace(tiny, slots="learner,learner,learner"),
        "bc": dataclasses.replace(tiny, algo="bc", slots="learner,expert:explorer,expert:oracle"),
    }


def lower_all(repo: Path) -> dict:
    """Per variant and part ('init', 'iteration'): {'seconds': trace and lower, 'sha256': of the text}, with
    `repo`'s jaxsocial (first on sys.path, `main`)."""
    import jax
    from conftest import TINY

    import jaxsocial
    from jaxsocial.run import loop

    try:
        from jaxsocial.run.startup import setup
    except ImportError:  # a tree from before run/startup.py, where setup was the config's
        from jaxsocial.run.config import setup

    if not Path(jaxsocial.__file__).is_relative_to(repo.resolve()):
        raise SystemExit(f"imported jaxsocial from {jaxsocial.__file__}, not from {repo}")
    key = jax.random.key(0)
    out = {}
    for name, cfg in variants(TINY).items():
        static = setup(cfg, load_frozen=False)
        init, run_chunk = loop.make_program(cfg.program, static.stage(-1), static.pop)
        state = jax.eval_shape(init, key)
        parts = {
            "init": (jax.jit(init), (key,)),
            "iteration": (jax.jit(run_chunk, static_argnums=2), (state, None, 1)),
        }
        for part, (jitted, args) in parts.items():
            start = time.perf_counter()
            text = jitted.lower(*args).as_text()
            seconds = time.perf_counter() - start
            digest = hashlib.sha256(text.encode()).hexdigest()
            out[f"{name}/{part}"] = {"seconds": seconds, "sha256": digest}
            print(f"{name:15s} {part:9s} {seconds:6.2f} s  {digest[:16]}", flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repo", default=str(REPO), help="the checkout to import")
    parser.add_argument("--out", default=None, help="JSON results")
    args = parser.parse_args()
    repo = Path(args.repo).resolve()
    sys.path[:0] = [str(repo), str(repo / "tests")]  # before anything imports jaxsocial (run_info does)
    import run_info

    meta = run_info.metadata(args)
    programs = lower_all(repo)
    total = sum(p["seconds"] for p in programs.values())
    print(f"{len(programs)} programs traced and lowered in {total:.1f} s")
    if args.out:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True).stdout
        sections = {"repo_commit": commit.strip() or None, "programs": programs, "total_s": total}
        run_info.write_results(args.out, meta, sections)


if __name__ == "__main__":
    main()
