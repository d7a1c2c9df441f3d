"""Streamed per-pixel moments equal the two-pass numpy result."""
from __future__ import annotations

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.stats import PixelMoments, pixel_moments


def test_matches_numpy_two_pass():
    rng = np.random.default_rng(7)
    stack = rng.integers(0, 65535, size=(25, 16, 12), dtype=np.uint16)
    res = pixel_moments(iter(stack))
    ref = stack.astype(np.float64)
    np.testing.assert_allclose(res.mean, ref.mean(axis=0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.var, ref.var(axis=0, ddof=1), rtol=1e-12, atol=1e-6)
    assert res.n == 25


def test_large_offset_small_variance_is_stable():
    # values near 60000 DN with unit variance: the naive sum of squares loses the variance,
    # the shifted algorithm must not
    rng = np.random.default_rng(8)
    stack = 60000.0 + rng.standard_normal((200, 8, 8))
    res = pixel_moments(stack)
    np.testing.assert_allclose(res.var, stack.var(axis=0, ddof=1), rtol=1e-9)


def test_pairs_and_errors():
    acc = PixelMoments()
    with pytest.raises(CcdError):
        acc.result()
    acc.add(np.zeros((3, 3)))
    assert np.isnan(acc.result().var).all()
    with pytest.raises(CcdError, match="b.tif: frame shape"):
        acc.add(np.zeros((3, 4)), name="b.tif")


def test_result_in_place_is_the_same():
    """``result(in_place=True)`` gives the same bits in the accumulator's buffers, and empties it."""
    rng = np.random.default_rng(9)
    for stack in (rng.integers(0, 255, (5, 7, 6), dtype=np.uint8),
                  rng.normal(100, 3, (4, 7, 6)).astype(np.float32), np.ones((1, 2, 2))):
        a, b = PixelMoments(), PixelMoments()
        for f in stack:
            a.add(f)
            b.add(f)
        ra, rb = a.result(), b.result(in_place=True)
        np.testing.assert_array_equal(rb.mean, ra.mean)
        np.testing.assert_array_equal(rb.var, ra.var)
        assert rb.n == ra.n == len(stack) and b.n == 0
        np.testing.assert_array_equal(a.result().mean, ra.mean)   # a keeps accumulating
        b.add(np.zeros((3, 3)))                                   # b takes any shape again
        assert b.result().mean.shape == (3, 3)


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from hypothesis.extra import numpy as hnp  # noqa: E402


@settings(max_examples=60, deadline=None, derandomize=True)
@given(hnp.arrays(np.uint16, st.tuples(st.integers(2, 9), st.integers(1, 5), st.integers(1, 5)),
                  elements=st.integers(0, 65535)))
def test_any_integer_stack_matches_two_pass(stack):
    res = pixel_moments(stack)
    ref = stack.astype(np.float64)
    np.testing.assert_allclose(res.mean, ref.mean(axis=0), rtol=1e-12, atol=1e-9)
    # variance of 16-bit data: absolute error well below one part in 1e9 of the square range
    np.testing.assert_allclose(res.var, ref.var(axis=0, ddof=1), rtol=1e-9, atol=1e-3)
