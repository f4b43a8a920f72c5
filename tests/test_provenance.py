"""Provenance that cannot lie (issue 84): every training process records the code it ran (its commit, whether
the package's files were that commit's, and where not the diff that rebuilds them) beside the machine, in one
process file a runner or the training itself writes; records carry it, diffs included; `experiments record`
and a pre-registered design's runs refuse a dirty tree unless `--allow-dirty`. On git checkouts made here,
no training."""

import hashlib
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import needs_records

from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments.analyse import records
from jaxsocial.experiments.launch import pinned, verify
from jaxsocial.experiments.plan import paths
from jaxsocial.run import checkout, cpuinfo, jsonio, provenance

REPO = Path(__file__).resolve().parents[1]
RECORD = ["record", "no_penalty", "--scale", "tiny", "--seeds", "2"]


def _git(root: Path, *args: str) -> str:
    command = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false", *args]
    return subprocess.run(command, cwd=root, check=True, capture_output=True, text=True).stdout.strip()


@pytest.fixture
def repo(tmp_path) -> Path:
    """A checkout whose package, jaxsocial/, holds two committed files, with a README beside it."""
    root = tmp_path / "checkout"
    (root / "jaxsocial" / "sub").mkdir(parents=True)
    (root / "jaxsocial" / "recipes.py").write_text("SCALE = 1\n")
    (root / "jaxsocial" / "sub" / "gone.py").write_text("x = 1\n")
    (root / "README.md").write_text("readme\n")
    (root / ".gitignore").write_text("__pycache__/\n")
    _git(root, "init", "-q")
    _git(root, "add", ".")
    _git(root, "commit", "-qm", "first")
    return root


def _make_dirty(root: Path) -> None:
    """Every kind of change: a tracked file edited after part of it was staged, one deleted, files git does
    not track (a binary, a design in a new folder), an ignored one, and a change outside the package."""
    (root / "jaxsocial" / "recipes.py").write_text("SCALE = 2\n")
    _git(root, "add", "jaxsocial/recipes.py")
    (root / "jaxsocial" / "recipes.py").write_text("SCALE = 3  # edited after staging\n")
    (root / "jaxsocial" / "sub" / "gone.py").unlink()
    (root / "jaxsocial" / "designs").mkdir()
    (root / "jaxsocial" / "designs" / "mine.json").write_text('{"seeds": 40}\n')
    (root / "jaxsocial" / "blob.bin").write_bytes(bytes(range(256)))
    (root / "jaxsocial" / "__pycache__").mkdir()
    (root / "jaxsocial" / "__pycache__" / "recipes.pyc").write_bytes(b"ignored")
    (root / "README.md").write_text("edited outside the package\n")


def _package_files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes()
        for p in (root / "jaxsocial").rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    }


def test_a_clean_tree_records_its_commit_and_no_diff(repo, tmp_path):
    tree = checkout.tree(repo)
    head = _git(repo, "rev-parse", "HEAD")
    assert tree.fields() == {
        "commit": head,
        "dirty": False,
        "tree_diff": None,
        "tree_diff_sha256": None,
        "no_commit_reason": None,
    }
    (repo / "README.md").write_text("edited outside the package\n")  # docs and results change no run
    assert checkout.tree(repo).dirty is False
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    provenance.write_run_file(run_dir, "python -m jaxsocial.train", tree, None, provenance.now(), 0)
    info = jsonio.read_json(run_dir / provenance.RUN_FILE)
    assert (info["commit"], info["dirty"], info["tree_diff"]) == (head, False, None)
    assert [p.name for p in run_dir.iterdir()] == [provenance.RUN_FILE]  # no diff


def test_a_dirty_trees_diff_rebuilds_it_from_its_commit(repo, tmp_path):
    head = _git(repo, "rev-parse", "HEAD")
    _make_dirty(repo)
    tree = checkout.tree(repo)
    assert tree.commit == head and tree.dirty is True
    assert set(tree.changes) == {
        "MM jaxsocial/recipes.py",
        "D jaxsocial/sub/gone.py",
        "?? jaxsocial/blob.bin",
        "?? jaxsocial/designs/mine.json",
    }  # neither the ignored file nor the README
    assert tree.describe().startswith(
        f"jaxsocial/ differs from commit {head[:12]} (MM jaxsocial/recipes.py, "
    )
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    provenance.write_run_file(run_dir, "python -m jaxsocial.train", tree, None, provenance.now(), 0)
    info = jsonio.read_json(run_dir / provenance.RUN_FILE)
    diff = run_dir / info["tree_diff"]
    assert info["dirty"] is True and info["tree_diff_sha256"] == hashlib.sha256(diff.read_bytes()).hexdigest()
    assert info["tree_diff"] == f"tree-{info['tree_diff_sha256'][:12]}.diff"
    rebuilt = tmp_path / "rebuilt"
    _git(tmp_path, "clone", "-q", str(repo), str(rebuilt))
    _git(rebuilt, "checkout", "-q", info["commit"])
    _git(rebuilt, "apply", str(diff))
    assert _package_files(rebuilt) == _package_files(repo)
    assert (rebuilt / "README.md").read_text() == "readme\n"  # only the package is rebuilt


def test_outside_a_checkout_there_is_no_commit_and_a_reason(repo, tmp_path):
    installed = tmp_path / "site-packages"
    (installed / "jaxsocial").mkdir(parents=True)
    tree = checkout.tree(installed)
    assert (tree.commit, tree.dirty) == (None, None)
    assert (
        tree.reason
        == f"{installed / 'jaxsocial'} is not in a git checkout of its own (an installed package?)"
    )
    vendored = repo / "vendored"  # inside another project's checkout, not at its root
    (vendored / "jaxsocial").mkdir(parents=True)
    assert checkout.tree(vendored).commit is None and checkout.tree(vendored).dirty is None
    fresh = tmp_path / "fresh"
    (fresh / "jaxsocial").mkdir(parents=True)
    _git(fresh, "init", "-q")
    assert checkout.tree(fresh).reason == f"the checkout {fresh} has no commit yet"
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    provenance.write_run_file(run_dir, "python -m jaxsocial.train", tree, None, provenance.now(), 0)
    info = jsonio.read_json(run_dir / provenance.RUN_FILE)
    assert info["commit"] is None and info["no_commit_reason"] == tree.reason and info["dirty"] is None


def test_a_training_process_records_itself_unless_its_runner_does(repo, tmp_path, monkeypatch):
    """What `train.run` wraps its training in: the process file before (no end) and after, with the commit,
    the tree and the machine; a resumed process keeps the one before, a failed one says so; a process
    `pinned.run` started (`PARENT_WRITES`) writes none."""
    monkeypatch.setattr(checkout, "ROOT", repo)
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")
    monkeypatch.delenv(provenance.PARENT_WRITES, raising=False)
    _make_dirty(repo)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    with provenance.recorded(run_dir, "python -m jaxsocial.train --seed 0", resume=False):
        during = jsonio.read_json(run_dir / provenance.RUN_FILE)
    after = jsonio.read_json(run_dir / provenance.RUN_FILE)
    assert (during["ended"], during["rc"], after["rc"]) == (None, None, 0) and after["ended"] >= after[
        "started"
    ]
    assert {k: v for k, v in after.items() if k not in ("ended", "rc")} == {
        k: v for k, v in during.items() if k not in ("ended", "rc")
    }
    assert after["command"] == "python -m jaxsocial.train --seed 0" and after["cores"] is None
    assert after["commit"] == _git(repo, "rev-parse", "HEAD") and after["dirty"] is True
    assert (run_dir / after["tree_diff"]).read_bytes() == checkout.tree(repo).diff
    assert after["cpu"] == cpuinfo.model() and after["visible_cores"] == provenance.visible_cores()
    assert after["xla_flags"] == "--xla_cpu_multi_thread_eigen=false"
    assert {k: after[k] for k in provenance.ENVIRONMENT_FIELDS} == provenance.environment()
    with (
        pytest.raises(RuntimeError),
        provenance.recorded(run_dir, "python -m jaxsocial.train --resume", True),
    ):
        raise RuntimeError("a failure while training")
    resumed = jsonio.read_json(run_dir / provenance.RUN_FILE)
    assert resumed["rc"] == 1 and resumed["earlier"] == [after]
    monkeypatch.setenv(provenance.PARENT_WRITES, "1")
    started_by_runner = tmp_path / "pinned"
    started_by_runner.mkdir()
    with provenance.recorded(started_by_runner, "python -m jaxsocial.train", resume=False):
        pass
    assert not any(started_by_runner.iterdir())


def test_the_runner_records_the_tree_each_process_started_from(repo, tmp_path, monkeypatch):
    monkeypatch.setattr(pinned, "POLL_SECONDS", 0.05)
    monkeypatch.setattr(checkout, "ROOT", repo)
    _make_dirty(repo)
    run_dir = tmp_path / "job"
    make = f"import os, pathlib; d = pathlib.Path({str(run_dir)!r}); d.mkdir(); (d / 'config.json').touch()"
    told = f"(d / 'told').write_text(os.environ[{provenance.PARENT_WRITES!r}])"
    assert pinned.run([pinned.Job("job", ("-c", f"{make}; {told}"), run_dir)], [0]) == [0]
    assert (run_dir / "told").read_text() == "1"  # so a training process would write no process file itself
    info = jsonio.read_json(run_dir / provenance.RUN_FILE)
    assert info["commit"] == _git(repo, "rev-parse", "HEAD") and info["dirty"] is True and info["cores"] == 1
    assert hashlib.sha256((run_dir / info["tree_diff"]).read_bytes()).hexdigest() == info["tree_diff_sha256"]
    run = pinned.run_provenance(run_dir, "a CPU", "0.0")
    assert {k: run[k] for k in ("commit", *checkout.TREE_FIELDS)} == checkout.tree(repo).fields()


def _runs_with_process_files(tmp_path: Path, tree: checkout.Tree) -> Path:
    """The committed tiny records as runs a runner left, each with a process file of `tree`."""
    runs = tmp_path / "runs"
    shutil.copytree(REPO / paths.RECORDS / "tiny", runs / "tiny")
    for run_dir in (runs / "tiny").iterdir():
        provenance.write_run_file(run_dir, "python -m jaxsocial.train", tree, 1, provenance.now(), 0)
    return runs


@needs_records("records/tiny")
def test_record_refuses_a_dirty_tree_unless_allowed(repo, tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)  # the experiments' commands run from a checkout's root
    monkeypatch.setattr(checkout, "ROOT", repo)
    clean = checkout.tree(repo)
    runs, out = _runs_with_process_files(tmp_path, clean), tmp_path / "records"
    command = [*RECORD, "--runs-dir", str(runs), "--out-dir", str(out)]
    cli.main(command)  # a clean tree, runs trained from one: recorded as they are
    packed = sorted(out.rglob(records.PROVENANCE_FILE))
    assert len(packed) == 4 and not list(out.rglob("tree-*.diff"))
    before = {p: p.read_text() for p in packed}
    for provenance_ in map(jsonio.read_json, packed):
        assert provenance_["run"]["commit"] == clean.commit and provenance_["run"]["dirty"] is False
        assert provenance_["record"]["packed_at_commit"] == clean.commit
        assert provenance_["record"]["packed_dirty"] is False
    _make_dirty(repo)
    refused = (
        rf"refusing to record from a dirty tree: jaxsocial/ differs from commit {clean.commit[:12]} \(MM "
    )
    with pytest.raises(SystemExit, match=refused + r".*--allow-dirty.*Nothing was recorded"):
        cli.main([*command, "--overwrite"])
    assert {p: p.read_text() for p in sorted(out.rglob(records.PROVENANCE_FILE))} == before  # nothing written
    cli.main([*command, "--overwrite", "--allow-dirty"])
    assert all(jsonio.read_json(p)["record"]["packed_dirty"] is True for p in packed)


@needs_records("records/tiny")
def test_runs_trained_from_a_dirty_tree_are_recorded_only_when_allowed_and_with_their_diff(
    repo, tmp_path, monkeypatch
):
    monkeypatch.chdir(REPO)
    monkeypatch.setattr(checkout, "ROOT", repo)
    _make_dirty(repo)
    dirty = checkout.tree(repo)
    runs, out = _runs_with_process_files(tmp_path, dirty), tmp_path / "records"
    _git(repo, "add", "-A")
    _git(repo, "commit", "-qm", "the changes, committed after the runs")
    assert checkout.tree(repo).dirty is False
    command = [*RECORD, "--runs-dir", str(runs), "--out-dir", str(out)]
    with pytest.raises(
        SystemExit, match=rf"refusing to record runs trained from a dirty tree.*\({dirty.diff_file}\)"
    ):
        cli.main(command)
    assert not out.exists()
    cli.main([*command, "--allow-dirty"])
    packed = sorted(out.rglob(records.PROVENANCE_FILE))
    assert len(packed) == 4
    for path in packed:
        run = jsonio.read_json(path)["run"]
        assert {k: run[k] for k in ("commit", *checkout.TREE_FIELDS)} == dirty.fields()
        assert (path.parent / dirty.diff_file).read_bytes() == dirty.diff  # rebuilds the code it ran
        assert records.tree_diffs(path.parent, run) == [path.parent / dirty.diff_file]
    altered = runs / "tiny" / "solo_pred_nopenalty-s0-1" / dirty.diff_file
    altered.write_text("edited since\n")
    with pytest.raises(SystemExit, match=f"{altered}: its sha256 is not the {dirty.diff_sha256}"):
        cli.main([*command, "--allow-dirty", "--overwrite"])


def test_a_designs_runs_refuse_a_dirty_tree_unless_allowed(repo, tmp_path, monkeypatch, capsys):
    """A pre-registered design's runs train from a clean tree; a dry run trains nothing and is not refused,
    and another recipe's runs train with a warning (their process files record the diff)."""
    monkeypatch.setattr(checkout, "ROOT", repo)
    started = []
    monkeypatch.setattr(
        pinned, "run", lambda jobs, cores, flags: started.append(len(jobs)) or [0] * len(jobs)
    )
    runs = tmp_path / "runs"
    design = ["run", "h1_laptop", "--scale", "laptop", "--runs-dir", str(runs), "--cores", "0"]
    cli.main(design)
    assert len(started) == 1 and "warning" not in capsys.readouterr().err
    _make_dirty(repo)
    with pytest.raises(
        SystemExit,
        match=r"refusing to train the pre-registered design h1_laptop from a dirty tree: jaxsocial/ differs "
        r".*--allow-dirty.*Nothing was trained",
    ):
        cli.main(design)
    assert len(started) == 1 and not runs.exists()
    cli.main([*design, "--dry-run"])
    cli.main([*design, "--allow-dirty"])
    assert len(started) == 2
    cli.main(["run", "h1", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(runs), "--cores", "0"])
    assert len(started) == 3
    assert "warning: jaxsocial/ differs from commit" in capsys.readouterr().err


def test_verify_reads_a_plain_runs_process_file_and_names_its_diff(repo, tmp_path, monkeypatch):
    """A run directory that is no record answers verify's questions from its process file; the report's
    commit line and its way to re-train bit for bit name the diff of a run from a dirty tree."""
    monkeypatch.setattr(checkout, "ROOT", repo)
    monkeypatch.delenv(provenance.PARENT_WRITES, raising=False)
    _make_dirty(repo)
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    with provenance.recorded(run_dir, "python -m jaxsocial.train", resume=False):
        pass
    assert records.run_field(run_dir, "cpu") is None  # no record
    assert verify.record_cpu(run_dir) == cpuinfo.model()
    assert verify.record_cores(run_dir) == len(provenance.visible_cores())
    environment = {field: verify.record_field(run_dir, field) for field in provenance.ENVIRONMENT_FIELDS}
    assert verify.environment_differences(environment, provenance.environment()) == []
    tree = {k: verify.record_field(run_dir, k) for k in checkout.TREE_FIELDS}
    result = {
        "record": str(run_dir),
        "iterations": 1,
        "exact": True,
        "rows": [1, 1],
        "first_difference": None,
        "compared": "every field",
        "cpu": {"record": verify.record_cpu(run_dir), "here": cpuinfo.model()},
        "environment": {"record": environment, "here": provenance.environment()},
        "commit": {"record": verify.record_field(run_dir, "commit"), "here": "b" * 40},
        "tree": {"record": tree, "here": {"dirty": False}},
        "xla_flags": verify.retraining_flags(run_dir),
        "cores": {"record": verify.record_cores(run_dir), "here": verify.record_cores(run_dir)},
    }
    said = verify.report(result)
    assert "not recorded" not in said
    commit = _git(repo, "rev-parse", "HEAD")
    assert (
        f"  commit: record {commit} with jaxsocial/ changed ({tree['tree_diff']}); here {'b' * 40}\n" in said
    )
    assert said.splitlines()[-1].startswith(
        f"  bit for bit it re-trains from commit {commit} with its {tree['tree_diff']} applied (git apply), "
    )
