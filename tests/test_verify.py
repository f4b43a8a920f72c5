"""`experiments verify`: a record re-trained on the same machine and code equals its rows up to where a row
was changed, which it names; bad input is refused before anything trains; nothing is written into the
record."""

import dataclasses
import json
import shutil

import pytest

from jaxsocial import train
from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments import pinned, recipes, records, verify
from jaxsocial.run import logs


@pytest.fixture(scope="module")
def tiny_record(tmp_path_factory):
    """One seed of the tiny scale trained in this process (4 iterations): a run directory to verify."""
    runs_dir = tmp_path_factory.mktemp("verify")
    cfg = dataclasses.replace(recipes.TINY.config, runs_dir=str(runs_dir), run_name="record", seed=3)
    return train.run(cfg)


def test_first_difference_names_the_row_and_field():
    rows = [{"iteration": 1, "env_steps_per_s": 5.0, "loss/0": 0.5}, {"iteration": 2, "loss/0": 0.25}]
    faster = [dict(rows[0], env_steps_per_s=9.0), dict(rows[1])]
    assert verify.first_difference(rows, faster) is None  # timings are not compared
    changed = [dict(rows[0]), dict(rows[1], **{"loss/0": 0.3})]
    d = verify.first_difference(rows, changed)
    assert (d["iteration"], d["field"], d["record"], d["retrained"]) == (2, "loss/0", 0.25, 0.3)
    assert d["abs"] == pytest.approx(0.05) and d["rel"] == pytest.approx(0.05 / 0.3)
    missing = [dict(rows[0]), {"iteration": 2}]
    assert verify.first_difference(rows, missing)["field"] == "loss/0"
    assert verify.first_difference([{"x": float("nan")}], [{"x": float("nan")}]) is None


@pytest.mark.slow
def test_a_retrained_record_is_exact_up_to_a_changed_row(tiny_record, tmp_path, capsys):
    """The last row of a copy is changed: the re-training must equal every row before it bit for bit, and
    the report names the changed one."""
    record = tmp_path / "record"
    shutil.copytree(tiny_record, record)
    rows = [json.loads(line) for line in (record / logs.METRICS_FILE).read_text().splitlines()]
    field = next(k for k in rows[-1] if k.startswith("policy_loss"))
    rows[-1][field] += 1e-7
    (record / logs.METRICS_FILE).write_text("".join(json.dumps(r) + "\n" for r in rows))
    before = sorted(p.relative_to(record) for p in record.rglob("*"))
    cli.main(["verify", str(record), "--iterations", str(len(rows)), "--out", str(tmp_path / "v.json")])
    out = capsys.readouterr().out
    result = json.loads((tmp_path / "v.json").read_text())
    assert not result["exact"] and result["first_difference"]["iteration"] == len(rows)
    assert result["first_difference"]["field"] == field
    assert result["first_difference"]["abs"] == pytest.approx(1e-7, rel=1e-3)
    assert f"differs from iteration {len(rows)}, field {field}" in out and "CPU: record" in out
    assert sorted(p.relative_to(record) for p in record.rglob("*")) == before  # nothing written into it


def test_bad_input_is_refused_before_training(tiny_record, tmp_path):
    with pytest.raises(SystemExit, match="no config.json"):
        cli.main(["verify", str(tmp_path)])
    with pytest.raises(SystemExit, match="logged only 4 rows"):
        cli.main(["verify", str(tiny_record), "--iterations", "5"])
    taken = tmp_path / "taken.json"
    taken.write_text("{}")
    with pytest.raises(SystemExit, match="exists"):
        cli.main(["verify", str(tiny_record), "--out", str(taken)])
    with pytest.raises(SystemExit, match="inside the record"):
        cli.main(["verify", str(tiny_record), "--out", str(tiny_record / "v.json")])
    with pytest.raises(SystemExit):
        cli.main(["verify", str(tiny_record), "--iterations", "0"])
    assert taken.read_text() == "{}"


@pytest.mark.parametrize(
    ("run", "expected"),
    [
        ({"cores": 1, "xla_flags": "--xla_cpu_max_isa=AVX2"}, "--xla_cpu_max_isa=AVX2"),  # as recorded
        ({"cores": 1}, "--xla_cpu_multi_thread_eigen=false"),  # recorded before the flags were
        ({"cores": 2}, "--from-this-process"),
    ],
)
def test_the_retraining_has_the_records_xla_flags(tiny_record, tmp_path, monkeypatch, run, expected):
    record = tmp_path / "record"
    record.mkdir()
    shutil.copy(tiny_record / logs.CONFIG_FILE, record)
    (record / records.PROVENANCE_FILE).write_text(json.dumps({"run": run}))
    monkeypatch.setenv("XLA_FLAGS", "--from-this-process")
    seen = []
    monkeypatch.setattr(verify, "train_in_process", lambda cfg, work_dir, flags: seen.append(flags))
    verify.retrain(record, 2, tmp_path / "work")
    assert seen == [expected] == [verify.retraining_flags(record)]


def test_a_difference_without_the_cross_cpu_flags_points_to_them():
    result = {
        "record": "r",
        "iterations": 1,
        "exact": False,
        "rows": [1, 1],
        "first_difference": {"iteration": 1, "field": "kl/0", "record": 1.0, "retrained": 2.0},
        "cpu": {"record": "one CPU", "here": "another"},
        "environment": {"record": {}, "here": {}},
        "commit": {"record": "a", "here": "a"},
        "xla_flags": pinned.SINGLE_CORE_XLA_FLAGS,
        "compared": "every field",
    }
    said = verify.report(result)
    assert f"XLA flags (the record's): {pinned.SINGLE_CORE_XLA_FLAGS}" in said
    assert "platform-dependent math" in said and pinned.CROSS_CPU_XLA_FLAGS in said
    crossed = {**result, "xla_flags": f"{pinned.SINGLE_CORE_XLA_FLAGS} {pinned.CROSS_CPU_XLA_FLAGS}"}
    assert "platform-dependent" not in verify.report(crossed)
    assert "platform-dependent" not in verify.report({**result, "exact": True})


def test_environment_differences_name_what_differs_and_what_was_not_recorded():
    here = {"cpu_features": ["avx2", "fma"], "cache_sizes": {"L1d": "48K"}, "versions": {"jax": "0.10.2"}}
    same = verify.environment_differences(dict(here), here)
    assert same == []
    older = {"cpu_features": ["avx2", "fma"], "cache_sizes": {"L1d": "32K"}, "versions": None}
    lines = verify.environment_differences(older, here)
    assert lines == [
        "  cache_sizes differ: record {'L1d': '32K'}; here {'L1d': '48K'}",
        "  versions: not recorded; here {'jax': '0.10.2'}",
    ]
