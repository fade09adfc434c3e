"""The banded box-constrained QP solver: hand-computed cases, bounds, bridging, exactness."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize

from cinetransfer.services.smoother.qp import smooth


def objective(x, y, w, lam, link=None):
    y0 = np.where(w > 0, y, 0.0)
    d = np.diff(x, axis=0)
    if link is not None:
        d = d * link[:, None]
    return float(np.sum(w * (x - y0) ** 2) + lam * np.sum(d ** 2))


def test_two_frames_hand_computed():
    # Given y = (0, 1), w = (1, 1), lam = 1: stationarity gives 2 x0 - x1 = 0, -x0 + 2 x1 = 1
    # When solved, then x = (1/3, 2/3).
    r = smooth(np.array([0.0, 1.0]), np.array([1.0, 1.0]), 1.0)
    np.testing.assert_allclose(r.x, [1 / 3, 2 / 3], atol=1e-12)
    assert r.iterations == 1 and r.n_active == 0


def test_three_frames_missing_middle_is_bridged():
    # Given the middle frame unobserved, y = (0, ?, 3), lam = 1: stationarity gives
    # 2 x0 = x1, x1 = (x0 + x2) / 2, 2 x2 = 3 + x1  ->  x = (0.75, 1.5, 2.25).
    r = smooth(np.array([0.0, np.nan, 3.0]), np.array([1.0, 0.0, 1.0]), 1.0)
    np.testing.assert_allclose(r.x, [0.75, 1.5, 2.25], atol=1e-12)


def test_bound_active_hand_computed():
    # Given y = (0, 1), lam = 1 and x <= 0.5: x1 = 0.5 (active), then 2 x0 - 0.5 = 0 -> x0 = 0.25;
    # the multiplier of x1's bound is positive (the objective wants x1 larger).
    r = smooth(np.array([0.0, 1.0]), np.array([1.0, 1.0]), 1.0, lo=0.0, hi=0.5)
    np.testing.assert_allclose(r.x, [0.25, 0.5], atol=1e-12)
    assert r.n_active == 1


def test_unlinked_frames_are_independent_and_empty_segment_is_nan():
    y = np.array([[0.0], [10.0], [np.nan], [np.nan]])
    w = np.array([[1.0], [1.0], [0.0], [0.0]])
    r = smooth(y, w, 100.0, link=np.array([False, False, True]))
    np.testing.assert_allclose(r.x[:2, 0], [0.0, 10.0], atol=1e-12)  # no coupling: exact fit
    assert np.isnan(r.x[2:, 0]).all()  # nothing observed in the last run: undetermined


def test_matches_brute_force_on_small_problems():
    rng = np.random.default_rng(3)
    for F, lam in itertools.product((2, 5, 9), (0.3, 3.0)):
        y = rng.normal(0, 2, (F, 2))
        w = rng.uniform(0.1, 1, (F, 2))
        lo, hi = -0.5, 1.0
        r = smooth(y, w, lam, lo=lo, hi=hi)
        assert np.all(r.x >= lo - 1e-12) and np.all(r.x <= hi + 1e-12)
        for c in range(2):
            ref = minimize(lambda x: objective(x[:, None], y[:, c:c + 1], w[:, c:c + 1], lam), np.zeros(F),
                           bounds=[(lo, hi)] * F, method="L-BFGS-B", options={"ftol": 1e-15, "gtol": 1e-12})
            # The banded solution is never worse than the reference (it is the exact optimum).
            mine = objective(r.x[:, c:c + 1], y[:, c:c + 1], w[:, c:c + 1], lam)
            assert mine <= ref.fun + 1e-9
            np.testing.assert_allclose(r.x[:, c], ref.x, atol=1e-4)


@settings(max_examples=80, deadline=None)
@given(F=st.integers(2, 40), seed=st.integers(0, 10_000), lam=st.floats(0.01, 50.0),
       hi=st.floats(-1.0, 3.0), lam2=st.sampled_from([0.0, 0.5, 30.0]))
def test_kkt_conditions_hold(F, seed, lam, hi, lam2):
    """Property: the result satisfies the KKT conditions of the box-constrained QP (first and
    second differences)."""
    rng = np.random.default_rng(seed)
    y = rng.normal(0, 2, (F, 1))
    w = rng.uniform(0, 1, (F, 1)) * (rng.uniform(size=(F, 1)) > 0.3)
    w[0, 0] = max(w[0, 0], 0.05)
    lo = hi - 2.0
    x = smooth(y, w, lam, lo=lo, hi=hi, lam2=lam2).x[:, 0]
    assert np.all(x >= lo - 1e-9) and np.all(x <= hi + 1e-9)
    y0 = np.where(w[:, 0] > 0, y[:, 0], 0.0)
    grad = 2 * w[:, 0] * (x - y0)
    d = np.diff(x)
    grad[:-1] -= 2 * lam * d
    grad[1:] += 2 * lam * d
    if F >= 3:
        a = x[2:] - 2 * x[1:-1] + x[:-2]
        grad[:-2] += 2 * lam2 * a
        grad[1:-1] -= 4 * lam2 * a
        grad[2:] += 2 * lam2 * a
    scale = 1.0 + np.abs(grad).max()
    free = (x > lo + 1e-9) & (x < hi - 1e-9)
    assert np.all(np.abs(grad[free]) <= 1e-7 * scale)
    assert np.all(grad[x <= lo + 1e-9] >= -1e-7 * scale)  # at the lower bound the objective wants to go up
    assert np.all(grad[x >= hi - 1e-9] <= 1e-7 * scale)


def test_rejects_bad_input():
    with pytest.raises(ValueError):
        smooth(np.zeros((3, 1)), -np.ones((3, 1)), 1.0)
    with pytest.raises(ValueError):
        smooth(np.zeros((3, 1)), np.ones((3, 1)), 1.0, lo=1.0, hi=0.0)
