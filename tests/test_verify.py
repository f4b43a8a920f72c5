"""`experiments verify`: a record re-trained on the same machine and code equals its rows up to where a row
was changed, which it names, in a process that sees as many cores as the record's did; bad input is refused
before anything trains; nothing is written into the record."""

import dataclasses
import json
import shutil

import jax
import pytest
from conftest import TINY

from jaxsocial import train
from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments.analyse import records
from jaxsocial.experiments.launch import pinned, verify
from jaxsocial.run import config, cpuinfo, provenance, rundir
from jaxsocial.run.flags import config_flags

TWO_CORES = len(provenance.visible_cores() or []) >= 2


@pytest.fixture(scope="module")
def tiny_record(tmp_path_factory):
    """TINY's seed 3 trained in this process (4 iterations; TINY's program, which the tiny-runs group
    compiles once): a run directory to verify."""
    runs_dir = tmp_path_factory.mktemp("verify")
    cfg = dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="record", seed=3)
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


def test_an_evaluation_at_the_retrainings_end_is_not_a_difference():
    """A run evaluates when it ends: a re-training cut short of the record evaluates where the record did
    not, and only that evaluation is set aside; every other field, and any earlier evaluation, is compared."""
    recorded = [{"iteration": 1, "loss/0": 0.5, "eval/goalcycle4": 1.0}, {"iteration": 2, "loss/0": 0.25}]
    retrained = [dict(recorded[0]), {"iteration": 2, "loss/0": 0.25, "eval/goalcycle4": 3.0}]
    assert verify.first_difference(recorded, verify.without_final_evaluation(retrained, recorded)) is None
    changed = [dict(recorded[0]), {"iteration": 2, "loss/0": 0.3, "eval/goalcycle4": 3.0}]
    assert (
        verify.first_difference(recorded, verify.without_final_evaluation(changed, recorded))["field"]
        == "loss/0"
    )
    earlier = [dict(recorded[0], **{"eval/goalcycle4": 2.0}), retrained[1]]
    d = verify.first_difference(recorded, verify.without_final_evaluation(earlier, recorded))
    assert (d["iteration"], d["field"]) == (1, "eval/goalcycle4")


@pytest.mark.slow
def test_a_retrained_record_is_exact_up_to_a_changed_row(tiny_record, tmp_path, capsys):
    """The last row of a copy is changed: the re-training must equal every row before it bit for bit, and
    the report names the changed one."""
    record = tmp_path / "record"
    shutil.copytree(tiny_record, record)
    rows = [json.loads(line) for line in (record / rundir.METRICS_FILE).read_text().splitlines()]
    field = next(k for k in rows[-1] if k.startswith("policy_loss"))
    rows[-1][field] += 1e-7
    (record / rundir.METRICS_FILE).write_text("".join(json.dumps(r) + "\n" for r in rows))
    before = sorted(p.relative_to(record) for p in record.rglob("*"))
    written = tmp_path / "new" / "v.json"  # its folder is made
    cli.main(["verify", str(record), "--iterations", str(len(rows)), "--out", str(written)])
    out = capsys.readouterr().out
    result = json.loads(written.read_text())
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
    with pytest.raises(SystemExit, match="cannot make its folder"):
        cli.main(["verify", str(tiny_record), "--out", str(taken / "v.json")])
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
    shutil.copy(tiny_record / rundir.CONFIG_FILE, record)
    (record / records.PROVENANCE_FILE).write_text(json.dumps({"run": run}))
    monkeypatch.setenv("XLA_FLAGS", "--from-this-process")
    seen = []
    monkeypatch.setattr(verify, "train_in_process", lambda cfg, work_dir, flags, cores: seen.append(flags))
    verify.retrain(record, 2, tmp_path / "work")
    assert seen == [expected] == [verify.retraining_flags(record)]


def test_a_difference_names_its_possible_causes_and_how_to_reproduce():
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
        "cores": {"record": 1, "here": 1},
    }
    said = verify.report(result)
    assert f"XLA flags (the record's): {pinned.SINGLE_CORE_XLA_FLAGS}" in said
    assert "platform-dependent math" in said and pinned.CROSS_CPU_XLA_FLAGS in said
    assert "cores seen: record 1 core; re-training 1 core" in said and "counts of cores differ" not in said
    assert said.splitlines()[-1] == (
        f"  bit for bit it re-trains from commit a, with $XLA_FLAGS '{pinned.SINGLE_CORE_XLA_FLAGS}', in a "
        "process that sees 1 core (verify pins itself so), on one CPU, with the same package versions"
    )
    crossed = {**result, "xla_flags": f"{pinned.SINGLE_CORE_XLA_FLAGS} {pinned.CROSS_CPU_XLA_FLAGS}"}
    assert "platform-dependent" not in verify.report(crossed)
    alike = {"expected": "exact expected", "says": "exact expected: they agree", "alike": ["a third CPU"]}
    said = verify.report({**crossed, "prediction": alike}).splitlines()
    assert said[0] == "prediction: exact expected: they agree" and said[1].startswith("r: first 1 iterations")
    assert said[-1].endswith(
        "on one CPU or a kind whose operation fingerprints agree with it under those flags (a third CPU), "
        "with the same package versions"
    )
    assert "platform-dependent" not in verify.report({**result, "exact": True})
    unpinned = {**result, "cores": {"record": 1, "here": 2}}
    assert "counts of cores differ that is expected" in verify.report(unpinned)
    assert "counts of cores" not in verify.report({**unpinned, "exact": True})


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


LONG_PRODUCTS = dataclasses.replace(
    TINY,
    num_envs=32,
    ppo=dataclasses.replace(TINY.ppo, minibatch_segments=64, num_minibatches=1),
    seed=0,
    seeds=1,
)
"""TINY with every sample of an iteration in one minibatch, so that the conv layers' weight gradients
contract over 32 x 8 samples' positions: products that long give other bits seeing two cores than one
(at TINY's 16 samples a minibatch they do not: docs/reproducibility.md, "Does the training re-run?")."""


@pytest.fixture(scope="module")
def one_core_record(tmp_path_factory):
    """`LONG_PRODUCTS` trained as the designs train (`pinned.run`, on this process's first core) and packed
    as a record with the provenance `pinned` wrote."""
    tmp = tmp_path_factory.mktemp("one_core")
    name = "tiny/pinned-s0-0"
    cfg = dataclasses.replace(LONG_PRODUCTS, runs_dir=str(tmp), run_name=name)
    fresh_cache = ["--compile-cache", str(tmp / "cache")]  # compiled seeing one core, as the designs' seeds
    job = pinned.Job("pinned", pinned.train_command([*config_flags(cfg), *fresh_cache]), tmp / name)
    assert pinned.run([job], provenance.visible_cores()[:1]) == [0]
    run = pinned.run_provenance(job.run_dir, "this CPU", jax.__version__)
    return records.pack(job.run_dir, tmp / "record", run, name)


@pytest.mark.slow
@pytest.mark.skipif(not TWO_CORES, reason="needs a process that sees two cores")
def test_a_one_core_record_is_exact_from_a_process_that_sees_two(one_core_record, tmp_path):
    """The record's provenance says its process saw one core; verify, seeing two, re-trains pinned to one and
    is exact. Re-trained seeing both cores (as verify did before), the same rows differ."""
    assert records.run_field(one_core_record, "visible_cores") == provenance.visible_cores()[:1]
    result = verify.verify(one_core_record, iterations=4)
    assert result["exact"] and result["cores"] == {"record": 1, "here": 1}
    assert "cores seen: record 1 core; re-training 1 core" in verify.report(result)
    cfg = config.config_from_dict(rundir.read_config(one_core_record))
    both = verify.train_in_process(cfg, tmp_path, verify.retraining_flags(one_core_record), cores=None)
    assert (
        verify.first_difference(rundir.read_metrics(one_core_record), rundir.read_metrics(both)) is not None
    )


@pytest.mark.parametrize(
    ("run", "cores"),
    [
        ({"visible_cores": [3], "cores": 1, "device": "2 cores"}, 1),  # as measured
        ({"visible_cores": [0, 1, 2]}, 3),
        ({"cores": 1, "device": "Intel Xeon, 2 cores, one core per seed"}, 1),  # the runner's rule, before
        ({"cores": None, "device": "AMD EPYC, 2 cores, one core per branch"}, 1),
        ({"device": "CPU (AMD EPYC, 2 cores)"}, 2),  # trained unpinned: every core of its machine
        ({"device": "an H100"}, None),
    ],
)
def test_the_cores_a_records_process_saw(tmp_path, monkeypatch, run, cores):
    (tmp_path / records.PROVENANCE_FILE).write_text(json.dumps({"run": run}))
    assert verify.record_cores(tmp_path) == cores
    monkeypatch.setattr(provenance, "visible_cores", lambda pid=0: [4, 5])
    assert verify.retraining_cores(cores) == ([4] if cores == 1 else None)  # 2 or 3: as many or more here


ZEN3, ZEN5 = "AMD EPYC (family 25, model 1)", "AMD EPYC (family 26, model 2)"
INTEL = "Intel(R) Xeon(R) Processor (family 6, model 167)"


def fingerprints(cpu: str, hashes: dict[str, str]) -> dict:
    flags = f"{pinned.SINGLE_CORE_XLA_FLAGS} {pinned.CROSS_CPU_XLA_FLAGS}"
    return {"cpu": cpu, "settings": {"cross": {"xla_flags": flags, "visible_cores": 1, "hashes": hashes}}}


@pytest.fixture
def predicted(tmp_path, monkeypatch):
    """`verify.prediction` of a record trained on a Zen 5 with the designs' flags, re-trained on an Intel
    kind whose fingerprints agree with it and beside a Zen 3 whose do not (hand-built files)."""
    kinds = [
        fingerprints(ZEN5, {"dot": "1", "init/params": "2"}),
        fingerprints(INTEL, {"dot": "1", "init/params": "2"}),
        fingerprints(ZEN3, {"dot": "x", "init/params": "2"}),
    ]
    monkeypatch.setattr(verify.cpu_kinds, "read_kinds", lambda where=None: kinds)
    monkeypatch.setattr(cpuinfo, "model", lambda: INTEL)
    flags = f"{pinned.SINGLE_CORE_XLA_FLAGS} {pinned.CROSS_CPU_XLA_FLAGS}"
    versions = provenance.environment()["versions"]

    def predict(cores=1, here=1, **run):
        run = {"cpu": ZEN5, "xla_flags": flags, "versions": versions, **run}
        (tmp_path / records.PROVENANCE_FILE).write_text(json.dumps({"run": run}))
        return verify.prediction(tmp_path, cores, here)

    return predict


def test_the_prediction_reads_the_kinds_files(predicted):
    said = predicted()
    assert said["expected"] == "exact expected" and said["alike"] == [INTEL]
    assert (
        said["says"]
        == f"exact expected: {ZEN5} (the record's) and {INTEL} (here) agree on all 2 fingerprints under cross"
    )
    said = predicted(cpu=ZEN3)
    assert said["expected"] == "expected to differ" and said["alike"] == []
    assert said["says"].endswith("differ in 1 of 2 fingerprints under cross (1 of 1 operations), first dot")
    said = predicted(cpu="AMD EPYC (family 25, model 17), 2 cores, AVX512-BF16, no AMX")  # no file
    assert said["says"].startswith("no fingerprint file for AMD EPYC (family 25, model 17), 2 cores")
    assert said["expected"] == "unknown" and said["says"].endswith(": unknown")
    assert predicted(cpu=None, device=f"{INTEL}, one core per seed")["says"].startswith("exact expected: the")


def test_the_prediction_weighs_the_cores_and_the_versions_first(predicted):
    said = predicted(cores=2, here=1)
    assert said["expected"] == "expected to differ"
    assert (
        said["says"] == "expected to differ, because its process saw 2 cores and the re-training sees 1 core"
    )
    assert predicted(cores=None)["says"] == "the record does not say how many cores its process saw: unknown"
    said = predicted(versions={**provenance.environment()["versions"], "jaxlib": "0.0.1"})
    assert said["expected"] == "unknown" and said["says"].startswith(
        "package versions differ (jaxlib: record 0.0.1, here "
    )


def test_verify_says_its_prediction_before_it_trains_and_reports_it_first(
    tiny_record, tmp_path, monkeypatch, capsys
):
    """The re-training replaced by the record itself (equal rows): the prediction is printed before
    `retrain` is called, is in the result, and is the report's first line. The record is a plain run
    (`train.run` in this process): its process file holds what a record's provenance would."""
    printed = []

    def retrain(record_dir, iterations, work_dir):
        printed.append(capsys.readouterr().out)
        return tiny_record

    monkeypatch.setattr(verify, "retrain", retrain)
    result = verify.verify(tiny_record, iterations=4)
    assert result["exact"] and result["cpu"]["record"] == cpuinfo.model()  # from its process file
    assert "not recorded" not in verify.report(result)  # a plain run says what a record says (issue 84)
    assert printed == [f"prediction: {result['prediction']['says']}\n"]
    assert verify.report(result).splitlines()[0] == f"prediction: {result['prediction']['says']}"
