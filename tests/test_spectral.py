"""The DFT grid and the evaluation band."""

import numpy as np
import pytest

from roadcollab import ParameterError, SegmentGrid
from roadcollab.lti.batch2x2 import inv2x2, matmul


def test_band_weight_is_zero_at_dc_half_at_the_edge_and_one_in_band():
    g = SegmentGrid(4000, 200.0, band_low_hz=0.5)
    assert g.nfft >= 6000
    assert g.weight[0] == 0.0
    k = np.argmin(np.abs(g.freqs - 0.5))
    assert g.weight[k] == pytest.approx(1 / (1 + (0.5 / g.freqs[k]) ** 8))
    assert np.all(g.weight[g.freqs > 2.0] > 1 - 1e-4)


def test_band_limit_is_zero_phase_and_removes_a_constant():
    g = SegmentGrid(2000, 200.0, band_low_hz=0.5)
    t = np.arange(2000) / 200.0
    x = np.column_stack([np.sin(2 * np.pi * 10 * t), np.ones_like(t)])
    out = g.band_limit(x)
    # A 10 Hz sine passes unchanged in the interior (zero phase); a constant is removed
    # except for window-edge leakage.
    np.testing.assert_allclose(out[500:1500, 0], x[500:1500, 0], atol=1e-3)
    assert np.abs(out[500:1500, 1]).max() < 0.05


def test_the_grids_transforms_are_scipy_ffts_bit_for_bit():
    """rfft and irfft call pocketfft's binding without scipy.fft's dispatch: the same bits as scipy.fft.rfft /
    irfft with n = nfft along the samples, padded or not, and the same results where they fall back to it."""
    import scipy.fft

    g = SegmentGrid(4000, 200.0)
    rng = np.random.default_rng(3)
    for rows in (4000, g.nfft, 1, 0):
        x = rng.standard_normal((rows, 2))
        assert g.rfft(x).tobytes() == scipy.fft.rfft(x, n=g.nfft, axis=0).tobytes()
    assert g.rfft(np.arange(10, dtype=np.float32)[:, None]).tobytes() == scipy.fft.rfft(
        np.arange(10.0)[:, None], n=g.nfft, axis=0).tobytes()
    X = rng.standard_normal((g.n_bins, 3)) + 1j * rng.standard_normal((g.n_bins, 3))
    assert g.irfft(X).tobytes() == scipy.fft.irfft(X, n=g.nfft, axis=0).tobytes()
    assert g.irfft(X, n=4000).tobytes() == scipy.fft.irfft(X, n=g.nfft, axis=0)[:4000].tobytes()
    for other in (X.real, X[:-5], X.astype(np.complex64), X[:, :1].T.T):       # the fallback, or the same layout
        assert g.irfft(other).tobytes() == scipy.fft.irfft(other, n=g.nfft, axis=0).tobytes()


def test_band_limited_many_is_band_limited_of_each_spectrum_bit_for_bit():
    """Side by side, one transform along rows: each column pair has the bits of its own band_limited call."""
    g = SegmentGrid(4000, 200.0)
    rng = np.random.default_rng(5)
    Xs = [rng.standard_normal((g.n_bins, c)) + 1j * rng.standard_normal((g.n_bins, c)) for c in (2, 2, 1, 2)]
    Xs[0][0] = 0.0
    for n in (None, 4000, 1):
        many = g.band_limited_many(Xs, n)
        one = np.concatenate([g.band_limited(X, n) for X in Xs], axis=1)
        assert many.shape == one.shape == ((g.nfft if n is None else n), 7)
        assert np.ascontiguousarray(many).tobytes() == one.tobytes()
    with pytest.raises(ParameterError, match="bins"):
        g.band_limited_many([Xs[0][:-1]])


def test_closed_form_2x2_inverse():
    rng = np.random.default_rng(0)
    M = rng.standard_normal((50, 2, 2)) + 1j * rng.standard_normal((50, 2, 2))
    np.testing.assert_allclose(inv2x2(M), np.linalg.inv(M), rtol=1e-10)


def test_written_out_2x2_products_match_numpy_with_broadcasting():
    rng = np.random.default_rng(1)
    P = rng.standard_normal((3, 40, 2, 2)) + 1j * rng.standard_normal((3, 40, 2, 2))
    S = rng.standard_normal((40, 2, 2))
    Q = rng.standard_normal((40, 2, 2)) + 1j * rng.standard_normal((40, 2, 2))
    got = matmul(P, S[None], Q)
    assert got.shape == (3, 40, 2, 2) and got.dtype == complex
    np.testing.assert_allclose(got, P @ S[None] @ Q, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(matmul(np.eye(2), Q), Q, rtol=0, atol=0)
    # Other sizes go through numpy's product.
    R = rng.standard_normal((40, 2, 3))
    np.testing.assert_allclose(matmul(Q, R), Q @ R, rtol=1e-13)


def test_bad_grids():
    with pytest.raises(ParameterError, match="n_samples must be >= 16, got 3"):
        SegmentGrid(3, 200.0)
    with pytest.raises(ParameterError, match="band_low_hz must be <= 100"):
        SegmentGrid(100, 200.0, band_low_hz=150.0)
