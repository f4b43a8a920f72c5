"""What every benchmark records beside its numbers: versions, machine, git revision, arguments; and the one
way results are written (`write_json`), with paths made independent of the machine (`portable`)."""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxsocial.run import cpuinfo
from jaxsocial.run.provenance import package_version

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


def metadata(args: argparse.Namespace) -> dict:
    """Versions (python, jax, jaxlib, flax, numpy), devices, CPU, platform, git revision, args, load."""
    return {
        "timestamp": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "args": vars(args),
        "argv": sys.argv,
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": package_version("jaxlib"),
        "flax": package_version("flax"),
        "numpy": np.__version__,
        "devices": [f"{d} (platform={d.platform}, kind={d.device_kind})" for d in jax.devices()],
        "cpu_count": os.cpu_count(),
        "cpu_model": cpuinfo.model(),  # the model name with its family and model numbers
        "platform": platform.platform(),
        "git": git_revision(),
        "env": {k: os.environ.get(k) for k in ("XLA_FLAGS", "GLIBC_TUNABLES", "OMP_NUM_THREADS")},
        "loadavg_start": os.getloadavg(),
    }


def portable_path(path: str, repo: Path = REPO) -> str:
    """An absolute `path` as it is recorded: relative to the repository `repo` when inside it; a Python
    interpreter by its name (the versions say which); under the temporary directory as '$TMPDIR/...';
    anything else as '<outside the repository>/NAME'."""
    candidates = [Path(os.path.abspath(path))]
    candidates.append(candidates[0].resolve())
    for candidate in candidates:
        if candidate.is_relative_to(repo):
            return candidate.relative_to(repo).as_posix() or "."
    name = candidates[0].name
    if name.startswith("python"):
        return name
    tmp = Path(tempfile.gettempdir()).resolve()
    for candidate in candidates:
        if candidate.is_relative_to(tmp):
            return "$TMPDIR/" + candidate.relative_to(tmp).as_posix()
    return f"<outside the repository>/{name}"


def portable(value: Any, repo: Path = REPO) -> Any:
    """JSON `value` with every string that is an absolute path replaced by `portable_path(path, repo)`."""
    if isinstance(value, dict):
        return {k: portable(v, repo) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [portable(v, repo) for v in value]
    if isinstance(value, str) and os.path.isabs(value):
        return portable_path(value, repo)
    return value


def write_json(out: str | Path, payload: dict) -> None:
    """Write `payload` to `out` as indented JSON, its paths made `portable`."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(portable(payload), indent=2) + "\n")
    print(f"\nwrote {out}")


def write_results(out: str | Path, meta: dict, sections: dict) -> None:
    """`{"metadata": meta, "sections": sections}` to `out` with `write_json`, adding the end load average."""
    meta["loadavg_end"] = os.getloadavg()
    write_json(out, {"metadata": meta, "sections": sections})
