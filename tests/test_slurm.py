"""A design's seeds as Slurm jobs through submitit (`launch.slurm`): the options checked before anything is
submitted, a dry run that submits nothing, and, through submitit's local executor (no Slurm needed), a seed
whose run directory, process file and record are a local run's."""

import contextlib
import io
import json
import shlex
import sys
import types
from pathlib import Path

import pytest
from conftest import metrics_without_speed, needs_records

from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments import kind_commands
from jaxsocial.experiments.launch import pinned, slurm
from jaxsocial.run import provenance

RUN = ["run", "bc", "--scale", "tiny"]


def _config(path: Path, text: str) -> str:
    path.write_text(text)
    return str(path)


def _local_cluster(tmp_path: Path) -> str:
    """A --slurm-config that runs the jobs with submitit's local executor, its files under tmp_path."""
    return _config(
        tmp_path / "slurm.toml", f'cluster = "local"\ntime = "10"\nfolder = "{tmp_path / "submitit"}"\n'
    )


class FakeSubmitit:
    """submitit, as far as `Slurm.run` uses it: each job runs its function in this process when its result is
    asked for, and every executor and job is kept."""

    def __init__(self):
        self.executors, self.jobs = [], []
        self.helpers = types.SimpleNamespace(as_completed=lambda jobs, poll_frequency: iter(jobs))
        self.core = types.SimpleNamespace(utils=types.SimpleNamespace(UncompletedJobError=RuntimeError))

    def AutoExecutor(self, folder, cluster):  # noqa: N802 (submitit's name)
        fake = self

        class Executor:
            def __init__(self):
                self.folder, self.cluster, self.parameters = folder, cluster, None
                fake.executors.append(self)

            def update_parameters(self, **parameters):
                self.parameters = parameters

            batch = contextlib.nullcontext

            def submit(self, fn, *args):
                job = types.SimpleNamespace(job_id=f"{700 + len(fake.jobs)}", result=lambda: fn(*args))
                fake.jobs.append(job)
                return job

        return Executor()


@pytest.fixture
def fake_submitit(monkeypatch):
    fake = FakeSubmitit()
    monkeypatch.setattr(slurm, "submitit_module", lambda: fake)
    monkeypatch.setattr(pinned, "POLL_SECONDS", 0.05)
    return fake


def _job(tmp_path: Path, name: str, code: str) -> pinned.Job:
    """A job whose process makes its run directory (a config.json), then runs `code`."""
    run_dir = tmp_path / name
    make = (
        f"import pathlib; d = pathlib.Path({str(run_dir)!r}); d.mkdir(); (d / 'config.json').write_text('1')"
    )
    return pinned.Job(name, ("-c", f"{make}; {code}"), run_dir)


def test_each_job_runs_its_process_on_one_cpu_with_the_local_runs_process_file(tmp_path, fake_submitit):
    """`run_in_job` starts the job's command as `pinned.run` does, so the process file is a local run's: the
    command, one core, the single-core then the design's XLA flags (worked out where it was submitted)."""
    jobs = [_job(tmp_path, "ok", "pass"), _job(tmp_path, "fails", "import sys; sys.exit(3)")]
    launcher = slurm.Slurm(time_min=30, partition="cpu", cluster="local")
    assert launcher.run(jobs, "--xla_cpu_max_isa=AVX2") == [0, 3]
    (executor,) = fake_submitit.executors
    assert executor.cluster == "local" and executor.folder == slurm.DEFAULT_FOLDER
    assert executor.parameters["cpus_per_task"] == 1 and executor.parameters["timeout_min"] == 30
    assert executor.parameters["slurm_partition"] == "cpu"
    info = json.loads((tmp_path / "ok" / provenance.RUN_FILE).read_text())
    assert info["command"] == shlex.join(["python", *jobs[0].argv]) and info["cores"] == 1
    assert info["xla_flags"] == pinned.process_xla_flags("--xla_cpu_max_isa=AVX2") and info["rc"] == 0
    assert len(info["visible_cores"]) == 1 or not pinned.pin([0])  # pinned where there is taskset
    assert json.loads(slurm.marker(jobs[1]).read_text())["job_id"] == "701"  # which job trained it


def test_no_wait_submits_and_a_queued_run_is_not_submitted_again(
    tmp_path, fake_submitit, monkeypatch, capsys
):
    """--no-wait returns once the jobs are submitted (no exit codes); a later call submits nothing for a run
    whose job `squeue` still lists."""
    jobs = [_job(tmp_path, "a", "pass"), _job(tmp_path, "b", "pass")]
    assert slurm.Slurm(time_min=5, cluster="local", wait=False).run(jobs, "") == [None, None]
    out = capsys.readouterr().out
    assert "a: Slurm job 700" in out and "squeue -j 700,701" in out and "scancel 700 701" in out
    assert not (tmp_path / "a").exists()  # nothing waited for: the fake's jobs never ran
    monkeypatch.setattr(slurm.shutil, "which", lambda tool: f"/usr/bin/{tool}")
    squeue = types.SimpleNamespace(returncode=0, stdout="12\n701\n", stderr="")
    monkeypatch.setattr(slurm.subprocess, "run", lambda *args, **kwargs: squeue)
    assert slurm.Slurm(time_min=5, wait=False).run(jobs, "") == [None, None]
    assert "b: still queued or running as Slurm job 701; not submitted" in capsys.readouterr().out
    assert [job.job_id for job in fake_submitit.jobs] == ["700", "701", "702"]  # only a's resubmitted


def test_a_dry_run_shows_the_jobs_and_submits_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(slurm, "submitit_module", lambda: pytest.fail("a dry run needs no submitit"))
    folder = tmp_path / "submitit"
    config = _config(tmp_path / "s.json", f'{{"time": "2:00:00", "account": "lab", "folder": "{folder}"}}')
    runs = tmp_path / "runs"
    options = ["--launcher", "slurm", "--slurm-config", config, "--slurm-partition", "cpu", "--dry-run"]
    cli.main(
        [
            *RUN,
            "--seeds",
            "3",
            "--runs-dir",
            str(runs),
            *options,
            "--slurm-param",
            "mem=2G",
            "--max-runs",
            "2",
        ]
    )
    out = capsys.readouterr().out
    assert "would submit 2 job(s) to Slurm (nothing submitted: --dry-run)" in out
    assert "timeout_min=120, cpus_per_task=1" in out and "slurm_partition='cpu', slurm_account='lab'" in out
    assert "slurm_additional_parameters={'mem': '2G'}" in out
    assert f"XLA_FLAGS={pinned.process_xla_flags()!r}" in out
    command = "bc s1: python -m jaxsocial.train --preset small"
    assert command in out and f"--run-name tiny/bc-s1-1 --runs-dir {runs} --compile-cache" in out
    assert "bc s2:" not in out.split("would submit")[1]  # --max-runs 2
    assert f"submitit's files in {folder}" in out and not folder.exists() and not runs.exists()


@needs_records("records/laptop/prereg-experts")  # the branches' sources
def test_a_branch_designs_run_takes_the_slurm_launcher(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        kind_commands.branch_main(
            ["run", "mixing", "--runs-dir", str(tmp_path), "--max-runs", "2", "--dry-run"]
            + ["--launcher", "slurm", "--slurm-time", "90"]
        )
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "would submit 2 job(s) to Slurm" in out and "timeout_min=90, cpus_per_task=1" in out
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("options", "config", "message"),
    [
        (["--slurm-time", "ten"], None, "--slurm-time 'ten': not a Slurm time limit"),
        (["--slurm-time", "0:00"], None, "--slurm-time '0:00': a time limit must be above zero"),
        ([], None, "give a time limit a job, --slurm-time"),
        (["--slurm-time", "9"], ("s.toml", 'partion = "cpu"'), "unknown option(s) ['partion']"),
        ([], ("s.toml", "time = [1]"), "'time' = [1]: not a Slurm time limit"),
        ([], ("s.toml", "time = 5\ncluster = 'pbs'"), "'cluster' = 'pbs': one of slurm, local"),
        ([], ("s.yaml", "time: 5"), "give a .json or .toml file"),
        ([], ("s.json", "{time: 5}"), "--slurm-config"),
        (
            [],
            ("s.json", '{"time": 5, "additional_parameters": {"cpus-per-task": 4}}'),
            "'cpus-per-task': not",
        ),
        (
            ["--slurm-time", "9", "--slurm-param", "nodes=2"],
            None,
            "--slurm-param 'nodes': not an extra option",
        ),
        (
            ["--slurm-time", "9", "--slurm-partition", "a b"],
            None,
            "--slurm-partition 'a b': not a Slurm name",
        ),
        (["--slurm-time", "9", "--cores", "0"], None, "--cores: the local launcher's"),
    ],
)
def test_a_bad_slurm_option_is_refused_before_submitting(tmp_path, monkeypatch, options, config, message):
    monkeypatch.setattr(slurm, "submitit_module", lambda: pytest.fail("got as far as submitting"))
    if config is not None:
        options = [*options, "--slurm-config", _config(tmp_path / config[0], config[1])]
    runs = tmp_path / "runs"
    with pytest.raises(SystemExit) as exc:
        cli.main([*RUN, "--runs-dir", str(runs), "--launcher", "slurm", *options])
    assert str(exc.value).startswith("error: ") and message in str(exc.value), exc.value
    assert not runs.exists()


def test_slurm_options_need_the_slurm_launcher(tmp_path):
    with pytest.raises(
        SystemExit, match="--slurm-partition, --no-wait: the Slurm launcher's; add --launcher slurm"
    ):
        cli.main([*RUN, "--runs-dir", str(tmp_path), "--slurm-partition", "cpu", "--no-wait", "--cores", "0"])
    assert not any(tmp_path.iterdir())


def test_flags_override_the_config_file_and_times_are_slurms(tmp_path):
    config = _config(
        tmp_path / "s.toml",
        'partition = "a"\ntime = 10\nsetup = ["module load python"]\n'
        '[additional_parameters]\nmem = "1G"\nqos = "short"\n',
    )
    given = {"partition": "b", "time": None, "additional_parameters": {"mem": "2G"}}
    launcher = slurm.options(config, given)
    assert launcher.partition == "b" and launcher.time_min == 10 and launcher.setup == ("module load python",)
    assert launcher.additional_parameters == {"mem": "2G", "qos": "short"}
    times = {"90": 90, "1:30": 2, "1:30:00": 90, "2-0": 2880, "1-02:03:04": 1564, "0:00:01": 1}
    assert {text: slurm.slurm_minutes(text, "t") for text in times} == times


def test_the_launcher_is_chosen_in_one_place(tmp_path):
    def chosen(argv, **kwargs):
        args = cli.parse_args([*RUN, "--runs-dir", str(tmp_path), *argv])
        return slurm.chosen(args, **kwargs)

    assert chosen([]) is None  # in this process, as before
    assert chosen(["--cores", "0", "1"]) == pinned.Cores((0, 1))
    assert chosen([], default_cores=(0,)) == pinned.Cores((0,))  # a branch design's default
    launcher = chosen(["--launcher", "slurm", "--slurm-time", "5", "--dry-run", "--no-wait"])
    assert launcher == slurm.Slurm(time_min=5, wait=False)


def test_without_submitit_the_error_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "submitit", None)  # `import submitit` raises ImportError
    with pytest.raises(
        SystemExit, match=r"submitit, which is not installed: pip install 'jaxsocial\[slurm\]'"
    ):
        cli.main([*RUN, "--runs-dir", str(tmp_path), "--launcher", "slurm", "--slurm-time", "5"])
    assert not any(tmp_path.iterdir())


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Seed 0 of the tiny `bc` recipe trained twice: as a Slurm job through submitit's local executor, and
    by the local launcher (`--cores 0`); the runs directories and what the first call printed."""
    root = tmp_path_factory.mktemp("slurm")
    config, out = _local_cluster(root), io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(out):
        mp.setattr(slurm, "POLL_SECONDS", 0.5)
        mp.setattr(pinned, "POLL_SECONDS", 0.2)
        cli.main(
            [
                *RUN,
                "--seeds",
                "1",
                "--runs-dir",
                str(root / "slurm-runs"),
                "--launcher",
                "slurm",
                "--slurm-config",
                config,
            ]
        )
        cli.main([*RUN, "--seeds", "1", "--runs-dir", str(root / "local-runs"), "--cores", "0"])
    return types.SimpleNamespace(root=root, config=config, out=out.getvalue())


@pytest.mark.slow
def test_a_seed_trained_as_a_slurm_job_is_a_local_runs_seed(trained):
    """Same command, one CPU, the same flags: the metrics rows are the local run's (timings aside), and the
    job wrote the process file a local run has."""
    slurm_run, local_run = (
        trained.root / f"{where}-runs" / "tiny" / "bc-s0-0" for where in ("slurm", "local")
    )
    assert "bc: Slurm job " in trained.out and "bc: exit 0 (Slurm job " in trained.out
    rows = metrics_without_speed(slurm_run)
    assert len(rows) == 4 and rows == metrics_without_speed(local_run)
    mine, local = (json.loads((run / provenance.RUN_FILE).read_text()) for run in (slurm_run, local_run))
    assert mine["rc"] == 0 and mine["ended"] is not None and mine["cores"] == 1
    assert mine["command"] == local["command"].replace("local-runs", "slurm-runs")
    assert sorted(mine) == sorted(local) and mine["xla_flags"] == local["xla_flags"]
    assert (slurm_run.parent / "bc-s0-0.log").is_file() and slurm.marker(
        pinned.Job("", (), slurm_run)
    ).is_file()


@pytest.mark.slow
def test_record_packs_a_slurm_jobs_run_as_a_local_one(trained):
    provenances = []
    for where in ("slurm", "local"):
        out_dir = trained.root / f"{where}-records"
        runs = ["--seeds", "1", "--runs-dir", str(trained.root / f"{where}-runs")]
        cli.main(["record", *RUN[1:], *runs, "--out-dir", str(out_dir), "--allow-dirty"])  # a dirty tree too
        provenances.append(json.loads((out_dir / "tiny" / "bc-s0-0" / "provenance.json").read_text())["run"])
    mine, local = provenances
    assert sorted(mine) == sorted(local) and mine["device"] == local["device"] and mine["cores"] == 1
    assert mine["device"].endswith(", one core per seed")


@pytest.mark.slow
def test_a_second_call_submits_nothing_for_a_finished_seed(trained, capsys):
    folder = trained.root / "submitit"
    before = sorted(folder.iterdir())
    cli.main(
        [
            *RUN,
            "--seeds",
            "1",
            "--runs-dir",
            str(trained.root / "slurm-runs"),
            "--launcher",
            "slurm",
            "--slurm-config",
            trained.config,
        ]
    )
    out = capsys.readouterr().out
    assert "[bc/tiny] bc: finished" in out and "Slurm job" not in out
    assert sorted(folder.iterdir()) == before
