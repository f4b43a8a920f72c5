"""A design's verdict, for people, from its summary: one way for every kind. A headline (what was compared),
a line per test of each tested family (the rows' means where it compares scores, its p-value, Holm's and
whether it is rejected), a line per check (the design's commit first), the problems and deviations, and
NOT VALID where the summary does not test the design; then a branch design's amendment the same way."""

from __future__ import annotations

from typing import Any


def verdict(summary: dict[str, Any]) -> str:
    """The verdict of a summary of any kind of design: a training design's recipe summary (its
    `preregistered` block: 'counts', 'takeoff' or 'zero_shot'), an evaluation design's or a branch
    design's."""
    block = summary["preregistered"]
    environments = summary.get("environments")
    arms = summary.get("material", {}).get("treatment"), summary.get("material", {}).get("control")
    lines = [headline(summary)]
    for family, entries in tested_families(block):
        lines += test_lines(family, entries, environments, arms)
    lines += check_lines(block, "design")
    if "amendment" in block:
        added = block["amendment"]
        lines.append(f"amendment, {added['added']} (Holm among its tests at {added['alpha']:g}):")
        lines += test_lines("amendment", added["tests"], environments, arms)
        lines += check_lines(added, "amendment")
    return "\n".join(lines)


def headline(summary: dict[str, Any]) -> str:
    """The verdict's first line: what the design compared, and for a 'counts' training design its result."""
    block = summary["preregistered"]
    if "recorded" in summary:  # a branch design's
        return f"{summary['design']}: {summary['recorded']} branches recorded; alpha {block['alpha']:g}, Holm"
    if "material" in summary:  # an evaluation design's
        arms = summary["material"]
        return (
            f"{summary['design']}: {arms['treatment']} against {arms['control']}, alpha {block['alpha']:g}, "
            "Holm in each family"
        )
    said = f"pre-registered ({block['primary']['test']}, alpha {block['primary']['alpha']:g})"
    r = block["result"]
    if "treatment_learned" in r:
        return (
            f"{said}: treatment {r['treatment_learned']}/{r['treatment_seeds']} learned, control "
            f"{r['control_learned']}/{r['control_seeds']}, p = {r['p']:.4g}"
        )
    if "seeds" in r:  # a 'takeoff' design's
        return f"{said}, seeds {r['seeds']}:"
    scores = [f"{arm} {'none' if s is None else _mean(s)}" for arm, s in r["scores"].items()]
    return f"{said}: {', '.join(scores)}"


def _mean(scores: dict[str, Any]) -> str:
    """An arm's scores (`stats.summary`) in a few words."""
    return f"mean {scores['mean']} over {len(scores['final_returns'])} seeds"


def tested_families(block: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """The tests of a `preregistered` block by family, each test's entry holding its 'p' (None: no data),
    and where corrected its 'p_holm'; a 'counts' design's primary test is its headline's, not here."""
    r = block.get("result", {})
    if "seeds" in r:  # a 'takeoff' design's: both families in its result
        return [("primary", r["primary"]), ("secondary", r["secondary"])]
    if "scores" in r:  # a 'zero_shot' design's one test
        return [("primary", {name: entry for name, entry in r.items() if name != "scores"})]
    families = [("primary", block["primary"])] if "alpha" in block else []
    return families + ([("secondary", block["secondary"])] if "secondary" in block else [])


def test_lines(
    family: str,
    entries: dict[str, Any],
    environments: dict[str, Any] | None,
    arms: tuple[str | None, str | None],
) -> list[str]:
    """One line a test: its name, test and environment where the entry names them, the rows' means where
    the summary has per-environment rows (the entry's `arms`, else the design's `arms`), its p-value and
    Holm's, and whether it is rejected."""
    lines = []
    for name, entry in entries.items():
        where = ", ".join(str(entry[k]) for k in ("test", "env") if entry.get(k))
        said = [f"  {family} {name}" + (f" ({where})" if where else "")]
        if environments is not None and "env" in entry:
            rows = environments[entry["env"]]
            means = [f"{a} {'-' if rows[a] is None else rows[a]['mean']}" for a in entry.get("arms", arms)]
            said.append(f": mean {', '.join(means)};")
        else:
            said.append(":")
        counts = entry.get("counts") or entry.get("learned")
        if counts:
            said.append(f" {counts[0]}/{counts[1]} against {counts[2]}/{counts[3]};")
        if entry["p"] is None:
            said.append(" no data")
        else:
            holm = f" (Holm {entry['p_holm']:.4g})" if entry.get("p_holm") is not None else ""
            said.append(f" p = {entry['p']:.4g}{holm}")
        lines.append("".join(said) + (", rejected" if entry.get("rejected") else ""))
    return lines


def check_lines(block: dict[str, Any], what: str) -> list[str]:
    """The lines a verdict (or its amendment, `what`) ends with: its commit, each check (yes or NO, a count,
    or the names a list holds where it holds any), the problems and deviations, and NOT VALID where the
    block is not valid."""
    lines = [f"  {what} commit {block['commit'] or f'none (the {what} is not committed)'}"]
    for name, value in block["checks"].items():
        if isinstance(value, bool):
            lines.append(f"  {name}: {'yes' if value else 'NO'}")
        elif isinstance(value, list):
            lines += [f"  {name}: {', '.join(map(str, value))}"] if value else []
        else:
            lines.append(f"  {name}: {value}")
    lines += [f"  {problem}" for problem in block.get("problems", [])]
    lines += [f"  deviation ({d['date']}): {d['what']}" for d in block.get("deviations", [])]
    if not block.get("valid", True):
        lines.append(f"NOT VALID: the result above does not test the {what} (see its checks and problems)")
    return lines
