"""The exploratory sweep's settings (`Setting`, data in `sweeps/<name>.json` beside the plan folder), how a
seed of one trains (`train_flags`, `run_dir`) and which settings the map of where solo learners fails pairs
(`MAP_PAIRS`). Launched by `launch.sweep_runs`, summarised by `analyse.sweep_results`; the command is
`python -m jaxsocial.experiments sweep` (`jaxsocial.experiments.sweep`)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from jaxsocial.experiments.plan import conditions, recipes
from jaxsocial.run import jsonio

RECORDS_SUBDIR = "sweep"
STOP_RETURN = 5.0
"""A seed stops once a chunk's mean learner return reaches this (`--stop-at-return`): clearly past the
one-tile plateau (about 1) and the takeoff threshold (`LEARNED_RETURN`), so its remaining budget is saved."""


SETTINGS_DIR = Path(__file__).parent.parent / "sweeps"
"""`<name>.json` per setting: the fields of `Setting`."""


@dataclasses.dataclass(frozen=True)
class Setting:
    """One point of the sweep: `condition` at the cpu scale with `flags` on top, for `iterations`."""

    name: str
    condition: str
    flags: tuple[str, ...]
    iterations: int
    why: str


FIELDS = {
    "name": ("a string, the file's name", lambda v: isinstance(v, str)),
    "condition": (
        "one of conditions.CONDITIONS",
        lambda v: isinstance(v, str) and v in conditions.CONDITIONS,
    ),
    "flags": ("a list of strings", lambda v: isinstance(v, list) and all(isinstance(f, str) for f in v)),
    "iterations": ("a whole number >= 1", lambda v: type(v) is int and v >= 1),
    "why": ("a string", lambda v: isinstance(v, str)),
}
"""Each field of a setting's file: what it must be, and the check."""


def load_setting(path: Path) -> Setting:
    """The setting in `path`, a JSON object of `FIELDS` (ValueError naming the file and the field if a field
    is missing, unknown or not what `FIELDS` says, or `name` is not the file's stem; naming the file if it
    is not JSON)."""
    try:
        raw = jsonio.read_json(path)
    except json.JSONDecodeError as err:
        raise ValueError(f"sweep setting {path}: not JSON ({err})") from err
    if not isinstance(raw, dict):
        raise ValueError(f"sweep setting {path}: not a JSON object of the fields {list(FIELDS)}")
    for field in (*FIELDS, *raw):
        if field not in raw or field not in FIELDS:
            what = "missing" if field not in raw else "unknown"
            raise ValueError(f"sweep setting {path}: {what} field {field!r}; the fields are {list(FIELDS)}")
    for field, (must, ok) in FIELDS.items():
        if not ok(raw[field]) or field == "name" and raw[field] != path.stem:
            raise ValueError(f"sweep setting {path}: field {field!r} is {raw[field]!r}, not {must}")
    return Setting(**{**raw, "flags": tuple(raw["flags"])})


def load_settings(directory: Path = SETTINGS_DIR) -> dict[str, Setting]:
    """Every setting of `directory`, by name (`load_setting`)."""
    return {path.stem: load_setting(path) for path in sorted(directory.glob("*.json"))}


SETTINGS = load_settings()


def train_flags(setting: Setting, seed: int, runs_dir: str) -> list[str]:
    """The `python -m jaxsocial.train` flags of one seed of `setting` (later flags override earlier)."""
    base = recipes.condition_flags(recipes.CPU, setting.condition, seed, 1, runs_dir)
    return [
        *base,
        *setting.flags,
        "--iterations",
        str(setting.iterations),
        "--run-name",
        f"{setting.name}-s{seed}",
        "--stop-at-return",
        str(STOP_RETURN),
    ]


def run_dir(setting: Setting, seed: int, runs_dir: str) -> Path:
    return Path(runs_dir) / f"{setting.name}-s{seed}"


MAP_PAIRS = (
    ("7x7, 4 goals, rec", "map_g4_rec_7x7", "map_g4_solo_rec_7x7"),
    ("7x7, 4 goals, rec, 40.0M env-steps", "map_g4_40m_rec_7x7", "map_g4_40m_solo_rec_7x7"),
    ("7x7, 4 goals, rec, 80.0M env-steps", "map_g4_80m_rec_7x7", "map_g4_80m_solo_rec_7x7"),
    ("7x7, 4 goals, penalty 1.0, rec", "map_g4_pen1_rec_7x7", "map_g4_pen1_solo_rec_7x7"),
    ("7x7, 5 goals, rec", "map_g5_rec_7x7", "map_g5_solo_rec_7x7"),
    ("7x7, 125-step episodes, rec", "map_g3_steps125_rec_7x7", "map_g3_steps125_solo_rec_7x7"),
    ("7x7, clutter 0.3, rec", "map_g3_clutter03_rec_7x7", "map_g3_clutter03_solo_rec_7x7"),
    ("7x7, 3 goals, pred", "mb8k8_pred_7x7", "mb8k8_solo_pred_7x7"),
    ("8x8, 3 goals, rec", "mb8k8_rec_8x8", "mb8k8_solo_rec_8x8"),
    ("8x8, 3 goals, pred", "mb8k8_pred_8x8", "mb8k8_solo_pred_8x8"),
    ("8x8, penalty 2.0, rec", "mb8k8_rec_8x8_pen2", "mb8k8_solo_rec_8x8_pen2"),
    ("9x9, penalty 1.0, rec / solo pred", "mb8k8_rec_pen1", "mb8k8_solo_pred_pen1"),
    ("9x9, penalty 1.25, rec / solo pred", "mb8k8_rec_pen125", "mb8k8_solo_pred_pen125"),
    ("9x9, 3 goals, pred, 50.0M env-steps", "map_g3_pred_9x9_50m", "map_g3_solo_pred_9x9_50m"),
    ("10x10, 3 goals, pred, 50.0M env-steps", "map_g3_pred_10x10_50m", "map_g3_solo_pred_10x10_50m"),
)
"""The map of where solo learners fail (issue 46): per setting, (what it varies, the social learners' sweep
setting, the solo learners' one with the same loss where there is one)."""
