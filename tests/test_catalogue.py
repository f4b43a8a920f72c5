"""One folder of design files for every kind (`experiments.catalogue`), each design's kind read from its file,
its commit followed across moves, and one command, `python -m jaxsocial.experiments VERB NAME`, that reaches
every kind."""

from __future__ import annotations

import json
import subprocess

import pytest

from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments.plan import catalogue, designs


@pytest.mark.parametrize("name", catalogue.design_names())
def test_every_committed_design_loads_as_its_kind_and_as_no_other(name):
    """One loader for every kind: the design is its kind's class, and asking for another kind is refused."""
    kind = catalogue.design_kind(name)
    design = designs.load(name)
    assert design.name == name and kind == design.KIND and isinstance(design, catalogue.Design)
    assert designs.load(name, kind) == design
    for other in set(catalogue.DESIGN_KINDS) - {kind}:
        with pytest.raises(ValueError, match=f"design {name} is of kind {kind}, not {other}"):
            designs.load(name, other)


def test_a_file_names_its_kind_or_is_known_by_the_field_only_its_kind_has(tmp_path, monkeypatch):
    mixing = json.loads(catalogue.path_of("mixing").read_text())  # a branch design, from before `kind`
    monkeypatch.setattr(catalogue, "DESIGNS_DIR", tmp_path)
    files = {
        "named": {"kind": "branch", **mixing, "name": "named"},
        "references": {"references": {}},
        "arms": {"arms": {}},
        "neither": {"scale": "laptop"},
        "unknown": {"kind": "sweep"},
    }
    for name, raw in files.items():
        (tmp_path / f"{name}.json").write_text(json.dumps(raw))
    assert [catalogue.design_kind(n) for n in ("named", "references", "arms", "neither")] == [
        "branch",
        "evaluation",
        "branch",
        "training",
    ]
    with pytest.raises(ValueError, match="unknown kind 'sweep'"):
        catalogue.design_kind("unknown")
    named = designs.load("named")  # its `kind` is the catalogue's, not a field of the design
    assert named.KIND == "branch" and named.arms.keys() == mixing["arms"].keys()
    (tmp_path / "misnamed.json").write_text(json.dumps(mixing))
    with pytest.raises(ValueError, match=r"design misnamed: its file .*misnamed\.json names it 'mixing'"):
        designs.load("misnamed")
    with pytest.raises(FileNotFoundError, match=r"no design .*missing\.json; the designs are \['arms',"):
        catalogue.design_kind("missing")


def _git(repo, *args: str) -> str:
    done = subprocess.run(["git", *args], cwd=repo, capture_output=True, text=True, check=True)
    return done.stdout.strip()


def test_a_design_keeps_its_commit_when_its_file_moves_and_takes_a_new_one_when_it_changes(tmp_path):
    """The design's commit is the last commit that changed its content: a move into another folder (how the
    evaluation and branch designs joined `designs/`) keeps it, an edit replaces it."""
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "config", "user.email", "t@t")
    _git(tmp_path, "config", "user.name", "t")
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "d.json").write_text('{"name": "d", "seeds": 40}\n')
    _git(tmp_path, "add", ".")
    _git(tmp_path, "commit", "-q", "-m", "design")
    designed = _git(tmp_path, "rev-parse", "HEAD")
    (tmp_path / "new").mkdir()
    _git(tmp_path, "mv", "old/d.json", "new/d.json")
    _git(tmp_path, "commit", "-q", "-m", "move")
    assert catalogue.file_commit(tmp_path / "new" / "d.json") == designed
    (tmp_path / "new" / "d.json").write_text('{"name": "d", "seeds": 41}\n')
    _git(tmp_path, "commit", "-q", "-am", "edit")
    assert catalogue.file_commit(tmp_path / "new" / "d.json") == _git(tmp_path, "rev-parse", "HEAD")
    assert catalogue.file_commit(tmp_path / "new" / "none.json") is None


@pytest.mark.parametrize("kind", ["evaluation", "branch"])
def test_one_command_reaches_every_kind_of_design(kind, capsys):
    """`experiments power NAME` describes a design of any kind; a verb the kind does not take is refused
    with the verbs it does take."""
    name = catalogue.design_names(kind)[0]
    cli.main(["power", name])
    assert capsys.readouterr().out.startswith(f"{name}: {'from ' * (kind == 'branch')}the records ")
    if kind == "evaluation":
        with pytest.raises(
            SystemExit, match=f"record {name}: the evaluation design {name} takes power, run, status, figure"
        ):
            cli.main(["record", name])


def test_a_training_design_is_its_recipe_s(capsys):
    cli.main(["power", "h1_laptop"])  # pred8's exact 40-seed power takes a minute; this one seconds
    assert capsys.readouterr().out.startswith("h1_laptop: laptop scale, 2442 iterations")
