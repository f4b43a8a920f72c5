"""The design files: one folder, `designs/` beside this module, for every kind of pre-registered design, and
each file's kind, which says what the design does and which module reads it:

    training     trains a recipe's conditions from fresh seeds                   (`prereg.Design`)
    evaluation   plays a finished design's records zero-shot, training nothing    (`plan.evaluation_design`)
    branch       trains on from a finished design's records                       (`plan.branch_design`)

A file names its kind in its field `kind`. The files committed before that field are known by the field only
their kind has (`references`: evaluation; `arms`: branch; otherwise training), since a design file is never
edited once its runs began: its commit is the last commit that changed its content (`file_commit`, which
follows the file across moves). An amendment is `designs/amendments/<name>.json`, beside its design.
`python -m jaxsocial.experiments VERB NAME` reads a design's kind here and acts on it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from jaxsocial.experiments.plan import commits
from jaxsocial.run import logs

DESIGNS_DIR = Path(__file__).parent.parent / "designs"
DESIGN_KINDS = ("training", "evaluation", "branch")
VERBS = {
    "evaluation": ("power", "run", "figure"),
    "branch": ("power", "run", "record", "figure"),
}
"""What `python -m jaxsocial.experiments VERB NAME` does to a design of a kind that is not a recipe's
(`kind_commands`): its power; play or train what is missing, blind; record the finished branches; and its
summary, tests and figure. A training design takes its recipe's verbs."""
KIND_FIELDS = {"references": "evaluation", "arms": "branch"}
"""Where a design file has no `kind`: the field only that kind's designs have."""


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
    path = path_of(name)
    if not path.is_file():
        raise FileNotFoundError(f"no design {path}; the designs are {design_names()}")
    raw = logs.read_json(path)
    kind = raw.get("kind") or next((k for field, k in KIND_FIELDS.items() if field in raw), "training")
    if kind not in DESIGN_KINDS:
        raise ValueError(f"design {name}: unknown kind {kind!r}; choose from {DESIGN_KINDS}")
    return kind


def read(name: str, kind: str) -> dict:
    """Design `name`'s file as JSON, without its `kind` (FileNotFoundError if there is none; ValueError if it
    is of another kind)."""
    found = design_kind(name)
    if found != kind:
        raise ValueError(f"design {name} is of kind {found}, not {kind}")
    raw = logs.read_json(path_of(name))
    raw.pop("kind", None)
    return raw


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
