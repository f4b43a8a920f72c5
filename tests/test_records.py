"""Run records: the committed tiny record set re-derives its committed summary with no training, records
read like run directories, and packing checks everything before it writes."""

import functools
import json
import shutil
from pathlib import Path

import pytest
from conftest import needs_records

from jaxsocial import playback
from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments import followup, sweep
from jaxsocial.experiments.analyse import records, summaries, takeoff_power
from jaxsocial.experiments.plan import catalogue, designs, paths, recipes, sweep_settings
from jaxsocial.run import jsonio, metrics, policy_io, provenance, rundir
from jaxsocial.run.runlock import RunLock

REPO = Path(__file__).resolve().parents[1]
SUMMARY = "benchmarks/results/science/no_penalty-tiny.json"
"""The committed summary of the committed tiny records (`python -m jaxsocial.experiments figure no_penalty
--scale tiny --seeds 2 --runs-dir benchmarks/results/records --out-dir benchmarks/results/science`)."""
RECIPE = recipes.RECIPES["no_penalty"]
TINY_RECORDS = needs_records("records/tiny")
UNCOMMITTED = ["--allow-dirty"]
"""`record` on the tree as it is, uncommitted work included (tests/test_provenance.py tests the refusal)."""


@pytest.fixture
def in_repo(monkeypatch):
    """Run from the repository root, where the summary's relative record paths point."""
    monkeypatch.chdir(REPO)


def _record_dirs() -> list[Path]:
    return sorted(p.parent for p in (REPO / paths.RECORDS / "tiny").rglob(records.PROVENANCE_FILE))


@TINY_RECORDS
def test_the_committed_summary_is_rederived_from_the_records_alone(in_repo, tmp_path):
    committed = json.loads(Path(SUMMARY).read_text())
    runs = summaries.RecipeRuns(RECIPE, recipes.TINY, 0, 2, str(paths.RECORDS))
    assert jsonio.to_json(summaries.summarize(runs, committed["command"])) == committed
    assert committed["provenance"]["unrecorded"] == []
    for condition, dirs in committed["seed_dirs"].items():
        finals = [round(metrics.final_return(rundir.read_metrics(d)), 4) for d in dirs]
        assert committed["training"][condition]["final_returns"] == finals
    argv = committed["command"].split()[3:]  # after 'python -m jaxsocial.experiments'
    argv[argv.index("--out-dir") + 1] = str(tmp_path)
    cli.main(argv)
    again = json.loads((tmp_path / "no_penalty-tiny.json").read_text())
    assert {k: v for k, v in again.items() if k != "command"} == {
        k: v for k, v in committed.items() if k != "command"
    }
    assert (tmp_path / "no_penalty-tiny.png").stat().st_size > 1000


@TINY_RECORDS
def test_a_record_reads_like_a_run_directory():
    record_dirs = _record_dirs()
    assert len(record_dirs) == 4  # 2 conditions x 2 seeds
    for record in record_dirs:
        config = rundir.read_config(record)
        assert len(rundir.read_metrics(record)) == config["iterations"]
        assert not (record / "checkpoints").exists() and not (record / rundir.METRICS_FILE).exists()
        assert policy_io.policy_iteration(str(record)) == config["iterations"]
        recorded = records.read_provenance(record)
        assert set(recorded["run"]) == set(provenance.RUN_FIELDS) and recorded["run"]["rc"] == 0
        assert f"--run-name {recorded['record']['source'].rsplit('/', 1)[0]}" in recorded["run"]["command"]
    # what `render --ckpt` and `evaluate --ckpt` load: the policy with the network it was trained with
    spec = str(recipes.goalcycle_spec("goalcycle3", recipes.TINY))
    setup = playback.episode_setup(str(record_dirs[0]), spec)
    assert setup.net_cfg == policy_io.saved_net(str(record_dirs[0]))


def test_commands_log(tmp_path):
    log = tmp_path / "commands.log"
    commit = "a" * 40
    log.write_text(
        f"2026-01-01T00:00:00 {commit} python -m jaxsocial.train --seed 0 --run-name cpu/x-s0-2\n"
        "2026-01-01T00:10:00 done x rc=0 600s\n"
        '2026-01-01T00:10:30 machine {"cpu": "a GPU host", "xla_flags": ""}\n'
        f"2026-01-01T00:11:00 {commit} python -m jaxsocial.train --run-name cpu/y-s0-0\n"
        "2026-01-01T00:12:00 done y rc=0 60s\n"
        f"2026-01-01T00:13:00 {commit} python -m jaxsocial.train --run-name cpu/w-s0-0\n"
        "2026-01-01T00:14:00 done w rc=1 60s\n"
        "a line that is neither\n"
    )
    runs = records.read_commands_log(log)
    assert runs["cpu/x-s0-2"] == {
        "command": "python -m jaxsocial.train --seed 0 --run-name cpu/x-s0-2",
        "commit": commit,
        "started": "2026-01-01T00:00:00",
        "ended": "2026-01-01T00:10:00",
        "rc": 0,
        "machine": {},  # no machine line before its start
    }
    assert runs["cpu/w-s0-0"]["rc"] == 1
    run = records.logged_provenance("cpu/x-s0-2", runs, "a CPU", "0.1")
    assert (run["device"], run["jax"], run["commit"]) == ("a CPU", "0.1", commit) and "xla_flags" not in run
    run = records.logged_provenance("cpu/y-s0-0", runs, "a GPU", "0.1")
    assert (run["cpu"], run["xla_flags"], run["rc"]) == ("a GPU host", "", 0)  # no deterministic GPU ops
    with pytest.raises(ValueError, match="exited with 1; not a result to record"):
        records.logged_provenance("cpu/w-s0-0", runs, "a GPU", "0.1")
    with pytest.raises(ValueError, match="no command with --run-name cpu/z"):
        records.logged_provenance("cpu/z", runs, None, None)


@TINY_RECORDS
def test_pack_checks_before_it_writes(tmp_path):
    source = _record_dirs()[0]
    run = records.read_provenance(source)["run"]
    out = records.pack(source, tmp_path / "r", run, "tiny/x/s0")
    assert rundir.read_metrics(out) == rundir.read_metrics(source)
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in source.iterdir())
    assert records.read_provenance(out)["run"] == run
    with pytest.raises(FileExistsError, match="--overwrite"):
        records.pack(source, out, run, "tiny/x/s0")
    unfinished = tmp_path / "unfinished"
    shutil.copytree(source, unfinished)
    rundir.write_config(unfinished, {**rundir.read_config(source), "iterations": 1000})
    with pytest.raises(ValueError, match="unfinished"):
        records.pack(unfinished, tmp_path / "u", run, "tiny/u/s0")
    # A run its --stop-at-return ended is finished when its last chunk's learner return reached the threshold.
    stopped = {**rundir.read_config(source), "iterations": 1000}
    rundir.write_config(unfinished, {**stopped, "stop_at_return": 1e9})
    with pytest.raises(ValueError, match="unfinished"):
        records.pack(unfinished, tmp_path / "u", run, "tiny/u/s0")
    rundir.write_config(unfinished, {**stopped, "stop_at_return": -1e9})
    packed = records.pack(unfinished, tmp_path / "s", run, "tiny/s/s0")
    assert jsonio.read_json(packed / records.PROVENANCE_FILE)["record"]["stopped_early"] is True
    with pytest.raises(FileNotFoundError, match="not a finished seed run"):
        records.pack(tmp_path / "nowhere", tmp_path / "n", run, "n")
    assert not (tmp_path / "u").exists() and not (tmp_path / "n").exists()


def _commands_log(tmp_path: Path) -> Path:
    """The commands log the committed tiny records were made from, rebuilt from their provenance."""
    log = tmp_path / "commands.log"
    lines = []
    for cond in RECIPE.conditions:
        run = records.read_provenance(next(d for d in _record_dirs() if cond + "-" in str(d)))["run"]
        lines += [f"{run['started']} {run['commit']} {run['command']}", f"{run['ended']} done {cond} rc=0 1s"]
    log.write_text("\n".join(lines) + "\n")
    return log


@TINY_RECORDS
def test_record_command_keeps_existing_records_and_refuses_failed_runs(in_repo, tmp_path, capsys):
    log = _commands_log(tmp_path)
    argv = ["record", "no_penalty", "--scale", "tiny", "--seeds", "2", "--runs-dir", str(paths.RECORDS),
            "--commands-log", str(log), "--device", "a CPU", "--jax", "0.1",
            "--out-dir", str(tmp_path / "r"), *UNCOMMITTED]  # fmt: skip
    cli.main(argv)
    packed = sorted((tmp_path / "r").rglob(records.PROVENANCE_FILE))
    assert len(packed) == 4
    before = [p.read_text() for p in packed]
    capsys.readouterr()
    cli.main(argv)
    assert capsys.readouterr().out.count("already recorded, kept") == 4
    assert [p.read_text() for p in packed] == before
    # The records hold no checkpoints: asking for every seed's final checkpoint fails before any write, and
    # 'learned' asks only for the seeds past the threshold, which these tiny runs are not.
    with pytest.raises(SystemExit, match="no checkpoint of its final iteration"):
        cli.main([*argv, "--overwrite", "--final-checkpoint", "all"])
    assert [p.read_text() for p in packed] == before
    cli.main([*argv, "--overwrite", "--final-checkpoint", "learned"])
    assert not list((tmp_path / "r").rglob("checkpoints"))
    log.write_text(log.read_text().replace("rc=0", "rc=1"))
    with pytest.raises(SystemExit, match="exited with 1"):
        cli.main([*argv, "--overwrite"])


def test_figures_go_under_runs_unless_asked():
    assert cli.parse_args(["figure", "h1"]).out_dir.startswith("runs/")
    assert cli.parse_args(
        ["record", "h1", "--commands-log", "l", "--device", "d", "--jax", "j"]
    ).out_dir.startswith("runs/")


def _record_all_but_one_seed(tmp_path: Path, spoil) -> Path:
    """Copy the committed tiny records into a runs directory, `spoil(seed_dir)` one solo seed, run `record`
    over the copy and check that it packed every seed but that one; returns that seed's directory (what
    `record` printed is the caller's to read from `capsys`)."""
    runs = tmp_path / "runs"
    shutil.copytree(REPO / paths.RECORDS / "tiny", runs / "tiny")
    solo = next(d for d in _record_dirs() if "solo_pred" in str(d))
    spoiled = runs / solo.relative_to(REPO / paths.RECORDS)
    spoil(spoiled)
    argv = ["record", "no_penalty", "--scale", "tiny", "--seeds", "2", "--runs-dir", str(runs),
            "--commands-log", str(_commands_log(tmp_path)), "--device", "a CPU", "--jax", "0.1",
            "--out-dir", str(tmp_path / "r"), *UNCOMMITTED]  # fmt: skip
    cli.main(argv)
    packed = {p.parent.relative_to(tmp_path / "r") for p in (tmp_path / "r").rglob(records.PROVENANCE_FILE)}
    every = {p.parent.relative_to(runs) for p in runs.rglob(records.PROVENANCE_FILE)}
    assert len(every) == 4 and packed == every - {spoiled.relative_to(runs)}
    return spoiled


@TINY_RECORDS
def test_record_command_skips_seeds_still_training(in_repo, tmp_path, capsys):
    """A design's records are committed seed by seed while the next seeds train: `record` packs the finished
    seeds and names the unfinished one, which it leaves for a later call."""

    def still_training(seed_dir: Path) -> None:
        rundir.write_config(seed_dir, {**rundir.read_config(seed_dir), "iterations": 1000})

    training = _record_all_but_one_seed(tmp_path, still_training)
    assert f"{training} is unfinished: 4 of 1000 iterations logged; skipped" in capsys.readouterr().out


@TINY_RECORDS
def test_record_command_skips_seeds_not_evaluated_yet(in_repo, tmp_path, capsys):
    """A seed that finished training but not yet its evaluations (the runner evaluates after training, or
    `run --no-train` does): `record` names it and leaves it for a later call, so no record lacks them."""

    def not_evaluated(seed_dir: Path) -> None:
        assert list((seed_dir / "eval").iterdir())
        shutil.rmtree(seed_dir / "eval")

    unevaluated = _record_all_but_one_seed(tmp_path, not_evaluated)
    assert f"{unevaluated} not evaluated yet in " in capsys.readouterr().out


@TINY_RECORDS
def test_record_command_skips_seeds_whose_command_has_not_ended(in_repo, tmp_path, capsys):
    """A seed whose training has finished while its `pinned` command has not yet written its run file (the
    runner winding up): `record` names it and leaves it for a later call instead of failing."""
    runs = tmp_path / "runs"
    shutil.copytree(REPO / paths.RECORDS / "tiny", runs / "tiny")  # records hold no run file
    argv = ["record", "no_penalty", "--scale", "tiny", "--seeds", "2", "--runs-dir", str(runs),
            "--device", "a CPU", "--jax", "0.1", "--out-dir", str(tmp_path / "r"), *UNCOMMITTED]  # fmt: skip
    cli.main(argv)
    assert capsys.readouterr().out.count(f"{provenance.RUN_FILE} does not exist") == 4
    assert not (tmp_path / "r").exists()


def test_every_committed_results_path_exists():
    """`paths` names where the committed results are: each of them is in the repository (the records, which a
    code-only clone leaves out, in the test below)."""
    committed = {name: value for name, value in vars(paths).items() if isinstance(value, Path)}
    committed = {n: p for n, p in committed.items() if p.is_relative_to(paths.RESULTS) and p != paths.RECORDS}
    suffixed = {paths.SWEEP_SUMMARY, paths.MAP_SUMMARY}  # named without their .json/.png
    missing = [
        name
        for name, p in committed.items()
        if not (REPO / (p.with_suffix(".json") if p in suffixed else p)).exists()
    ]
    assert not missing and len(committed) >= 8


@needs_records("records")
def test_the_records_are_in_the_repository():
    assert (REPO / paths.RECORDS).is_dir()


def test_a_record_keeps_its_checkpoint_only_with_a_reason():
    """`record --final-checkpoint`: learned seeds (above the threshold) or every seed keep theirs, and say
    why; otherwise none is kept."""
    assert records.checkpoint_reason(None, 30.0, 5.0) is None
    assert records.checkpoint_reason("learned", 4.9, 5.0) is None
    assert "final return 30.00 > 5" in records.checkpoint_reason("learned", 30.0, 5.0)
    assert "--final-checkpoint all" in records.checkpoint_reason("all", -3.0, 5.0)


def _rederivations() -> dict[str, functools.partial]:
    """Every committed summary made from the committed records alone (file name) -> the command that writes
    it, run from the repository root: the `figure` command it names (a recipe's or a design's of any kind),
    the follow-ups', the sweep's and its map, and the pooled summaries."""
    science = REPO / paths.SCIENCE
    out = {}
    for path in sorted(science.glob("*.json")):
        summary = jsonio.read_json(path)
        command = summary.get("command") or ""
        if command.startswith("python -m jaxsocial.experiments figure "):
            out[path.name] = functools.partial(cli.main, command.split()[3:])
        elif path.name.startswith("followup-"):
            out[path.name] = functools.partial(followup.main, ["figure", summary["design"]])
    out[paths.SWEEP_SUMMARY.name + ".json"] = functools.partial(sweep.main, ["figure"])
    committed = ["--summary", str(science / "sweep.json")]
    out[paths.MAP_SUMMARY.name + ".json"] = functools.partial(sweep.main, ["map", *committed])
    for pooled in takeoff_power.POOLED:
        out[pooled] = functools.partial(takeoff_power.main, [])
    return out


def _records_read(name: str) -> tuple[str, ...]:
    """The folders under benchmarks/results/ that re-deriving the committed summary `name` reads: its
    scale's records, the sweep's, an evaluation design's, a branch design's and its material's, or none (the
    map reads the sweep's summary)."""
    summary = jsonio.read_json(REPO / paths.SCIENCE / name)
    command = (summary.get("command") or "").split()
    if name == paths.MAP_SUMMARY.name + ".json":
        return ()
    if name == paths.SWEEP_SUMMARY.name + ".json":
        return (f"records/{sweep_settings.RECORDS_SUBDIR}",)
    designed = summary.get("design") in catalogue.design_names()
    kind = catalogue.design_kind(summary["design"]) if designed else None
    if kind == "evaluation":
        return (f"records/{designs.load(summary['design']).records}",)
    if kind == "branch":
        design = designs.load(summary["design"])
        return (f"records/{design.records}", f"records/{design.out}")
    if "--scale" in command:
        return (f"records/{command[command.index('--scale') + 1]}",)
    return ("records/laptop",)  # the follow-ups' and the pooled laptop summaries


def _rederivation_params() -> list:
    return [pytest.param(n, marks=needs_records(*_records_read(n))) for n in sorted(_rederivations())]


def test_every_committed_summary_is_rederived_or_from_runs_not_committed():
    """A summary the test below does not re-derive names a command that trains (`run`): its runs were not
    recorded."""
    rederived = _rederivations()
    for path in sorted((REPO / paths.SCIENCE).glob("*.json")):
        if path.name not in rederived:
            assert jsonio.read_json(path)["command"].startswith("python -m jaxsocial.experiments run "), path


@pytest.mark.slow
@pytest.mark.parametrize("name", _rederivation_params())
def test_a_committed_summary_rederives_byte_for_byte_at_head(name, tmp_path, monkeypatch):
    """What the README promises: run a summary's command and `git status` shows nothing changed. It runs, as
    written, in a copy of the repository's results whose summaries are not there yet (everything else is
    linked), and its JSON must equal the committed bytes (the figures' PNG bytes depend on the plotting
    library's version)."""
    results = REPO / paths.RESULTS
    for entry in results.iterdir():
        if entry.name != paths.SCIENCE.name:
            (tmp_path / paths.RESULTS / entry.name).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / paths.RESULTS / entry.name).symlink_to(entry)
    for entry in (REPO / paths.SCIENCE).iterdir():
        if entry.is_dir():  # evaluations some summaries read
            (tmp_path / paths.SCIENCE).mkdir(parents=True, exist_ok=True)
            (tmp_path / paths.SCIENCE / entry.name).symlink_to(entry)
    monkeypatch.chdir(tmp_path)
    _rederivations()[name]()
    assert (tmp_path / paths.SCIENCE / name).read_bytes() == (REPO / paths.SCIENCE / name).read_bytes()


@TINY_RECORDS
def test_restore_copies_records_back_so_the_runner_trains_only_the_rest(in_repo, tmp_path, capsys):
    """On a fresh machine (or in a worktree at a design's commit) the run directories are gone: `restore`
    copies the records back where they were packed from, the runner then counts those seeds finished, and
    `record` leaves them alone; a second `restore` keeps what is there, and a seed that began training again
    beside its record is refused before anything is copied."""
    runs = tmp_path / "runs"
    seeds = ["--scale", "tiny", "--seeds", "2", "--runs-dir", str(runs)]
    cli.main(["restore", "no_penalty", *seeds])
    restored = sorted(p.parent for p in runs.rglob("restored.json"))
    assert [d.relative_to(runs) for d in restored] == [
        d.relative_to(REPO / paths.RECORDS) for d in _record_dirs()
    ]
    for seed_dir, record_dir in zip(restored, _record_dirs(), strict=True):
        assert rundir.read_metrics(seed_dir) == rundir.read_metrics(record_dir)
    capsys.readouterr()
    cli.main(["run", "no_penalty", *seeds, "--dry-run"])
    states = [line for line in capsys.readouterr().out.splitlines() if line.startswith("[no_penalty/tiny] ")]
    assert len(states) == 2 and all(line.endswith(": finished") for line in states), states
    cli.main(["record", "no_penalty", *seeds, "--out-dir", str(tmp_path / "r"), *UNCOMMITTED])
    assert capsys.readouterr().out.count("was restored from its record, kept as it is") == 4
    assert not (tmp_path / "r").exists()
    cli.main(["restore", "no_penalty", *seeds])
    assert capsys.readouterr().out.count("there already, kept") == 4

    fresh = tmp_path / "fresh"
    begun = fresh / restored[-1].relative_to(runs)
    begun.mkdir(parents=True)
    with pytest.raises(SystemExit, match="has begun training again"):
        cli.main(["restore", "no_penalty", *seeds[:-1], str(fresh)])
    assert not list(fresh.rglob("restored.json"))


@TINY_RECORDS
def test_status_says_where_each_seed_stands(in_repo, tmp_path, capsys):
    """`status` reads the records and the run directories: recorded (or training again beside its record),
    finished but not recorded, stopped partway (one seed's program or several seeds'), training now (a live
    lock), not begun; with the iterations of each seed begun, and no return."""
    runs = tmp_path / "runs"
    seeds = ["--scale", "tiny", "--seeds", "3", "--runs-dir", str(runs)]
    cli.main(["status", "no_penalty", *seeds])
    out = capsys.readouterr().out
    for condition in RECIPE.conditions:  # the committed tiny records hold seeds 0 and 1
        assert f"  {condition}: 2 recorded (0-1); 1 not begun (2)" in out, out
    cli.main(["restore", "no_penalty", *seeds])
    record = _record_dirs()[0]
    begun = runs / "tiny" / f"{RECIPE.conditions[0]}-s2-2"  # where `run --cores` trains seed 2
    begun.mkdir()
    shutil.copy(record / rundir.CONFIG_FILE, begun)
    first_row = json.dumps(rundir.read_metrics(record)[0])
    (begun / rundir.METRICS_FILE).write_text(first_row + "\n")
    elsewhere = ["--records", str(tmp_path / "no-records")]
    capsys.readouterr()
    cli.main(["status", "no_penalty", *seeds, *elsewhere])
    out = capsys.readouterr().out
    stopped = "1 stopped partway (run resumes it) (2: 1 of 4 iterations)"
    assert f"  {RECIPE.conditions[0]}: 2 finished, not recorded (0-1); {stopped}" in out, out
    with RunLock(begun):
        cli.main(["status", "no_penalty", *seeds, *elsewhere])
    assert "1 training now (2: 1 of 4 iterations)" in capsys.readouterr().out
    (begun / rundir.METRICS_FILE).unlink()  # begun, nothing logged yet
    cli.main(["status", "no_penalty", *seeds, *elsewhere])
    assert "1 stopped partway (run resumes it) (2: 0 of 4 iterations)" in capsys.readouterr().out
    shutil.rmtree(begun)
    program = runs / "tiny" / f"{RECIPE.conditions[0]}-s0-2"  # the three seeds as one program, begun
    program.mkdir()
    shutil.copy(record / rundir.CONFIG_FILE, program)
    cli.main(["status", "no_penalty", *seeds, *elsewhere])
    assert "1 stopped partway (run resumes it) (2: 0 of 4 iterations)" in capsys.readouterr().out
    with RunLock(runs / "tiny" / f"{RECIPE.conditions[0]}-s0-1"):
        cli.main(["status", "no_penalty", *seeds])
    twice = "2 recorded, yet training again (two results: keep one) (0-1)"
    assert f"  {RECIPE.conditions[0]}: {twice}" in capsys.readouterr().out


@needs_records("records/laptop8/prereg-pred8", "records/laptop/prereg-mixing")
def test_status_of_an_evaluation_and_a_branch_design(in_repo, tmp_path, capsys):
    """`status` of the other kinds: an evaluation design's plays written or not, environment by environment;
    a branch design's branches by arm, recorded or not begun."""
    cli.main(["status", "transfer8"])
    played = capsys.readouterr().out
    assert "  goalcycle4:width=8,height=8: 4 of 4 played\n" in played, played
    cli.main(["status", "transfer8", "--science", str(tmp_path)])
    left = capsys.readouterr().out
    assert "  goalcycle4:width=8,height=8: 0 of 4 played; to play: social_pred, solo_pred, " in left, left
    assert left.count(" played") == played.count(" played")  # every environment, either way
    cli.main(["status", "mixing"])
    assert "  social: 40 recorded (300-339)\n" in capsys.readouterr().out
    cli.main(["status", "mixing", "--records", str(tmp_path), "--runs-dir", str(tmp_path)])
    assert "  social: 40 not begun (300-339)\n" in capsys.readouterr().out


@needs_records("records/laptop8/prereg-imitation8")
def test_restore_finds_a_designs_one_seed_runs(in_repo, tmp_path, capsys):
    """A design trains one seed a program (`<condition>-s<k>-<k>`): its records go back to those names, not
    to the one program its seeds would share without --cores; and `run` plans the design's programs so with
    or without --cores, so a dry run counts the restored seeds finished and the others missing."""
    folder = REPO / paths.RECORDS / "laptop8" / "prereg-imitation8"
    where = ["--scale", "laptop8", "--runs-dir", str(tmp_path)]
    cli.main(["restore", "imitation8", *where])
    restored = sorted(p.parent.relative_to(tmp_path) for p in tmp_path.rglob("restored.json"))
    committed = sorted(
        p.parent.relative_to(REPO / paths.RECORDS) for p in folder.rglob(records.PROVENANCE_FILE)
    )
    assert restored == committed and committed
    capsys.readouterr()
    cli.main(["run", "imitation8", *where, "--dry-run"])
    prefix = "[imitation8/laptop8] bc"
    states = [line for line in capsys.readouterr().out.splitlines() if line.startswith(prefix)]
    recorded = {int(d.name.rsplit("-", 1)[1]) for d in restored}
    seeds = designs.load("imitation8").seed_range
    assert states == [f"{prefix} s{k}: {'finished' if k in recorded else 'missing'}" for k in seeds]
