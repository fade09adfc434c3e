"""The guided filter (focus map, mask refinement) computed in place gives the bits of the formula."""
import numpy as np
import pytest

from cinetransfer.services.detector.focus import _box, guided_filter


def _formula(guide, src, radius, eps):
    """He et al.'s guided filter written out, each operation into a fresh array."""
    mean_i, mean_p = _box(guide, radius), _box(src, radius)
    corr_ip = _box(guide * src, radius)
    var_i = _box(guide * guide, radius) - mean_i * mean_i
    a = (corr_ip - mean_i * mean_p) / (var_i + eps)
    b = mean_p - a * mean_i
    return _box(a, radius) * guide + _box(b, radius)


@pytest.mark.parametrize("radius", [1, 2, 3])
def test_guided_filter_in_place_gives_the_formulas_bits(radius):
    rng = np.random.default_rng(radius)
    guide = rng.random((90, 160), dtype=np.float32)
    mask = np.zeros((90, 160), np.float32)
    mask[20:70, 40:100] = 1.0
    for src in (mask, rng.random((90, 160), dtype=np.float32)):
        want, got = _formula(guide, src, radius, 1e-3), guided_filter(guide, src, radius, 1e-3)
        assert got.dtype == np.float32
        assert np.array_equal(want.view(np.uint32), got.view(np.uint32))


def test_guided_filter_keeps_a_constant_source_and_leaves_its_inputs():
    # a constant source has no covariance with the guide: a = 0, b = the constant, exactly
    rng = np.random.default_rng(0)
    guide = rng.random((40, 50), dtype=np.float32)
    src = np.full((40, 50), 0.25, np.float32)
    g0, s0 = guide.copy(), src.copy()
    out = guided_filter(guide, src, 3, 1e-3)
    assert np.array_equal(out, np.full((40, 50), 0.25, np.float32))
    assert np.array_equal(guide, g0) and np.array_equal(src, s0)
