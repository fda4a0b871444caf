"""``lti.realisation.minreal``: python-control's ``minreal`` without importing python-control."""

import numpy as np
import pytest

from roadcollab.lti.realisation import StateSpaceData, minreal


def _padded(rng):
    """A random stable 2x2 system of order 4, plus one uncontrollable and one unobservable state."""
    A0 = np.diag([0.5, -0.3, 0.8, 0.1]) + 0.05 * rng.standard_normal((4, 4))
    B0, C0 = rng.standard_normal((4, 2)), rng.standard_normal((2, 4))
    A = np.zeros((6, 6))
    A[:4, :4] = A0
    A[4, 4], A[5, 5] = 0.7, -0.6
    A[4, :4] = rng.standard_normal(4)       # state 4 is driven by the rest but feeds nothing
    B = np.vstack([B0, [[0.0, 0.0]], rng.standard_normal((1, 2))])     # state 5: driven, unobserved
    C = np.hstack([C0, [[0.0], [0.0]], [[0.0], [0.0]]])
    return StateSpaceData(A, B, C, rng.standard_normal((2, 2)), 0.005), None


def test_minreal_removes_the_padding_and_keeps_the_transfer_matrix():
    rng = np.random.default_rng(7)
    sys, core = _padded(rng)
    got = minreal(sys, tol=1e-9)
    assert got.order == 4
    om = np.linspace(0.01, 3.0, 50)
    np.testing.assert_allclose(got.frequency_response(om), sys.frequency_response(om), rtol=1e-11, atol=1e-12)


def test_minreal_equals_python_control_bit_for_bit():
    control = pytest.importorskip("control")
    rng = np.random.default_rng(8)
    for _ in range(5):
        sys, _ = _padded(rng)
        ref = control.minreal(sys.to_control(), tol=1e-9, verbose=False)
        got = minreal(sys, tol=1e-9)
        for a, b in zip((ref.A, ref.B, ref.C, ref.D), (got.A, got.B, got.C, got.D)):
            assert np.array_equal(np.asarray(a), b)


def test_minreal_of_a_static_gain():
    D = np.array([[1.0, 2.0], [3.0, 4.0]])
    got = minreal(StateSpaceData(np.zeros((0, 0)), np.zeros((0, 2)), np.zeros((2, 0)), D, 0.01))
    assert got.order == 0 and np.array_equal(got.D, D)
