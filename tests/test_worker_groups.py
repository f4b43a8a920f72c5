"""The suite's split over pytest-xdist workers (`conftest.FileGroups`): a test file's tests
share one worker, so its module fixtures and compiled programs are made once, and the files that train TINY's
programs share one worker between them."""

from __future__ import annotations

from pathlib import Path

from conftest import SHARED_RUNS, FileGroups


def test_each_file_is_one_work_unit_and_the_tiny_run_files_one_together():
    scope = FileGroups.__new__(FileGroups)._split_scope  # the grouping alone (a scheduler needs workers)
    one_file = {scope(f"tests/test_experiments.py::{t}") for t in ("test_a", "test_b[laptop]", "test_c[1-x]")}
    assert len(one_file) == 1
    tiny = {scope(f"tests/{name}.py::test_a") for name in SHARED_RUNS}
    assert len(tiny) == 1
    assert len({*one_file, *tiny, scope("tests/test_ppo.py::test_a")}) == 3


def test_the_tiny_run_files_exist():
    assert {name for name in SHARED_RUNS if not (Path(__file__).parent / f"{name}.py").exists()} == set()
