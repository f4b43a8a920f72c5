"""The design files: one folder, `designs/` beside this module, for every kind of pre-registered design, and
each file's kind, which says what the design does and which module reads it:

    training     trains a recipe's conditions from fresh seeds                   (`prereg.TrainingDesign`)
    evaluation   plays a finished design's records zero-shot, training nothing    (`evaluation_design`)
    branch       trains on from a finished design's records                       (`branch_design`)

Every kind is a `Design`: what each states (its name, seeds, alpha, power and how that was computed, why),
`checked(fields)`, which makes one from its file's fields, and `describe()`, itself and its power for people;
each kind adds only what differs. `fields` reads a design file once; `designs.load` makes any design of it.

A file names its kind in its field `kind`. The files committed before that field are known by the field only
their kind has (`references`: evaluation; `arms`: branch; otherwise training), since a design file is never
edited once its runs began: its commit is the last commit that changed its content (`file_commit`, which
follows the file across moves). An amendment is `designs/amendments/<name>.json`, beside its design.
`python -m jaxsocial.experiments VERB NAME` reads a design's kind here and acts on it."""

from __future__ import annotations

import abc
import dataclasses
from pathlib import Path
from typing import Any, ClassVar, Self

from jaxsocial import stats
from jaxsocial.experiments.plan import commits
from jaxsocial.run import jsonio

DESIGNS_DIR = Path(__file__).parent.parent / "designs"
DESIGN_KINDS = ("training", "evaluation", "branch")
VERBS = {
    "evaluation": ("power", "run", "status", "figure"),
    "branch": ("power", "run", "status", "record", "figure"),
}
"""What `python -m jaxsocial.experiments VERB NAME` does to a design of a kind that is not a recipe's
(`kind_commands`): its power; play or train what is missing, blind; say what is played, or where each
branch stands; record the finished branches; and its summary, tests and figure. A training design takes its
recipe's verbs."""
P_DECIMALS = 6
"""A summary's p-values and other floats: 6 decimals, 3 significant digits below 1e-6 (`stats.round_p`)."""
KIND_FIELDS = {"references": "evaluation", "arms": "branch"}
"""Where a design file has no `kind`: the field only that kind's designs have."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class Design(abc.ABC):
    """What a design of every kind states, fixed in its committed file before any of its runs."""

    KIND: ClassVar[str]
    name: str
    seed: int
    """The first seed: of every condition it trains, or of the records it plays or branches."""
    seeds: int
    """Seeds seed..seed+seeds-1, none left out."""
    alpha: float
    power: float
    """The power the file states, as its kind computes it (3 decimals)."""
    power_simulation: dict[str, Any] = dataclasses.field(default_factory=dict)
    """How the power was computed, where by simulation: its pilot, discounts and table."""
    rationale: str = ""

    @classmethod
    @abc.abstractmethod
    def checked(cls, raw: dict[str, Any]) -> Self:
        """A design of this kind from its file's fields, `kind` aside (ValueError if it is invalid)."""

    @classmethod
    def read(cls, name: str) -> Self:
        """Design `name`, which must be of this kind (`fields`' errors otherwise)."""
        return cls.checked(fields(name, cls.KIND)[1])

    @property
    def seed_range(self) -> range:
        return range(self.seed, self.seed + self.seeds)

    @property
    def last_seed(self) -> int:
        return self.seed + self.seeds - 1

    @abc.abstractmethod
    def describe(self) -> str:
        """The design, its tests and its power, for people."""


@dataclasses.dataclass(frozen=True)
class Test:
    """One comparison a design of any kind makes: two arms' per-seed scores in the environment `env`
    (NAME[:field=value,...]), one-sided (`alternative` 'greater' or 'less': the treatment's) or two-sided
    (`stats.ALTERNATIVES`). The arms are the design's treatment and control, or those it names (a branch
    design's `treatment` and `control`)."""

    env: str
    alternative: str
    statement: str = ""
    treatment: str | None = None
    control: str | None = None


def power_lines(power: dict[str, dict[str, float]], prefix: str) -> list[str]:
    """One line a discount of a simulated power table: each test's power, and where the table has them, that
    of all and of any of them."""
    return [
        f"{prefix}{case}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()) for case, row in power.items()
    ]


def path_of(name: str) -> Path:
    """The file of design `name` (which may not exist)."""
    return DESIGNS_DIR / f"{name}.json"


def amendment_path(name: str) -> Path:
    """The file of design `name`'s amendment (which may not exist)."""
    return DESIGNS_DIR / "amendments" / f"{name}.json"


def design_names(kind: str | None = None) -> list[str]:
    """Every design's name, sorted, or those of one kind."""
    found = sorted(p.stem for p in DESIGNS_DIR.glob("*.json"))
    return [n for n in found if kind is None or design_kind(n) == kind]


def design_kind(name: str) -> str:
    """The kind of design `name` (FileNotFoundError, naming the designs, if there is none)."""
    return _kind_of(name, _raw(name))


def fields(name: str, kind: str | None = None) -> tuple[str, dict[str, Any]]:
    """Design `name`'s kind and its file's other fields, read once (FileNotFoundError, naming the designs, if
    there is none; ValueError if the file names another design, or it is not of `kind` where one is asked
    for)."""
    raw = _raw(name)
    found = _kind_of(name, raw)
    if kind is not None and found != kind:
        raise ValueError(f"design {name} is of kind {found}, not {kind}")
    if raw.get("name") != name:
        raise ValueError(f"design {name}: its file {path_of(name)} names it {raw.get('name')!r}")
    raw.pop("kind", None)
    return found, raw


def _raw(name: str) -> dict[str, Any]:
    """Design `name`'s file as JSON (FileNotFoundError, naming the designs, if there is none)."""
    path = path_of(name)
    if not path.is_file():
        raise FileNotFoundError(f"no design {path}; the designs are {design_names()}")
    return jsonio.read_json(path)


def _kind_of(name: str, raw: dict[str, Any]) -> str:
    """The kind a design file states, or that its kind's own field shows (ValueError if unknown)."""
    kind = raw.get("kind") or next((k for field, k in KIND_FIELDS.items() if field in raw), "training")
    if kind not in DESIGN_KINDS:
        raise ValueError(f"design {name}: unknown kind {kind!r}; choose from {DESIGN_KINDS}")
    return kind


def file_commit(path: Path) -> str | None:
    """The last commit that changed the content of file `path`, followed across moves (None if it is not
    committed)."""
    out = commits.git(
        "log", "-1", "--follow", "--diff-filter=AM", "--format=%H", "--", path.name, cwd=path.parent
    )
    return out.stdout.strip() or None if out.returncode == 0 else None


def design_commit(name: str) -> str | None:
    """The commit of design `name`: the last that changed its file (None if it is not committed)."""
    return file_commit(path_of(name))


def commit_time(commit: str | None) -> str | None:
    """When `commit` was committed, ISO 8601 with its offset (None if unknown to git)."""
    out = commits.git("show", "-s", "--format=%cI", commit, cwd=DESIGNS_DIR) if commit else None
    return out.stdout.strip() or None if out is not None and out.returncode == 0 else None


def precedes(design: str | None, commit: str | None) -> bool | None:
    """Whether commit `design` is an ancestor of (or is) `commit`; None if either is unknown to git."""
    if not design or not commit:
        return None
    out = commits.git("merge-base", "--is-ancestor", design, commit, cwd=DESIGNS_DIR)
    return {0: True, 1: False}.get(out.returncode)


def holm_family(entries: dict[str, dict[str, Any]], alpha: float) -> dict[str, dict[str, Any]]:
    """`entries` (a family's tests: name -> result with its 'p', None where it could not run), each given
    its Holm-adjusted p-value over the family's tests that ran ('p_holm', None if it did not) and whether it
    is rejected at `alpha`, every float rounded (`stats.round_p` to `P_DECIMALS`); returned."""
    adjusted = stats.holm({name: e["p"] for name, e in entries.items() if e["p"] is not None})
    for name, entry in entries.items():
        entry["p_holm"] = adjusted.get(name)
        entry["rejected"] = name in adjusted and adjusted[name] <= alpha
        entry.update({k: stats.round_p(v, P_DECIMALS) for k, v in entry.items() if isinstance(v, float)})
    return entries


def commit_checks(commit: str | None, run_commits: dict[str, str | None]) -> dict[str, Any]:
    """Whether the design is committed and precedes every run's recorded commit (and which runs it does
    not)."""
    order = {d: precedes(commit, c) for d, c in run_commits.items()}
    return {
        "design_committed": commit is not None,
        "design_precedes_every_run": bool(order) and all(order.values()),
        "runs_not_after_design": sorted(d for d, ok in order.items() if not ok),
    }
