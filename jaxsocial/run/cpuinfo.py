"""What this CPU is, as /proc/cpuinfo and sysfs say (no JAX): its model (`model`), its flags (`flags`; those
that change the floats it computes: `NUMERICS_FLAGS`) and its cache sizes (`cache_sizes`). A run's process
file records them (`provenance`), `verify` compares them, and the autotuner's cache keys name them."""

from __future__ import annotations

import functools
import platform
import re
from pathlib import Path

NUMERICS_FLAGS = frozenset(
    ("sse4_2", "avx", "avx2", "fma", "f16c", "avx512f", "avx512dq", "avx512bw", "avx512vl", "avx512_vnni")
    + ("avx512_bf16", "avx512_fp16", "amx_tile", "amx_bf16", "amx_int8")
)
"""The /proc/cpuinfo flags that choose code and kernels at run time (XLA's LLVM target, YNNPACK's and
oneDNN's dispatch), so the floats a CPU computes can follow them."""


@functools.cache
def _fields() -> dict[str, str]:
    """The first processor's /proc/cpuinfo fields (empty where it is missing)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        lines = []
    fields: dict[str, str] = {}
    for line in lines:
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields


def flags() -> frozenset[str]:
    """The CPU's flags from /proc/cpuinfo (empty where it is missing)."""
    return frozenset(_fields().get("flags", "").split())


def cache_sizes() -> dict[str, str]:
    """'L<level><d|i|>' -> size as Linux reports the first CPU's caches, e.g. {'L1d': '48K', ...} (empty where
    it does not): Eigen sizes its blocks of a matrix product's contraction from them."""
    sizes = {}
    for index in sorted(Path("/sys/devices/system/cpu/cpu0/cache").glob("index*")):
        try:
            kind = (index / "type").read_text().strip()
            level = (index / "level").read_text().strip()
            size = (index / "size").read_text().strip()
        except OSError:
            continue
        suffix = {"Data": "d", "Instruction": "i"}.get(kind, "")
        sizes[f"L{level}{suffix}"] = size
    return sizes


def model() -> str:
    """The CPU's model name, with its family and model numbers where /proc/cpuinfo gives them, e.g. 'AMD EPYC
    9R14 96-Core Processor (family 25, model 17)': what tells machine kinds apart (several kinds share a
    name)."""
    info = _fields()
    if "cpu family" in info and "model" in info:
        return f"{model_name()} (family {info['cpu family']}, model {info['model']})"
    return model_name()


def model_name() -> str:
    return _fields().get("model name") or platform.processor() or platform.machine()


def slug(model_text: str) -> str:
    """`model_text` (a `model()`) as a file name: lower-case, every run of other characters than letters and
    digits a '-', e.g. 'amd-epyc-family-25-model-1'."""
    return re.sub(r"[^a-z0-9]+", "-", model_text.lower()).strip("-")
