"""What every benchmark records beside its numbers: versions, machine, git revision, arguments."""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np

REPO = Path(__file__).resolve().parent.parent


def git_revision() -> dict:
    """{'commit': HEAD sha or None, 'dirty': uncommitted changes or None}."""

    def git(*cmd):
        return subprocess.run(["git", *cmd], cwd=REPO, capture_output=True, text=True, timeout=10)

    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0:
            return {"commit": None, "dirty": None}
        return {"commit": head.stdout.strip(), "dirty": git("diff", "--quiet").returncode != 0}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


def cpu_model() -> str | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return None


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def metadata(args: argparse.Namespace) -> dict:
    """Versions (python, jax, jaxlib, flax, numpy), devices, CPU, platform, git revision, args, load."""
    return {
        "timestamp": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "args": vars(args),
        "argv": sys.argv,
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": _version("jaxlib"),
        "flax": _version("flax"),
        "numpy": np.__version__,
        "devices": [f"{d} (platform={d.platform}, kind={d.device_kind})" for d in jax.devices()],
        "cpu_count": os.cpu_count(),
        "cpu_model": cpu_model(),
        "platform": platform.platform(),
        "git": git_revision(),
        "env": {k: os.environ.get(k) for k in ("XLA_FLAGS", "GLIBC_TUNABLES", "OMP_NUM_THREADS")},
        "loadavg_start": os.getloadavg(),
    }


def write_results(out: str | Path, meta: dict, sections: dict) -> None:
    """Write `{"metadata": meta, "sections": sections}` to `out` as JSON (the end load average added)."""
    meta["loadavg_end"] = os.getloadavg()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"metadata": meta, "sections": sections}, indent=2) + "\n")
    print(f"\nwrote {out}")
