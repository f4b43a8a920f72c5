"""Runs as pinned single-core processes: the pool (`pinned.run`) and a recipe trained that way, recorded from
the processes' own provenance and read back by `figure`."""

import dataclasses
import json

import jax
import pytest

from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan import prereg
from jaxsocial.run import cpuinfo, provenance, rundir


def _job(tmp_path, name: str, code: str) -> pinned.Job:
    """A job whose process makes its run directory (a config.json) and then runs `code`."""
    run_dir = tmp_path / name
    make = (
        f"import pathlib; d = pathlib.Path({str(run_dir)!r}); d.mkdir(); (d / 'config.json').write_text('1')"
    )
    return pinned.Job(name, ("-c", f"{make}; {code}"), run_dir)


def test_one_process_per_core_at_a_time_each_with_its_provenance(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(pinned, "POLL_SECONDS", 0.05)
    jobs = [
        _job(tmp_path, "first", "import time; time.sleep(1.1)"),
        _job(tmp_path, "second", "import sys; sys.exit(3)"),
        pinned.Job("nothing", ("-c", "pass"), tmp_path / "never_made"),
    ]
    assert pinned.run(jobs, [0]) == [0, 3, 0]  # in the jobs' order
    first, second = (
        json.loads((tmp_path / n / provenance.RUN_FILE).read_text()) for n in ("first", "second")
    )
    assert second["started"] >= first["ended"]  # one core: the second waited for the first
    assert first["rc"] == 0 and second["rc"] == 3 and first["cores"] == 1
    assert first["visible_cores"] == (
        [0] if pinned.pin([0]) else provenance.visible_cores()
    )  # what it could see
    assert first["command"].startswith("python -c ")
    assert not (tmp_path / "never_made").exists()  # no run directory: no provenance written
    assert "first: core 0" in capsys.readouterr().out
    run = pinned.run_provenance(tmp_path / "first", "a CPU", "0.0")
    assert run["device"] == "a CPU" and run["rc"] == 0 and run["cores"] == 1
    assert run["cpu"] == cpuinfo.model() and run["xla_flags"] == pinned.process_xla_flags()
    assert run["visible_cores"] == first["visible_cores"]
    environment = {field: run[field] for field in provenance.ENVIRONMENT_FIELDS}
    assert environment == provenance.environment()
    assert run["versions"]["jax"] == jax.__version__
    assert set(run["versions"]) == set(provenance.VERSIONED)
    with pytest.raises(pinned.RunNotEnded, match="not trained by"):
        pinned.run_provenance(tmp_path, "a CPU", "0.0")
    with pytest.raises(ValueError, match="exited with 3; not a result to record"):  # every kind's records
        pinned.run_provenance(tmp_path / "second", "a CPU", "0.0")
    with pytest.raises(ValueError, match="at least one core"):
        pinned.run(jobs, [])


def test_a_resumed_run_keeps_its_earlier_processes_and_a_running_one_is_not_recorded(tmp_path, monkeypatch):
    """The process file is written once the run directory exists (no end yet: `run_provenance` refuses it),
    and a later process of the same run, e.g. one resumed after a killed sitting, keeps it under `earlier`."""
    monkeypatch.setattr(pinned, "POLL_SECONDS", 0.05)
    run_dir, seen = tmp_path / "run", tmp_path / "seen.json"
    run_file = run_dir / provenance.RUN_FILE
    copy_while_running = (
        f"import pathlib, shutil, time; f = pathlib.Path({str(run_file)!r})\n"
        "while not f.is_file(): time.sleep(0.02)\n"
        f"shutil.copy(f, {str(seen)!r})"
    )
    assert pinned.run([_job(tmp_path, "run", copy_while_running)], [0]) == [0]
    running = json.loads(seen.read_text())
    assert running["rc"] is None and running["ended"] is None and "earlier" not in running
    run_file.write_text(seen.read_text())  # as a killed sitting leaves it
    with pytest.raises(pinned.RunNotEnded, match="has not ended"):
        pinned.run_provenance(run_dir, "a CPU", "0.0")
    resumed = pinned.Job("run", ("-c", "import sys; sys.exit(0)"), run_dir)
    assert pinned.run([resumed, resumed], [0]) == [0, 0]  # resumed twice: the killed process, then the first
    run = pinned.run_provenance(run_dir, "a CPU", "0.0")
    assert run["rc"] == 0 and run["command"] == "python -c 'import sys; sys.exit(0)'"
    killed, first_resume = run["earlier"]
    assert killed["ended"] is None and killed["command"] == running["command"] != run["command"]
    assert first_resume["rc"] == 0 and first_resume["cpu"] == cpuinfo.model()
    assert "earlier" not in killed and "earlier" not in first_resume  # flat, oldest first


def test_the_xla_of_each_process_is_single_threaded_after_the_callers_flags(tmp_path, monkeypatch):
    monkeypatch.setattr(pinned, "POLL_SECONDS", 0.05)
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=0")
    out = tmp_path / "flags.txt"
    code = f"import os, pathlib; pathlib.Path({str(out)!r}).write_text(os.environ['XLA_FLAGS'])"
    assert pinned.run([_job(tmp_path, "x", code)], [0], extra_xla_flags="--xla_cpu_max_isa=AVX2") == [0]
    expected = "--xla_backend_optimization_level=0 --xla_cpu_multi_thread_eigen=false --xla_cpu_max_isa=AVX2"
    assert out.read_text() == expected == pinned.process_xla_flags("--xla_cpu_max_isa=AVX2")
    assert json.loads((tmp_path / "x" / provenance.RUN_FILE).read_text())["xla_flags"] == expected
    monkeypatch.delenv("XLA_FLAGS")
    assert pinned.process_xla_flags() == pinned.SINGLE_CORE_XLA_FLAGS


def test_a_word_xla_would_ignore_with_every_flag_after_it_is_refused(tmp_path, monkeypatch):
    """XLA silently skips a word without `--` and all flags after it (a process would train without them)."""
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_max_isa=AVX2 intra_op_parallelism_threads=1")
    with pytest.raises(ValueError, match="'intra_op_parallelism_threads=1' is not an XLA flag"):
        pinned.run([_job(tmp_path, "x", "pass")], [0])
    assert not (tmp_path / "x").exists()  # refused before any process started
    monkeypatch.delenv("XLA_FLAGS")
    with pytest.raises(ValueError, match="'AVX2' is not an XLA flag"):
        pinned.run([_job(tmp_path, "x", "pass")], [0], extra_xla_flags="--xla_cpu_max_isa= AVX2")


@pytest.mark.slow
def test_a_recipe_trains_seed_by_seed_on_pinned_cores(tmp_path, monkeypatch):
    """`run --cores`: every seed a one-seed program in its own process; `record` takes each run's provenance
    from its process file (no commands log); `figure` reads the seeds from their one-seed runs."""
    monkeypatch.setattr(pinned, "POLL_SECONDS", 0.2)
    runs, records_dir = tmp_path / "runs", tmp_path / "records"
    common = ["bc", "--scale", "tiny", "--seeds", "2", "--runs-dir", str(runs)]
    cli.main(["run", *common, "--cores", "0", "0"])
    for s in (0, 1):
        run_dir = runs / "tiny" / f"bc-s{s}-{s}"
        assert len(rundir.read_metrics(run_dir)) == 4 and (run_dir / provenance.RUN_FILE).is_file()
        assert f"--seed {s} --seeds 1" in json.loads((run_dir / provenance.RUN_FILE).read_text())["command"]
    recorded = ["--device", "a CPU", "--jax", "0.0", "--out-dir", str(records_dir), "--allow-dirty"]
    cli.main(["record", *common, *recorded])  # --allow-dirty: the tree may hold uncommitted work
    recorded = json.loads((records_dir / "tiny" / "bc-s1-1" / "provenance.json").read_text())
    assert recorded["run"]["device"] == "a CPU" and recorded["run"]["cores"] == 1
    cli.main(["figure", *common[:-2], "--runs-dir", str(records_dir), "--out-dir", str(tmp_path / "fig")])
    summary = json.loads((tmp_path / "fig" / "bc-tiny.json").read_text())
    assert len(summary["conditions"]["bc"]["final_returns"]) == 2


def test_run_with_cores_trains_seed_by_seed(tmp_path, monkeypatch):
    """Every condition of a seed before the next seed, so a sitting cut short leaves whole seeds; a failed
    process is an error naming it, after every process has ended."""
    started = []

    def fake_run(jobs, cores, xla_flags):
        assert xla_flags == ""  # not a design's seeds
        started.extend(job.label for job in jobs)
        return [1 if job.label == "social_rec s1" else 0 for job in jobs]

    monkeypatch.setattr(pinned, "run", fake_run)
    with pytest.raises(SystemExit, match="training failed for social_rec s1"):
        cli.main(
            ["run", "h1", "--scale", "tiny", "--seeds", "2", "--runs-dir", str(tmp_path), "--cores", "0"]
        )
    conditions = ["solo_pred", "social_none", "social_rec", "social_pred"]
    assert started == [f"{c} s{s}" for s in (0, 1) for c in conditions]


def test_max_runs_starts_only_the_first_runs_seed_by_seed(tmp_path, monkeypatch, capsys):
    """--max-runs N starts the first N pending runs in the seed-by-seed order and says how many wait; a
    later call starts from the rest (a finished run is not pending); N below 1 is refused at parsing."""
    started = []
    monkeypatch.setattr(
        pinned, "run", lambda jobs, cores, flags: started.append([j.label for j in jobs]) or [0] * len(jobs)
    )
    command = ["run", "h1", "--scale", "tiny", "--seeds", "2", "--runs-dir", str(tmp_path), "--cores", "0"]
    cli.main([*command, "--max-runs", "3"])
    assert started == [["solo_pred s0", "social_none s0", "social_rec s0"]]
    assert "starting 3 of 8 pending runs (--max-runs)" in capsys.readouterr().out
    cli.main([*command, "--max-runs", "8"])  # all of them: nothing said
    assert started[-1][-1] == "social_pred s1" and "--max-runs" not in capsys.readouterr().out
    for bad in ("0", "-2", "two"):
        with pytest.raises(SystemExit):
            cli.main([*command, "--max-runs", bad])
        assert "--max-runs" in capsys.readouterr().err


def test_a_designs_seeds_train_with_its_xla_flags(tmp_path, monkeypatch):
    """With --cores every process gets them after the single-core flags; in this process they must already
    be in $XLA_FLAGS (XLA reads them once), else nothing trains."""
    flags, read, given = "--xla_cpu_max_isa=AVX2", prereg.TrainingDesign.read, []
    with_flags = classmethod(lambda cls, name: dataclasses.replace(read(name), xla_flags=flags))
    monkeypatch.setattr(prereg.TrainingDesign, "read", with_flags)
    monkeypatch.setattr(
        pinned, "run", lambda jobs, cores, xla_flags: given.append(xla_flags) or [0] * len(jobs)
    )
    command = ["run", "h1_laptop", "--scale", "laptop", "--runs-dir", str(tmp_path), "--allow-dirty"]
    cli.main([*command, "--cores", "0"])
    assert given == [flags]
    monkeypatch.setenv("XLA_FLAGS", pinned.SINGLE_CORE_XLA_FLAGS)
    with pytest.raises(SystemExit, match=f"trains with \\$XLA_FLAGS ending in '{flags}': train with --cores"):
        cli.main(command)
    assert not any(tmp_path.iterdir())  # refused before anything trained


def test_seed_processes_share_the_compilation_cache(monkeypatch, tmp_path):
    """Every seed of a condition is one program: the processes share a persistent cache unless told
    another."""
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path))
    assert pinned.train_command(["--seed", "1"])[-2:] == ("--compile-cache", str(tmp_path))
    own = pinned.train_command(["--compile-cache", "elsewhere"])
    assert own == ("-m", "jaxsocial.train", "--compile-cache", "elsewhere")
