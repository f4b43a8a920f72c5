"""`benchmarks/op_fingerprints.py`: its inputs are exact on every CPU, and its emulated FMA chains tell
summation orders apart (what `dot_blocks` reads a library's blocking from)."""

import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.append(str(REPO / "benchmarks"))  # the script, its `reproducibility` and `run_info`
import op_fingerprints  # noqa: E402


def test_exact_inputs_are_small_integers_over_1024_and_fixed_by_the_seed():
    x = op_fingerprints.exact_inputs((3, 500), seed=7)
    assert x.dtype == np.float32
    scaled = x.astype(np.float64) * 1024
    np.testing.assert_array_equal(scaled, np.round(scaled))
    assert np.abs(scaled).max() <= 4096
    np.testing.assert_array_equal(x, op_fingerprints.exact_inputs((3, 500), seed=7))
    assert not np.array_equal(x, op_fingerprints.exact_inputs((3, 500), seed=8))


def test_fma_chain_tells_one_chain_from_blocks():
    """[2^-24, 1, 2^-24, 2^-24] . 1: one float32 chain absorbs every 2^-24 into 1 (ties to even), while blocks
    of 2 sum the last two first (2^-23) and add that to 1."""
    tiny = np.float32(2.0**-24)
    a = np.array([[tiny, 1, tiny, tiny]], np.float32)
    ones = np.ones((4, 1), np.float32)
    assert op_fingerprints.fma_chain(a, ones, None)[0, 0] == np.float32(1)
    assert op_fingerprints.fma_chain(a, ones, 4)[0, 0] == np.float32(1)
    assert op_fingerprints.fma_chain(a, ones, 2)[0, 0] == np.float32(1) + np.float32(2.0**-23)


def test_fma_chain_equals_the_product_where_no_rounding_happens():
    a = op_fingerprints.exact_inputs((5, 40), seed=1) * np.float32(1 / 64)
    b = np.round(op_fingerprints.exact_inputs((40, 3), seed=2))
    for block in (None, 8, 16):
        np.testing.assert_array_equal(op_fingerprints.fma_chain(a, b, block), a.astype(np.float64) @ b)


def test_differing_names_the_shared_operations_whose_digests_differ():
    mine = {"dot": "a", "exp": "b", "only_mine": "c"}
    theirs = {"dot": "a", "exp": "x", "only_theirs": "d"}
    assert op_fingerprints.differing(mine, theirs) == ["exp"]
