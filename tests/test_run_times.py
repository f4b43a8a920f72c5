"""The pace of a design's committed records: minutes a run by CPU kind, and the cost line `run` prints from
them before training, on hand-written provenances with known times."""

from pathlib import Path

from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments.analyse import run_times
from jaxsocial.experiments.plan import paths
from jaxsocial.run import cpuinfo, jsonio

START = "2026-12-01T10:00:00+00:00"


def write_record(root: Path, name: str, minutes: int, **run) -> None:
    """A record whose process ran `minutes` from START, one core, rc 0, unless `run` says otherwise."""
    ended = f"2026-12-01T{10 + minutes // 60:02d}:{minutes % 60:02d}:00+00:00"
    fields = {"started": START, "ended": ended, "rc": 0, "cores": 1} | run
    (root / name).mkdir(parents=True)
    jsonio.write_json(root / name / "provenance.json", {"run": fields, "record": {}})


def test_minutes_by_cpu_keeps_whole_one_core_runs_that_ended_well(tmp_path):
    write_record(tmp_path, "a-s1-1", 10, cpu="Zen 5")
    write_record(tmp_path, "a-s2-2", 20, cpu="Zen 5")
    write_record(tmp_path, "b-s1-1", 30, cpu="Zen 3")
    write_record(tmp_path, "b-s2-2", 75, device="typed by hand, one core per seed")
    write_record(tmp_path, "c-s1-1", 5, cpu="Zen 5", cores=2)  # saw two cores
    write_record(tmp_path, "c-s2-2", 5, cpu="Zen 5", rc=1)  # failed
    write_record(tmp_path, "c-s3-3", 5, cpu="Zen 5", earlier=[{"started": START}])  # resumed
    write_record(tmp_path, "c-s4-4", 5, cpu="Zen 5", ended=None)  # no end written
    assert run_times.minutes_by_cpu(tmp_path) == {
        "Zen 5": [10.0, 20.0],
        "Zen 3": [30.0],
        "typed by hand, one core per seed": [75.0],
    }
    assert run_times.minutes_by_cpu(tmp_path / "none") == {}


def test_recorded_pace_totals_rounds_on_this_cpu_and_names_the_kinds_elsewhere(tmp_path):
    for k, minutes in enumerate((10, 20, 12)):
        write_record(tmp_path, f"a-s{k}-{k}", minutes, cpu="Zen 5")
    write_record(tmp_path, "a-s9-9", 45, cpu="Zen 3")
    line = run_times.recorded_pace(tmp_path, 5, 2, cpu="Zen 5")
    # 3 rounds of two (5 runs on 2 cores) at the median 12 minutes
    assert line.endswith(
        "took a median 12.0 min a run on this CPU (Zen 5: 3 runs, 10.0-20.0 min): about 36 min for 5 more, "
        "2 at a time"
    )
    assert line.startswith(f"the 4 runs recorded in {tmp_path} took")
    elsewhere = run_times.recorded_pace(tmp_path, 5, 2, cpu="Intel")
    assert elsewhere.endswith(
        "a median a run of Zen 5: 12.0 min (3 runs); Zen 3: 45.0 min (1 run); none trained on this CPU "
        "(Intel), whose pace may differ"
    )
    assert run_times.recorded_pace(tmp_path / "none", 5, 2) is None


def test_run_prints_the_pace_of_the_designs_records_for_the_runs_it_starts(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(paths, "RECORDS", tmp_path / "records")
    for k, minutes in enumerate((30, 40)):
        write_record(tmp_path / "records/laptop8/prereg-pred8", f"solo_pred-s{k}-{k}", minutes,
                     cpu=cpuinfo.model())  # fmt: skip
    cli.main(["run", "pred8", "--scale", "laptop8", "--runs-dir", str(tmp_path / "runs"), "--dry-run",
              "--cores", "0", "1", "--max-runs", "3"])  # fmt: skip
    # 3 runs on 2 cores: two rounds of the median 35 minutes
    assert "took a median 35.0 min a run on this CPU" in (out := capsys.readouterr().out)
    assert "about 70 min for 3 more, 2 at a time" in out
