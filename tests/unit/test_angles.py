"""The one angle-wrap helper (shared/angles.py): (-pi, pi], floats and arrays alike."""
import math

import numpy as np
import pytest

from cinetransfer.shared.angles import wrap_angle


@pytest.mark.parametrize("a, want", [(0.0, 0.0), (math.pi, math.pi), (-math.pi, math.pi),
                                     (3 * math.pi / 2, -math.pi / 2), (-3 * math.pi / 2, math.pi / 2),
                                     (2 * math.pi + 0.1, 0.1), (-0.1, -0.1)])
def test_wrap_angle_of_a_float(a, want):
    assert wrap_angle(a) == pytest.approx(want, abs=1e-12)


def test_wrap_angle_of_an_array_matches_the_float_form():
    a = np.array([0.0, math.pi, -math.pi, 3 * math.pi / 2, -7.0, 7.0, 100.0])
    np.testing.assert_allclose(wrap_angle(a), [wrap_angle(float(x)) for x in a], atol=1e-12)
