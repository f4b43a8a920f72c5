"""Which CPU kinds compute the same bits, read from the committed operation fingerprints (issue 85).

`benchmarks/op_fingerprints.py` hashes operations on fixed inputs (matrix products, the orthogonal
initialiser, reductions, elementwise functions) and the laptop recipe's state after `init` and one iteration,
under XLA settings, into one JSON per CPU kind (`folder()`: `benchmarks/results/op_fingerprints/`). Two kinds
*agree* under some $XLA_FLAGS where both files measured a setting with exactly those flags and every
fingerprint both hold is equal (`compare`). From that, `verify` says before it trains whether a record should
re-train bit for bit here (`predict`), and names the kinds a record re-trains alike on (`alike`);
`op_fingerprints.py --compare` prints, from the same files, the tables docs/reproducibility.md quotes
("Does the training re-run?": `markdown`).

A kind is its CPU's vendor with its family and model numbers (`kind_key`), so that a record whose provenance
names its CPU only inside its device text ("AMD EPYC (family 25, model 17), 2 cores, ...", before records
had a `cpu` field) is matched too. What a file cannot say is left unknown: a kind without a file, a setting a
file did not measure. The cores each file's processes saw are carried along (`visible_cores`, not recorded
before 2026-11-28): some products' bits depend on them, so a comparison between files whose processes saw
other counts of cores says so.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path
from typing import Any

from jaxsocial.experiments.plan import paths
from jaxsocial.run import cpuinfo, jsonio

FOLDER = "op_fingerprints"
"""The kinds' files' folder under `paths.RESULTS`."""
FAMILY_MODEL = re.compile(r"family (\d+), model (\d+)")
EXACT, DIFFER, UNKNOWN = "exact expected", "expected to differ", "unknown"
"""What `predict` expects of a re-training."""


def folder() -> Path:
    """Where the kinds' files are (read when called: `--results DIR` moves it)."""
    return paths.RESULTS / FOLDER


def file_name(cpu: str) -> str:
    """A kind's file name: its CPU description (`cpuinfo.model`) lower-cased, every run of other
    characters than letters and digits a '-' (as `benchmarks/reproducibility.kind_file` names it)."""
    return cpuinfo.slug(cpu) + ".json"


def kind_key(cpu: str | None) -> tuple[str, int, int] | None:
    """(vendor, family, model) of a CPU description ('AMD EPYC (family 25, model 1)', 'Intel Xeon (family 6,
    model 167, ...), 2 cores'); None where it has no family and model numbers."""
    numbers = FAMILY_MODEL.search(cpu or "")
    if numbers is None:
        return None
    words = cpu.lower()
    vendor = "intel" if "intel" in words else "amd" if "amd" in words else words.split()[0]
    return vendor, int(numbers[1]), int(numbers[2])


def read_kinds(where: Path | None = None) -> list[dict[str, Any]]:
    """Every kind's file in `where` (default `folder()`), in the order of their names ([] if none)."""
    return [jsonio.read_json(path) for path in sorted((where or folder()).glob("*.json"))]


def kind_for_cpu(kinds: list[dict[str, Any]], cpu: str | None) -> dict[str, Any] | None:
    """The file of `cpu`'s kind (`kind_key`) among `kinds`; None if none."""
    key = kind_key(cpu)
    return next((kind for kind in kinds if key is not None and kind_key(kind["cpu"]) == key), None)


def setting_of(kind: dict[str, Any], xla_flags: str | None) -> str | None:
    """The name of the setting `kind` measured with exactly `xla_flags` (word for word); None if none."""
    wanted = (xla_flags or "").split()
    return next((name for name, e in kind["settings"].items() if e["xla_flags"].split() == wanted), None)


def is_operation(name: str) -> bool:
    """Whether a fingerprint is one of the synthetic operations (not a leaf of the recipe's state)."""
    return "/" not in name


def compare(
    a: dict[str, Any], b: dict[str, Any], setting: str, b_setting: str | None = None
) -> dict[str, Any]:
    """Two kinds' fingerprints under `setting` of `a` and `b_setting` of `b` (default the same name): how many
    both hold (`fingerprints`, of them `operations`), those that differ in `a`'s order (`differ`, of them
    `operations_differ`), the first that differs (an operation where one does, else a leaf of the recipe's
    state; None: they agree) and the cores each file's process saw (None: not recorded)."""
    mine, theirs = a["settings"][setting], b["settings"][b_setting or setting]
    both = [name for name in mine["hashes"] if name in theirs["hashes"]]
    differ = [name for name in both if mine["hashes"][name] != theirs["hashes"][name]]
    operations_differ = [name for name in differ if is_operation(name)]
    return {
        "setting": setting,
        "fingerprints": len(both),
        "operations": sum(map(is_operation, both)),
        "differ": differ,
        "operations_differ": operations_differ,
        "first": (operations_differ or differ or [None])[0],
        "cores": [mine.get("visible_cores"), theirs.get("visible_cores")],
    }


def agree(a: dict[str, Any], b: dict[str, Any], xla_flags: str) -> bool | None:
    """Whether two kinds agree on every fingerprint under `xla_flags` (None: one of them did not measure
    a setting with those flags)."""
    setting, b_setting = setting_of(a, xla_flags), setting_of(b, xla_flags)
    if setting is None or b_setting is None:
        return None
    return not compare(a, b, setting, b_setting)["differ"]


def alike(kinds: list[dict[str, Any]], cpu: str | None, xla_flags: str | None) -> list[str]:
    """The other kinds whose fingerprints all equal `cpu`'s kind's under `xla_flags`, by their CPUs."""
    mine = kind_for_cpu(kinds, cpu)
    if mine is None:
        return []
    return [k["cpu"] for k in kinds if k is not mine and agree(mine, k, xla_flags or "")]


def predict(
    record_cpu: str | None, here_cpu: str, xla_flags: str | None, cores: int | None, kinds: list[dict]
) -> dict[str, Any]:
    """What a re-training on `here_cpu` of a record trained on `record_cpu` with `xla_flags`, seeing `cores`,
    should give, from the kinds' files: {"expected": `EXACT`, `DIFFER` or `UNKNOWN`, "says": why, for
    people, and where two kinds' files were compared, "comparison": `compare`'s}."""
    if kind_key(record_cpu) is None or kind_key(here_cpu) is None:
        unnamed = here_cpu if kind_key(record_cpu) is not None else record_cpu or "no CPU"
        return expectation(UNKNOWN, f"no CPU family and model in '{unnamed}': unknown")
    if kind_key(record_cpu) == kind_key(here_cpu):
        return expectation(EXACT, f"exact expected: the record trained on this CPU kind ({record_cpu})")
    record_kind, here_kind = kind_for_cpu(kinds, record_cpu), kind_for_cpu(kinds, here_cpu)
    for cpu, kind in ((record_cpu, record_kind), (here_cpu, here_kind)):
        if kind is None:
            return expectation(UNKNOWN, f"no fingerprint file for {cpu} in {folder()}: unknown")
    for kind in (record_kind, here_kind):
        if setting_of(kind, xla_flags) is None:
            said = (
                f"no fingerprints of {kind['cpu']} under the record's XLA flags '{xla_flags or ''}': unknown"
            )
            return expectation(UNKNOWN, said)
    found = compare(
        record_kind, here_kind, setting_of(record_kind, xla_flags), setting_of(here_kind, xla_flags)
    )
    pair, setting = f"{record_kind['cpu']} (the record's) and {here_kind['cpu']} (here)", found["setting"]
    if not found["differ"]:
        said = f"exact expected: {pair} agree on all {found['fingerprints']} fingerprints under {setting}"
    else:
        said = (
            f"expected to differ, because {pair} differ in {len(found['differ'])} of {found['fingerprints']} "
            f"fingerprints under {setting} ({len(found['operations_differ'])} of {found['operations']} "
            f"operations), first {found['first']}"
        )
    if found["cores"] != [cores, cores]:
        seen = " and ".join("not recorded" if c is None else str(c) for c in found["cores"])
        said += (
            f"; cores seen by the files' processes: {seen}, by the record's: {cores or 'not recorded'} (some "
            "products' bits depend on them)"
        )
    return expectation(EXACT if not found["differ"] else DIFFER, said, found)


def expectation(expected: str, says: str, comparison: dict[str, Any] | None = None) -> dict[str, Any]:
    """A prediction as `predict` returns it."""
    return {"expected": expected, "says": says, "comparison": comparison}


def label(cpu: str) -> str:
    """A kind's CPU for a table: without '(R)' and ' Processor'."""
    return cpu.replace("(R)", "").replace(" Processor", "")


def settings_in_order(kinds: list[dict[str, Any]]) -> list[str]:
    """Every setting some kind measured, in the order the files first name them."""
    return list(dict.fromkeys(name for kind in kinds for name in kind["settings"]))


def _cores(kind: dict[str, Any], setting: str) -> str:
    seen = kind["settings"][setting].get("visible_cores")
    return "not recorded" if seen is None else str(seen)


def kinds_table(kinds: list[dict[str, Any]]) -> list[str]:
    """Markdown rows: each kind's instruction sets, caches, the cores its processes saw and its settings."""
    rows = ["| kind | instruction sets | L1d, L2 | cores seen | settings measured |", "|---|---|---|---|---|"]
    for kind in kinds:
        caches = kind.get("cache_sizes") or {}
        cores = " or ".join(dict.fromkeys(_cores(kind, name) for name in kind["settings"]))
        isa = ", ".join(kind.get("cpu_flags") or [])
        measured = ", ".join(f"`{name}`" for name in kind["settings"])
        l1d_l2 = f"{caches.get('L1d')}, {caches.get('L2')}"
        rows.append(f"| {label(kind['cpu'])} | {isa} | {l1d_l2} | {cores} | {measured} |")
    return rows


def flag_table(kinds: list[dict[str, Any]], xla_flags: str) -> list[str]:
    """Markdown rows: per pair of kinds, whether they agree under `xla_flags`, how many fingerprints differ
    and the first that does."""
    rows = [
        "| kinds | agree | operations differing | fingerprints differing | first differing | cores seen |",
        "|---|---|---|---|---|---|",
    ]
    for a, b in itertools.combinations(kinds, 2):
        pair = f"{label(a['cpu'])} / {label(b['cpu'])}"
        missing = [k["cpu"] for k in (a, b) if setting_of(k, xla_flags) is None]
        if missing:
            rows.append(f"| {pair} | not measured on {', '.join(map(label, missing))} | | | | |")
            continue
        setting, b_setting = setting_of(a, xla_flags), setting_of(b, xla_flags)
        found = compare(a, b, setting, b_setting)
        n_ops, n_all = len(found["operations_differ"]), len(found["differ"])
        first = f"`{found['first']}`" if found["first"] else "none"
        cores = f"{_cores(a, setting)} / {_cores(b, b_setting)}"
        rows.append(
            f"| {pair} | {'yes' if not n_all else 'no'} | {n_ops} of {found['operations']} | "
            f"{n_all} of {found['fingerprints']} | {first} | {cores} |"
        )
    return rows


def settings_table(kinds: list[dict[str, Any]]) -> list[str]:
    """Markdown rows: per pair of kinds and setting both measured with the same flags (in the order the
    files first name the settings), how many operations and fingerprints differ and which operations."""
    rows = [
        "| kinds | setting | operations differing | fingerprints differing | the operations that differ |",
        "|---|---|---|---|---|",
    ]
    for a, b in itertools.combinations(kinds, 2):
        for name in settings_in_order(kinds):
            if name not in a["settings"] or name not in b["settings"]:
                continue
            if a["settings"][name]["xla_flags"] != b["settings"][name]["xla_flags"]:
                continue
            found = compare(a, b, name)
            operations = ", ".join(f"`{op}`" for op in found["operations_differ"]) or "none"
            rows.append(
                f"| {label(a['cpu'])} / {label(b['cpu'])} | `{name}` | {len(found['operations_differ'])} of "
                f"{found['operations']} | {len(found['differ'])} of {found['fingerprints']} | {operations} |"
            )
    return rows


def markdown(kinds: list[dict[str, Any]], xla_flags: str) -> str:
    """The three tables docs/reproducibility.md quotes: the kinds, each pair under `xla_flags` (the designs'
    cross-CPU flags), and each pair under every setting both measured."""
    return "\n".join(
        [
            *kinds_table(kinds),
            "",
            *flag_table(kinds, xla_flags),
            "",
            *settings_table(kinds),
        ]
    )
