"""The experiments' commands say at the door that they need a checkout's committed results, before anything
is read or written, where the working directory holds none; every command's `--results DIR` points them at
a checkout's results from anywhere."""

import re
from pathlib import Path

import pytest
from conftest import RESULTS, needs_records

from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments import followup, kind_commands, sweep
from jaxsocial.experiments.analyse import branch_results as br
from jaxsocial.experiments.analyse import takeoff_power
from jaxsocial.experiments.launch import evaluation_play
from jaxsocial.experiments.plan import designs, paths

COMMANDS = {
    "experiments": (cli.main, ["list"]),
    "sweep": (sweep.main, ["list"]),
    "pooled": (takeoff_power.main, []),
    "evaluation_design": (kind_commands.evaluation_main, ["figure", "transfer"]),
    "branch_design": (kind_commands.branch_main, ["figure", "mixing"]),
    "followup": (followup.main, ["figure", "h1_laptop"]),
}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_a_command_outside_a_checkout_says_it_needs_one(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    main, argv = COMMANDS[name]
    with pytest.raises(SystemExit, match=r"no benchmarks/results/ in .*run them from the root of a clone"):
        main(argv)
    assert not any(tmp_path.iterdir())  # nothing written


@pytest.fixture
def results_moved_back():
    """Put `paths` back as it was after a test that moved the results (`--results DIR`)."""
    saved = {name: value for name, value in vars(paths).items() if isinstance(value, Path)}
    yield
    vars(paths).update(saved)


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_results_dir_that_is_not_there_is_named(name, tmp_path, monkeypatch, results_moved_back):
    monkeypatch.chdir(tmp_path)
    main, argv = COMMANDS[name]
    missing = tmp_path / "elsewhere" / "results"
    with pytest.raises(SystemExit, match=rf"no {missing}/: .*or name its results with --results DIR"):
        main(["--results", str(missing), *argv])
    assert not any(tmp_path.iterdir())


def test_results_dir_moves_every_results_path_and_the_parsers_defaults(results_moved_back):
    runs = paths.EXPERIMENT_RUNS
    rest = paths.take_results_option(["figure", "--results", "/r", "--out", "x"])
    assert rest == ["figure", "--out", "x"]
    names = ("RESULTS", "RECORDS", "DEVIATIONS", "EVIDENCE", "EXPERIMENT_RUNS")
    moved = {name: str(getattr(paths, name)) for name in names}
    assert moved == {
        "RESULTS": "/r",
        "RECORDS": "/r/records",
        "DEVIATIONS": "/r/deviations",
        "EVIDENCE": "/r/science/experts-evidence",
        "EXPERIMENT_RUNS": str(runs),  # the run directories stay
    }
    args = sweep.make_parser().parse_args(["figure"])
    assert (args.records_dir, args.out) == ("/r/records", "/r/science/sweep")


@needs_records("records/laptop/prereg-experts")
def test_a_command_reads_the_results_it_is_pointed_at(tmp_path, monkeypatch, capsys, results_moved_back):
    mixing = designs.load("mixing")
    recorded = br.as_designed(mixing, RESULTS / "records")["recorded"]
    monkeypatch.chdir(tmp_path)  # no benchmarks/results here
    science = tmp_path / "science"
    kind_commands.branch_main(["figure", "mixing", "--results", str(RESULTS), "--science", str(science)])
    if recorded < 120:
        assert f"[mixing] {recorded} of 120 branches recorded" in capsys.readouterr().out
    else:
        assert (science / "mixing.json").exists()


def test_a_code_only_clone_says_how_to_fetch_the_records_a_command_reads(tmp_path, monkeypatch):
    """Where a committed records folder is left out of the checkout, `figure` and an evaluation design name
    the folder and the exact `git sparse-checkout add` line, not a training command."""
    (tmp_path / paths.SCIENCE).mkdir(parents=True)  # a checkout's results, without records/
    monkeypatch.chdir(tmp_path)
    figure = ["figure", "h1_laptop", "--scale", "laptop", "--runs-dir", str(paths.RECORDS)]
    fetch = "git sparse-checkout add '/benchmarks/results/records/laptop/prereg-h1_laptop/'"
    with pytest.raises(SystemExit, match=re.escape(fetch)):
        cli.main(figure)
    with pytest.raises(
        FileNotFoundError,
        match=re.escape("git sparse-checkout add '/benchmarks/results/records/laptop/prereg-experts/'"),
    ):
        evaluation_play.run(designs.load("transfer"), paths.RECORDS, paths.SCIENCE)
