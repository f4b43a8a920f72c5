"""Every design, of whichever kind its file says: `load(NAME)` reads the file once (`catalogue.fields`) and
checks it as its kind's `Design` does (`checked`)."""

from __future__ import annotations

from jaxsocial.experiments.plan import branch_design, catalogue, evaluation_design, prereg

KINDS: dict[str, type[catalogue.Design]] = {
    "training": prereg.TrainingDesign,
    "evaluation": evaluation_design.EvaluationDesign,
    "branch": branch_design.BranchDesign,
}
"""Each kind's `Design` (`catalogue.DESIGN_KINDS`)."""


def load(name: str, kind: str | None = None) -> catalogue.Design:
    """Design `name` (FileNotFoundError, naming the designs, if there is none; ValueError if it is invalid,
    or not of `kind` where one is asked for)."""
    found, raw = catalogue.fields(name, kind)
    return KINDS[found].checked(raw)
