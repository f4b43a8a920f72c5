"""JAX's persistent compilation cache: a later run of the same program loads it instead of compiling it.

    python -m jaxsocial.train --compile-cache ~/.cache/jaxsocial/xla ...   # use (and fill) a cache
    python -m jaxsocial.run.compile_cache                # where the default cache is, its entries and size
    python -m jaxsocial.run.compile_cache --clear        # delete its entries

JAX keys the cache by the program, the JAX/XLA versions, the flags and the devices, but not by the CPU or by
how many cores the process sees, on which XLA's CPU code (and so the bits it computes) depends: a program
compiled seeing two cores and loaded by a process that sees one trains other numbers than that process would
compile. So each directory holds one sub-directory per CPU kind and visible-core count
(`machine_dir`), and one directory serves every configuration and machine. Programs that compile
in under `MIN_COMPILE_SECONDS` are not stored (JAX runs many tiny ones). Setting $JAX_COMPILATION_CACHE_DIR
makes JAX use that directory itself, for any JAX program, without the sub-directories; `default_dir` reads it
for the runs a runner starts, which name it with `--compile-cache`.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from jaxsocial import user_cache
from jaxsocial.run import cpuinfo, provenance

__all__ = ["DEFAULT_DIR", "MIN_COMPILE_SECONDS", "default_dir", "enable", "entries", "main"]

DEFAULT_DIR = user_cache.ROOT / "xla"
"""The directory `python -m jaxsocial.run.compile_cache` looks at by default."""
MIN_COMPILE_SECONDS = 0.5


def default_dir() -> Path:
    """The cache processes share when nothing names one: $JAX_COMPILATION_CACHE_DIR where it is set (JAX's own
    variable, which the test suite sets), else `DEFAULT_DIR`."""
    return Path(os.environ.get("JAX_COMPILATION_CACHE_DIR") or DEFAULT_DIR).expanduser()


def machine_dir() -> str:
    """A cache's sub-directory for this process's programs: what XLA's CPU code depends on beyond the program,
    flags and versions that JAX's key names: this CPU (`cpuinfo.slug` of its model) and how many cores this
    process sees (`provenance.visible_cores`; the machine's count where the OS cannot say), e.g.
    'amd-epyc-family-25-model-1-2-cores'."""
    cores = provenance.visible_cores()
    return f"{cpuinfo.slug(cpuinfo.model())}-{len(cores) if cores else os.cpu_count()}-cores"


def enable(directory: str | Path, min_compile_seconds: float = MIN_COMPILE_SECONDS) -> Path:
    """Stores compiled programs in `directory`'s sub-directory for this CPU and visible-core count
    (`machine_dir`; both created if missing) and loads them from there from now on in this process.
    Returns that sub-directory (absolute)."""
    base = Path(directory).expanduser().absolute()
    if base.exists() and not base.is_dir():
        raise ValueError(f"compile cache {base} exists and is not a directory")
    path = base / machine_dir()
    path.mkdir(parents=True, exist_ok=True)
    import jax  # here, not above: `python -m jaxsocial.train` checks its input before JAX is imported

    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_seconds))
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    from jax.experimental.compilation_cache import compilation_cache

    compilation_cache.reset_cache()  # JAX opens the cache on the first compilation; point it here
    return path


def entries(directory: str | Path) -> list[Path]:
    """The files of JAX's cache in `directory`, in any machine's sub-directory (`enable`) or beside them (as
    caches were filled before): a `<key>-cache` per program and maybe `<key>-atime` (its last use); [] if
    `directory` does not exist. Nothing else there counts (or is deleted by --clear)."""
    path = Path(directory).expanduser()
    if not path.is_dir():
        return []
    files = [*path.iterdir(), *(p for d in path.iterdir() if d.is_dir() for p in d.iterdir())]
    return sorted(p for p in files if p.is_file() and p.name.endswith(("-cache", "-atime")))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m jaxsocial.run.compile_cache",
        description="Show or clear the persistent compile cache.",
    )
    parser.add_argument("directory", nargs="?", default=str(DEFAULT_DIR), help=f"default: {DEFAULT_DIR}")
    parser.add_argument("--clear", action="store_true", help="delete the cached programs")
    args = parser.parse_args(argv)
    path = Path(args.directory).expanduser().absolute()
    files = entries(path)
    programs = sum(f.name.endswith("-cache") for f in files)
    summary = f"{programs} programs, {sum(f.stat().st_size for f in files) / 1e6:.1f} MB"
    if args.clear:
        for f in files:
            f.unlink()
        print(f"cleared {path} ({summary})")
        return
    state = summary if path.is_dir() else "does not exist yet"
    print(f"{path}: {state}")
    print(f"use it with: python -m jaxsocial.train --compile-cache {path} ...")


if __name__ == "__main__":
    main()
