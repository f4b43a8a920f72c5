"""Every decimal that README.md and docs/*.md quote in a section that declares its sources is in one of them.

A section (from a heading to the next heading) declares where its numbers come from with a comment line
`<!-- numbers: PATH [PATH ...] -->`, paths from the repository root (globs allowed). Every decimal in its
prose and tables (12.5, -1.5, 0.10, 4.75M, 82.5%, x3.37; code is skipped) must equal, at its printed precision
and scaled by its suffix (k, M, G, %), some number in those files: a value, or a number written inside a
string value (a summary's flags). Sections without a declaration are not checked; `DECLARED` lists the
sections that must have one.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from conftest import needs_records
from doc_sections import sections

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]

DECLARED = {
    ("README.md", "jaxsocial"),
    ("README.md", "The headline result"),
    ("README.md", "Social learning on a laptop"),
    ("README.md", "The paper, finding by finding"),
    ("docs/experiments.md", "The sample-efficiency sweep (exploratory)"),
    ("docs/experiments.md", "Results"),
    (
        "docs/experiments.md",
        "`pred8`: do more learners with the prediction loss learn within 20.0M env-steps beside the experts? "
        "(pre-registered; holds)",
    ),
    ("docs/experiments.md", "`transfer`: H2 in Four Rooms and Maze (pre-registered; not significant)"),
    (
        "docs/experiments.md",
        "`transfer8`: H2 from the learners that needed the experts (pre-registered; holds)",
    ),
    (
        "docs/experiments.md",
        "`nopenalty8`: without the penalty, do solo learners leave the low-return regime? "
        "(pre-registered; holds as tested)",
    ),
    (
        "docs/experiments.md",
        "`mixing`: does mixing solo episodes in keep the solo skill? "
        "(pre-registered; holds against all-social)",
    ),
    ("docs/experiments.md", "The GPU scale: social learning appears in some seeds *(no records)*"),
    ("docs/experiments.md", "Pre-registration"),
    (
        "docs/experiments.md",
        "Beyond the paper: cultural-transmission ingredients at the CPU scale *(no records)*",
    ),  # noqa: E501
    ("docs/performance.md", "The KL early stop"),
    ("docs/performance.md", "GPU (one H100)"),
}
"""(file, heading) of the sections whose numbers must be checked: the results the project reports."""

SOURCES = re.compile(r"^<!--\s*numbers:\s*(.*?)\s*-->", re.S | re.M)
CODE = re.compile(r"```.*?```|`[^`\n]*`", re.S)
DECIMAL = re.compile(
    r"(?<![A-Za-wyz\d_.\-])((?:-?\d{1,3}(?:,\d{3})*\.\d+|-?\d+\.\d+)(?:e-?\d+)?)([kMG%]?)(?![\w.]\d|\d)"
)
SCALE = {"": 1.0, "k": 1e3, "M": 1e6, "G": 1e9, "%": 0.01}
NUMBER_IN_TEXT = re.compile(r"(-?\d+(?:\.\d+)?(?:e-?\d+)?)([kMG%]?)")


def numbers(x) -> list[float]:
    """Every number in a JSON value, including those written inside its strings (with their k/M/G/%)."""
    if isinstance(x, dict):
        return [v for item in x.values() for v in numbers(item)]
    if isinstance(x, list):
        return [v for item in x for v in numbers(item)]
    if isinstance(x, bool) or x is None:
        return []
    if isinstance(x, int | float):
        return [float(x)]
    return [float(n) * SCALE[suffix] for n, suffix in NUMBER_IN_TEXT.findall(str(x))]


def quoted(text: str) -> list[tuple[str, str]]:
    """(number as written, suffix) of every decimal in prose and tables (code blocks and spans skipped)."""
    return DECIMAL.findall(CODE.sub(" ", SOURCES.sub(" ", text)))


def found(written: str, suffix: str, values: list[float]) -> bool:
    """Whether some value, rounded to the decimals written (after the suffix's scale; 7.6e-7 to 8 decimals),
    is the number."""
    mantissa, _, exponent = written.partition("e")
    digits = len(mantissa.split(".")[1]) - int(exponent or 0)
    number = float(written.replace(",", ""))
    return any(round(v / SCALE[suffix], digits) in (number, -number) for v in values)


def declared_sections() -> list[tuple[str, str, list[Path], str]]:
    out = []
    for path in DOCS:
        for heading, text in sections(path):
            for declaration in SOURCES.findall(text):
                files = [f for pattern in declaration.split() for f in sorted(REPO.glob(pattern))]
                out.append((str(path.relative_to(REPO)), heading, files, text))
    return out


def test_the_reported_results_declare_their_sources():
    declared = {(doc, heading) for doc, heading, _, _ in declared_sections()}
    undeclared = sorted(DECLARED - declared)
    assert not undeclared, f"sections without a <!-- numbers: ... --> line: {undeclared}"


def records_read(text: str) -> list[str]:
    """The folders of benchmarks/results/records/ and inflight/ that a section's declared sources lie in, up
    to the first glob: a code-only clone has none of them."""
    out = []
    for pattern in (p for declaration in SOURCES.findall(text) for p in declaration.split()):
        parts = Path(pattern).parts
        if parts[:2] == ("benchmarks", "results") and parts[2] in ("records", "inflight"):
            folder = []
            for part in parts[2:-1]:
                if "*" in part:
                    break
                folder.append(part)
            out.append("/".join(folder))
    return out


@pytest.mark.parametrize(
    "doc, heading, files, text",
    [pytest.param(*s, marks=needs_records(*records_read(s[3]))) for s in declared_sections()],
    ids=lambda x: str(x)[:40],
)
def test_every_quoted_decimal_is_in_a_declared_source(doc, heading, files, text):
    assert files, f"{doc} '{heading}': its declared sources match no file"
    values = [v for f in files for v in numbers(json.loads(f.read_text()))]
    missing = [w + s for w, s in quoted(text) if not found(w, s, values)]
    assert not missing, f"{doc} '{heading}' quotes numbers in none of {[f.name for f in files]}: {missing}"


def test_the_walker_reads_what_it_should():
    """The walker itself: suffixes scale, exponents count, code is skipped, versions and names are not
    decimals."""
    text = "p = 0.10, 4.75M steps, x3.37, 82.5%, -1.5, 1,234.5 `--lr 0.3` jax 0.10.2, h1-cpu, 9x9, 82%"
    assert [w + s for w, s in quoted(text)] == ["0.10", "4.75M", "3.37", "82.5%", "-1.5", "1,234.5"]
    assert found("0.10", "", [0.0985]) and not found("0.10", "", [0.106])
    assert found("4.75", "M", [4_751_360.0]) and found("-25.7", "", [-25.7057])
    assert [w for w, _ in quoted("relative 7.6e-7, 1.2e-6)")] == ["7.6e-7", "1.2e-6"]  # whole, exponent too
    assert found("7.6e-7", "", [7.5957e-7]) and not found("7.6e-7", "", [7.4e-7, 7.6])
    assert numbers({"flags": "--env-args penalty=1.25 --lr 1e-3", "n": [2, True]}) == [1.25, 1e-3, 2.0]
    assert numbers("125.8M env-steps, 61%") == [125.8e6, 0.61]
