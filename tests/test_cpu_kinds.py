"""`cpu_kinds` (issue 85): which CPU kinds agree is derived from the committed operation fingerprints, and
what the repository says of them is checked against the files: the kinds `pinned.CROSS_CPU_KINDS` says the
cross-CPU flags make agree, the tables docs/reproducibility.md quotes, and the committed `verify` reports,
which must have come out as the files predict. The prediction itself on hand-built fingerprint files."""

import itertools
import sys
from pathlib import Path

import pytest
from doc_sections import sections

from jaxsocial.experiments.analyse import cpu_kinds
from jaxsocial.experiments.launch import pinned
from jaxsocial.run import jsonio, metrics

REPO = Path(__file__).resolve().parents[1]
FINGERPRINTS = REPO / "benchmarks/results/op_fingerprints"
VERIFIED = sorted((REPO / "benchmarks/results/reproducibility").glob("verify-*/*.json"))
CROSS_CPU = f"{pinned.SINGLE_CORE_XLA_FLAGS} {pinned.CROSS_CPU_XLA_FLAGS}"
SECTION = "Does the training re-run? `verify`, and what is reproducible where"
sys.path.append(str(REPO / "benchmarks"))  # the script, its `reproducibility` and `run_info`
import op_fingerprints  # noqa: E402


@pytest.fixture(scope="module")
def kinds():
    found = cpu_kinds.read_kinds(FINGERPRINTS)
    assert len(found) >= 4  # Zen 3, Zen 4, Zen 5, Intel
    return found


def test_each_kind_file_is_named_by_its_cpu_and_no_kind_has_two(kinds):
    names = sorted(path.name for path in FINGERPRINTS.glob("*.json"))
    assert names == sorted(cpu_kinds.file_name(kind["cpu"]) for kind in kinds)
    keys = [cpu_kinds.kind_key(kind["cpu"]) for kind in kinds]
    assert None not in keys and len(set(keys)) == len(keys)


def test_the_cross_cpu_kinds_are_exactly_those_the_files_show_agreeing(kinds):
    """`pinned.CROSS_CPU_KINDS` may claim only what the files show: each has a file that measured the designs'
    flags, every pair of them agrees on every fingerprint, and no other kind measured under the flags agrees
    with them (the claim is neither more nor less than the files')."""
    claimed = [cpu_kinds.kind_for_cpu(kinds, cpu) for cpu in pinned.CROSS_CPU_KINDS]
    assert None not in claimed, "a kind of pinned.CROSS_CPU_KINDS has no fingerprint file"
    for kind in claimed:
        assert cpu_kinds.setting_of(kind, CROSS_CPU) is not None, (
            f"{kind['cpu']}: not measured under the flags"
        )
    for a, b in itertools.combinations(claimed, 2):
        assert cpu_kinds.agree(a, b, CROSS_CPU), f"{a['cpu']} and {b['cpu']} differ under {CROSS_CPU}"
    for other in (k for k in kinds if k["cpu"] not in pinned.CROSS_CPU_KINDS):
        for kind in claimed:
            assert cpu_kinds.agree(other, kind, CROSS_CPU) is not True, (
                f"{other['cpu']} agrees with {kind['cpu']}"
            )
    for cpu in pinned.CROSS_CPU_KINDS:
        assert sorted(cpu_kinds.alike(kinds, cpu, CROSS_CPU)) == sorted(set(pinned.CROSS_CPU_KINDS) - {cpu})


def test_the_docs_quote_the_tables_the_files_give():
    """docs/reproducibility.md's section on re-training holds `op_fingerprints.py --compare`'s output as it is
    now: a kind file added or changed without the docs fails here."""
    text = dict(sections(REPO / "docs/reproducibility.md"))[SECTION]
    tables = op_fingerprints.compared(FINGERPRINTS)
    assert tables == cpu_kinds.markdown(cpu_kinds.read_kinds(FINGERPRINTS), CROSS_CPU)
    assert tables in text, "docs/reproducibility.md: paste `python benchmarks/op_fingerprints.py --compare`"


def _exact(report: dict) -> bool:
    """Whether a committed `verify` report found the rows equal, setting aside an evaluation the
    re-training made at its own end where the record made none (as `verify.without_final_evaluation`)."""
    d = report["first_difference"]
    final_evaluation = (
        d is not None
        and d["iteration"] == report["iterations"]
        and metrics.is_eval_key(d["field"])
        and d["record"] is None
    )
    return report["rows"][0] == report["rows"][1] and (d is None or final_evaluation)


@pytest.mark.parametrize("path", VERIFIED, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_the_committed_verify_reports_came_out_as_the_files_predict(path, kinds):
    report = jsonio.read_json(path)
    cpu, flags, cores = report["cpu"], report["xla_flags"], report["cores"]["record"]
    expected = cpu_kinds.predict(cpu["record"], cpu["here"], flags, cores, kinds)["expected"]
    assert expected == (cpu_kinds.EXACT if _exact(report) else cpu_kinds.DIFFER), expected


# ---------------------------------------------------------------------------------------------------------
# The prediction on hand-built files
# ---------------------------------------------------------------------------------------------------------

FLAGS = "--single --cross"


def kind(cpu: str, hashes: dict[str, str], cores: int | None = 1, flags: str = FLAGS) -> dict:
    return {"cpu": cpu, "settings": {"cross": {"xla_flags": flags, "visible_cores": cores, "hashes": hashes}}}


SAME = {"dot": "1", "rsqrt": "2", "init/params": "3"}
A = kind("AMD EPYC (family 26, model 2)", SAME)
B = kind("Intel(R) Xeon(R) Processor (family 6, model 167)", dict(SAME))
C = kind("AMD EPYC (family 25, model 1)", {"init/params": "x", "dot": "1", "rsqrt": "y"})
D = kind("AMD EPYC (family 25, model 17)", {"dot": "1", "rsqrt": "2", "init/params": "z"})


def test_kinds_are_found_by_vendor_family_and_model():
    assert cpu_kinds.kind_key(
        "Intel Xeon (family 6, model 167, AVX512 + AMX), 2 cores, one core per seed"
    ) == (
        "intel",
        6,
        167,
    )
    assert cpu_kinds.kind_for_cpu([A, B, C], "AMD EPYC (family 25, model 1, Zen 3), 2 cores") is C
    assert cpu_kinds.kind_for_cpu([A, B, C], "CPU (AMD EPYC, 2 cores)") is None
    assert cpu_kinds.file_name("Intel(R) Xeon(R) Processor (family 6, model 167)") == (
        "intel-r-xeon-r-processor-family-6-model-167.json"
    )


def test_compare_names_the_first_differing_operation_before_the_states_leaves():
    found = cpu_kinds.compare(A, C, "cross")
    assert found["differ"] == ["rsqrt", "init/params"] and found["operations_differ"] == ["rsqrt"]
    assert found["first"] == "rsqrt" and (found["fingerprints"], found["operations"]) == (3, 2)
    assert cpu_kinds.compare(A, D, "cross")["first"] == "init/params"  # no operation differs: the state's
    assert cpu_kinds.compare(A, B, "cross")["first"] is None


def test_agreeing_kinds_are_expected_exact_and_differing_ones_to_differ():
    said = cpu_kinds.predict(A["cpu"], B["cpu"], FLAGS, 1, [A, B, C])
    assert said["expected"] == cpu_kinds.EXACT
    assert said["says"].startswith("exact expected: AMD EPYC (family 26, model 2) (the record's) and Intel")
    assert "agree on all 3 fingerprints under cross" in said["says"] and "cores" not in said["says"]
    said = cpu_kinds.predict(C["cpu"], A["cpu"], FLAGS, 1, [A, B, C])
    assert said["expected"] == cpu_kinds.DIFFER
    assert said["says"].startswith("expected to differ, because AMD EPYC (family 25, model 1) (the record's)")
    assert said["says"].endswith("differ in 2 of 3 fingerprints under cross (1 of 2 operations), first rsqrt")
    assert cpu_kinds.alike([A, B, C], A["cpu"], FLAGS) == [B["cpu"]]
    assert cpu_kinds.alike([A, B, C], C["cpu"], FLAGS) == []


def test_the_same_kind_is_expected_exact_without_any_file():
    said = cpu_kinds.predict("AMD EPYC (family 25, model 1), one core per seed", C["cpu"], "--other", 1, [])
    assert said["expected"] == cpu_kinds.EXACT and "this CPU kind" in said["says"]


def test_what_the_files_do_not_say_is_unknown():
    said = cpu_kinds.predict("AMD EPYC (family 25, model 17)", A["cpu"], FLAGS, 1, [A, B])
    assert said["expected"] == cpu_kinds.UNKNOWN
    assert said["says"].startswith("no fingerprint file for AMD EPYC (family 25, model 17)")
    assert said["says"].endswith(": unknown")
    said = cpu_kinds.predict(A["cpu"], B["cpu"], "--single", 1, [A, B])  # not measured under these flags
    assert said["expected"] == cpu_kinds.UNKNOWN and "under the record's XLA flags '--single'" in said["says"]
    said = cpu_kinds.predict("CPU (AMD EPYC, 2 cores)", A["cpu"], FLAGS, 1, [A, B])
    assert said["expected"] == cpu_kinds.UNKNOWN and "no CPU family and model" in said["says"]
    flagged = kind(B["cpu"], dict(SAME), flags="--single  --cross")  # the words count, not the spaces
    assert cpu_kinds.predict(A["cpu"], B["cpu"], FLAGS, 1, [A, flagged])["expected"] == cpu_kinds.EXACT


def test_files_measured_seeing_other_cores_than_the_record_say_so():
    unrecorded = kind(B["cpu"], dict(SAME), cores=None)
    said = cpu_kinds.predict(A["cpu"], B["cpu"], FLAGS, 1, [A, unrecorded])["says"]
    assert said.endswith(
        "cores seen by the files' processes: 1 and not recorded, by the record's: 1 (some "
        "products' bits depend on them)"
    )


def test_the_tables_name_what_was_not_measured():
    other = {"cpu": D["cpu"], "settings": {"default": {"xla_flags": "--single", "hashes": SAME}}}
    text = cpu_kinds.markdown([A, C, other], FLAGS)
    assert (
        "| AMD EPYC (family 26, model 2) / AMD EPYC (family 25, model 1) | no | 1 of 2 | 2 of 3 | `rsqrt` |"
        in text
    )
    assert "/ AMD EPYC (family 25, model 17) | not measured on AMD EPYC (family 25, model 17) |" in text
    pair = "| AMD EPYC (family 26, model 2) / AMD EPYC (family 25, model 1) |"
    assert f"{pair} `cross` | 1 of 2 | 2 of 3 | `rsqrt` |" in text
