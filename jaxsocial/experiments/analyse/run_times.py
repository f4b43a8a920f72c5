"""What the runs left will take, at the pace a design's committed records kept: each record's provenance
says when its process started and ended, on which CPU, pinned to how many cores. The cost line a design's
`run` prints before training (`runner.print_cost`, `branch_runs.run`) quotes the median run on this CPU
kind where records trained on it, else each kind's median; the benchmark rates (`recipes.cost`) measure a
few iterations, these whole runs, evaluations and compiles included."""

from __future__ import annotations

import datetime
import math
import statistics
from collections import defaultdict
from pathlib import Path

from jaxsocial.experiments.analyse import records
from jaxsocial.run import cost, cpuinfo

UNNAMED = "a CPU not recorded"
"""The kind of a record whose provenance names no CPU."""


def minutes_by_cpu(root: Path) -> dict[str, list[float]]:
    """The wall-clock minutes (float) of each run recorded in a folder of `root` that trained pinned to one
    core and exited 0, by the CPU it trained on (its provenance's `cpu`, else its `device`, else
    `UNNAMED`), in the order of the folders' names; {} where `root` holds none. A resumed run is left out:
    its start and end do not span one process."""
    times: dict[str, list[float]] = defaultdict(list)
    for path in sorted(Path(root).glob(f"*/{records.PROVENANCE_FILE}")):
        run = records.read_provenance(path.parent).get("run") or {}
        if run.get("cores") != 1 or run.get("rc") != 0 or run.get("earlier"):
            continue
        if not (run.get("started") and run.get("ended")):
            continue
        started, ended = (datetime.datetime.fromisoformat(run[k]) for k in ("started", "ended"))
        times[run.get("cpu") or run.get("device") or UNNAMED].append((ended - started).total_seconds() / 60)
    return dict(times)


def recorded_pace(root: Path, runs: int, processes: int, cpu: str | None = None) -> str | None:
    """The cost of `runs` more runs like those recorded in `root`, `processes` at a time, one core each: on
    this CPU (`cpu`; default `cpuinfo.model()`), where records trained on it, their median minutes a
    run and the wall-clock time of ceil(runs / processes) rounds of it; else each recorded kind's median and
    no total. None where `root` holds no such record."""
    times = minutes_by_cpu(root)
    if not times:
        return None
    cpu = cpu or cpuinfo.model()
    head = f"the {_runs(sum(map(len, times.values())))} recorded in {root} took"
    if cpu in times:
        mine = times[cpu]
        median = statistics.median(mine)
        total = cost.duration(math.ceil(runs / processes) * median * 60)
        return (
            f"{head} a median {median:.1f} min a run on this CPU ({cpu}: {_runs(len(mine))}, "
            f"{min(mine):.1f}-{max(mine):.1f} min): about {total} for {runs} more, {processes} at a time"
        )
    kinds = "; ".join(
        f"{kind}: {statistics.median(spans):.1f} min ({_runs(len(spans))})" for kind, spans in times.items()
    )
    return f"{head} a median a run of {kinds}; none trained on this CPU ({cpu}), whose pace may differ"


def _runs(n: int) -> str:
    return f"{n} run{'s' * (n != 1)}"
