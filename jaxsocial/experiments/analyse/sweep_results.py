"""The exploratory sweep summarised from its records: each seed's takeoff in env-steps and CPU-minutes
(`seed_summary`), per setting (`summarise`), and the map of where solo learners fail (`summarise_map`,
`map_table`); the settings are `plan.sweep_settings`'."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from jaxsocial.experiments.analyse import records, takeoff
from jaxsocial.experiments.plan.sweep_settings import MAP_PAIRS, RECORDS_SUBDIR, SETTINGS
from jaxsocial.run import metrics, rundir
from jaxsocial.run.metrics import LEARNED_RETURN


def seed_summary(seed_dir: Path) -> dict[str, Any]:
    """One seed's takeoff (env-steps and CPU-minutes; None if it stayed on the plateau), final return and
    cost, from its record or run directory."""
    config = rundir.read_config(seed_dir)
    rows = rundir.read_metrics(seed_dir)
    prov = records.read_provenance(seed_dir) or {}
    cores = (prov.get("run") or {}).get("cores") or 1
    per_iteration = metrics.steps_per_iteration(config)
    iterations, returns = takeoff.window_curve(rows, per_iteration)
    lift = takeoff.takeoff(iterations, returns, LEARNED_RETURN)
    return {
        "seed": config["seed"],
        "iterations": len(rows),
        "env_steps": len(rows) * per_iteration,
        "cpu_minutes": metrics.cpu_minutes(rows, per_iteration, cores),
        "takeoff_env_steps": None if lift is None else lift * per_iteration,
        "takeoff_cpu_minutes": None
        if lift is None
        else metrics.cpu_minutes(rows, per_iteration, cores, lift),
        "stopped_early": bool((prov.get("record") or {}).get("stopped_early")),
        "final_return": metrics.final_return(rows),  # the last 10% of its iterations (until its stop)
        "expert_final_return": [metrics.final_return(rows, s) for s in metrics.slots(rows[-1]) if s != 0],
        "curve": {"env_steps": (iterations * per_iteration).tolist(), "return": returns.tolist()},
    }


def summarise(records_root: Path) -> dict[str, Any]:
    """Every recorded setting's seeds (`seed_summary`) and how many took off."""
    out: dict[str, Any] = {"learned_return": LEARNED_RETURN, "window_env_steps": takeoff.WINDOW_STEPS}
    out["settings"] = {}
    for setting_dir in sorted(p for p in (records_root / RECORDS_SUBDIR).glob("*") if p.is_dir()):
        seeds = [seed_summary(d) for d in sorted(setting_dir.glob("s*"), key=lambda d: int(d.name[1:]))]
        setting = SETTINGS.get(setting_dir.name)
        out["settings"][setting_dir.name] = {
            "why": setting.why if setting else None,
            "flags": list(setting.flags) if setting else None,
            "condition": setting.condition if setting else None,
            "seeds": seeds,
            "took_off": sum(s["takeoff_env_steps"] is not None for s in seeds),
            "n": len(seeds),
        }
    return out


def summarise_map(summary: dict[str, Any]) -> dict[str, Any]:
    """Per map setting with records, the social and solo seeds' takeoffs (env-steps, None: never), budgets
    and final returns (the experts' too, per seed: one per expert slot), from the sweep's summary."""
    out = {"window_env_steps": summary["window_env_steps"], "learned_return": summary["learned_return"]}
    cells = {}
    for label, social, solo in MAP_PAIRS:
        if social not in summary["settings"] or solo not in summary["settings"]:
            continue
        cells[label] = {}
        for who, name in (("social", social), ("solo", solo)):
            seeds = summary["settings"][name]["seeds"]
            experts = [r for x in seeds for r in x["expert_final_return"]]
            cells[label][who] = {
                "setting": name,
                "seeds": [x["seed"] for x in seeds],
                "takeoff_env_steps": [x["takeoff_env_steps"] for x in seeds],
                "env_steps": [x["env_steps"] for x in seeds],
                "final_return": [x["final_return"] for x in seeds],
                "expert_final_return": [x["expert_final_return"] for x in seeds],
                "expert_mean_final_return": sum(experts) / len(experts) if experts else None,
                "took_off": summary["settings"][name]["took_off"],
                "n": summary["settings"][name]["n"],
            }
    out["cells"] = cells
    return out


def map_table(found: dict[str, Any]) -> list[str]:
    """The map (`summarise_map`) as Markdown table lines: per cell, each arm's seeds past the plateau, each
    seed's takeoff in env-steps ("-": not within its budget), the budget, and the experts' mean final return
    beside the social learners. (Final returns of learners are left out: a seed past the plateau stops at
    return `STOP_RETURN`.)"""
    lines = [
        "| setting | social learned | solo learned | takeoffs (env-steps): social; solo | budget | experts |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for label, cell in found["cells"].items():
        social, solo = cell["social"], cell["solo"]
        lifts = "; ".join(
            ", ".join("-" if t is None else f"{t / 1e6:.2f}M" for t in arm["takeoff_env_steps"])
            for arm in (social, solo)
        )
        budget = max(max(arm["env_steps"]) for arm in (social, solo))
        experts = social["expert_mean_final_return"]
        lines.append(
            f"| {label} | {social['took_off']} of {social['n']} | {solo['took_off']} of {solo['n']} "
            f"| {lifts} | {budget / 1e6:.1f}M | {'-' if experts is None else f'{experts:.1f}'} |"
        )
    return lines
