"""docs/your-experiment.md's record, verify and power steps: `record` measures the device of runs trained by
`run --cores` instead of taking it typed, `verify`'s default fits a short record, `power` names the recipes
it takes."""

import shutil
from pathlib import Path

import jax
import pytest
from conftest import needs_records

from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments.analyse import records
from jaxsocial.experiments.launch import pinned, verify
from jaxsocial.experiments.plan import paths
from jaxsocial.run import checkout, cpuinfo, jsonio, provenance, rundir

REPO = Path(__file__).resolve().parents[1]
TINY_RECORDS = REPO / paths.RECORDS / "tiny"
RECORD = ["record", "no_penalty", "--scale", "tiny", "--seeds", "2"]


@needs_records("records/tiny")
def test_record_takes_the_device_each_runs_process_measured(tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)
    monkeypatch.setattr(checkout, "tree", lambda root=None: checkout.Tree("abc", False))  # as after a commit
    runs = tmp_path / "runs"
    shutil.copytree(TINY_RECORDS, runs / "tiny")
    for run_dir in (runs / "tiny").iterdir():  # as `run --cores` leaves them: a process file each
        provenance.write_run_file(
            run_dir, "python -m jaxsocial.train", checkout.tree(), 1, provenance.now(), rc=0
        )
    out = tmp_path / "records"
    cli.main([*RECORD, "--runs-dir", str(runs), "--out-dir", str(out)])
    provenances = [records.read_provenance(p.parent)["run"] for p in out.rglob(records.PROVENANCE_FILE)]
    assert len(provenances) == 4
    assert {p["device"] for p in provenances} == {f"{cpuinfo.model()}, one core per seed"}
    assert {p["jax"] for p in provenances} == {jax.__version__}
    assert pinned.with_measured({"cpu": "X", "cores": 2}, None, "1", runs)["device"] == "X, 2 cores"
    for run_dir in (runs / "tiny").iterdir():  # a run file written before it held the machine
        info = jsonio.read_json(run_dir / provenance.RUN_FILE)
        jsonio.write_json(run_dir / provenance.RUN_FILE, {k: v for k, v in info.items() if k != "versions"})
    with pytest.raises(SystemExit, match=f"its {provenance.RUN_FILE} does not say; give --jax"):
        cli.main([*RECORD, "--runs-dir", str(runs), "--out-dir", str(tmp_path / "more")])
    cli.main([*RECORD, "--runs-dir", str(runs), "--out-dir", str(tmp_path / "more"), "--jax", "0.1"])


def test_a_commands_logs_device_must_be_given(capsys):
    with pytest.raises(SystemExit):
        cli.parse_args([*RECORD, "--commands-log", "log"])
    assert "--commands-log: give --device and --jax" in capsys.readouterr().err


@needs_records("records/tiny")
def test_verify_defaults_to_what_a_short_record_holds(monkeypatch):
    record = next(p.parent for p in TINY_RECORDS.rglob(records.PROVENANCE_FILE))
    rows = len(rundir.read_metrics(record))
    assert rows < verify.DEFAULT_ITERATIONS
    asked = []
    monkeypatch.setattr(verify, "verify", lambda record_dir, iterations: asked.append(iterations) or {})
    monkeypatch.setattr(verify, "report", lambda result: "")
    cli.main(["verify", str(record)])
    cli.main(["verify", str(record), "--iterations", "2"])
    assert asked == [rows, 2]


def test_power_names_the_designs_it_takes(capsys):
    with pytest.raises(SystemExit):
        cli.parse_args(["power", "--help"])
    assert "designs of every kind: " in capsys.readouterr().out.replace("\n", " ").replace("  ", " ")
    with pytest.raises(SystemExit):
        cli.parse_args(["power", "no_penalty"])
    assert "invalid choice: 'no_penalty'" in capsys.readouterr().err
