"""The linear MMSE of the scored window, in time: a bound that holds for every linear estimator.

Every estimator of the reproduction is scored on the band-limited road velocity over the scored
segment ``sl`` of the recorded window (``N`` samples, two tracks):

.. math:: t = G w,\\qquad t_i = \\sum_{k=0}^{N-1} g[(s_0 + i - k) \\bmod n_{fft}]\\, w_k,\\quad
          g = \\mathrm{IDFT}_{n_{fft}}(W),

the circular convolution of the zero-padded window with the band weight's impulse response
(:meth:`~roadcollab.estimation.grid.SegmentGrid.band_limited`), rows ``s_0 .. s_0 + m - 1``. Vehicle
``i`` records, sample by sample and starting from its state ``x_0`` at the window's start,

.. math:: y_i = H_i w + O_i x_{0,i} + v_i,\\qquad (H_i w)_k = D w_k + \\sum_{l<k} C A^{k-1-l} B w_l,
          \\quad (O_i x_0)_k = C A^k x_0,

(the ZOH-exact plant of eqs. 1-3; the simulator starts every vehicle at rest, ``x_0 = 0``) with white
noise ``E v v^T = sigma_i^2 I``. With the road's second moment ``R = E[w w^T] = L L^T`` (``2N x 2N``)
and ``x_{0,i} = P_0^{1/2} xi_i``, the unknowns ``u = (L^{-1} w, xi_1..xi_V)`` have an identity prior
and the best *linear* estimate of ``t`` from ``y_1..y_j`` and its mean squared error are

.. math:: \\hat t = K A_j^{-1} \\sum_{i \\le j} J_i^T y_i / \\sigma_i^2,\\qquad
          \\mathrm{MSE}_j = \\mathrm{tr}(K A_j^{-1} K^T) / (2m),\\qquad
          A_j = I + \\sum_{i\\le j} J_i^T J_i / \\sigma_i^2,

with ``J_i = [H_i L, O_i P_0^{1/2}]`` and ``K = [G L, 0]``. No estimator that is linear in the
records (per bin on a padded grid or not, with or without the plant's free response) has a smaller
expected error under these second-order statistics: :meth:`WindowedMMSE.expected_error` evaluates any
such estimator's error in closed form, so the claim can be checked exactly.

Cost (dense): a Cholesky of ``R``, one ``2N x 2N`` rank-``2N`` update (BLAS ``syrk``) per vehicle, and
per prefix ``j`` a Cholesky of ``A_j`` and a triangular solve with ``K^T`` (``2N x 2m``): about
``(2N)^3 (1/3 + 2 m / N) + V (2N)^3 (1 + 1/3 + 2 m / N)`` flops, ``O((2N)^2)`` memory (five
``2N x 2N`` arrays).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import scipy.fft
import scipy.linalg

from .._validation import check_int, check_positive
from ..errors import ParameterError
from ..models.simulation import DiscretePlant
from .grid import SegmentGrid

__all__ = ["window_lag_moment", "respond", "respond_adjoint", "WindowedMMSE"]

#: White floor added to the road's second moment before its Cholesky, relative to the mean power
#: (the tyre enveloping puts near-zeros in the road spectrum, so ``R`` is close to singular).
PRIOR_FLOOR = 1e-10


def window_lag_moment(draw_velocity: Callable[[np.random.Generator], np.ndarray], n_samples: int, *,
                      n_draws: int = 64, rng=None) -> np.ndarray:
    """Stationarised second moment of the road velocity over a window, per lag.

    .. math:: r(l) = \\frac{1}{D N} \\sum_{d=1}^{D} \\sum_{k} w_d[k + l]\\, w_d[k]^T,\\qquad |l| < N,

    the averaged lag products of ``D`` roads drawn from the road model (the biased estimate, so the
    block-Toeplitz matrix it defines is positive semi-definite). It carries what the per-bin second
    moment carries (enveloping, anomalies, the coupling of the tracks), in time and without wrap-around.

    Parameters
    ----------
    draw_velocity : callable
        ``draw_velocity(rng) -> (n_samples, 2)`` road velocity (m/s) of one road from the model.
    n_samples : int
        ``N``.
    n_draws : int
        ``D``.
    rng : numpy.random.Generator | int | None
        Design randomness (use a seed disjoint from the runs').

    Returns
    -------
    r : (2 N - 1, 2, 2) ndarray
        ``r[l + N - 1] = E[w_{k+l} w_k^T]``, (m/s)^2.
    """
    N = check_int("n_samples", n_samples, low=2)
    n_draws = check_int("n_draws", n_draws, low=1)
    rng = np.random.default_rng(rng)
    nf = scipy.fft.next_fast_len(2 * N, real=True)
    acc = np.zeros((nf, 2, 2))
    for _ in range(n_draws):
        w = np.asarray(draw_velocity(rng), dtype=float)
        if w.shape != (N, 2):
            raise ParameterError(f"draw_velocity must return shape ({N}, 2), got {w.shape}")
        X = scipy.fft.rfft(w, n=nf, axis=0)
        acc += scipy.fft.irfft(X[:, :, None] * X[:, None, :].conj(), n=nf, axis=0)
    acc /= n_draws * N
    lags = np.arange(-(N - 1), N)
    return acc[lags % nf]


def respond(plant: DiscretePlant, w: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
    """``H w + O x0``: the plant's accelerations for a batch of road velocities.

    Parameters
    ----------
    plant : DiscretePlant
    w : (N, 2, M) ndarray
        ``M`` road velocities, m/s.
    x0 : (4, M) ndarray, optional
        Initial states (zero by default).

    Returns
    -------
    (N, 2, M) ndarray
        m/s^2; equal to :func:`~roadcollab.models.simulation.simulate_response` per column.
    """
    A, B, C, D = plant.Ad, plant.Bd, plant.C, plant.D
    N, _, M = w.shape
    x = np.zeros((4, M)) if x0 is None else np.array(x0, dtype=float)
    y = np.empty((N, 2, M))
    for k in range(N):
        y[k] = C @ x + D @ w[k]
        x = A @ x + B @ w[k]
    return y


def respond_adjoint(plant: DiscretePlant, y: np.ndarray) -> np.ndarray:
    """``H^T y``, the adjoint of :func:`respond` (``x0 = 0``), by the backward recursion
    ``lambda_k = C^T y_k + A^T lambda_{k+1}``, ``(H^T y)_k = D^T y_k + B^T lambda_{k+1}``.

    Parameters
    ----------
    plant : DiscretePlant
    y : (N, 2, M) ndarray

    Returns
    -------
    (N, 2, M) ndarray
    """
    A, B, C, D = plant.Ad, plant.Bd, plant.C, plant.D
    N, _, M = y.shape
    lam = np.zeros((4, M))
    out = np.empty((N, 2, M))
    for k in range(N - 1, -1, -1):
        out[k] = D.T @ y[k] + B.T @ lam
        lam = A.T @ lam + C.T @ y[k]
    return out


class WindowedMMSE:
    """Linear MMSE of the band-limited road velocity over the scored window (module docstring).

    Parameters
    ----------
    grid : SegmentGrid
        The window (``grid.n_samples = N``), its padded grid and band weight.
    scored : slice
        Scored samples ``s_0 .. s_0 + m - 1`` of the window.
    lag_moment : (2 N - 1, 2, 2) ndarray
        The road's second moment per lag (:func:`window_lag_moment`).
    plants : sequence of DiscretePlant
        The vehicles' *true* plants, in driving order.
    noise_std : sequence of float
        Accelerometer noise standard deviations ``sigma_i``, m/s^2, > 0.
    initial_state_cov : (4, 4) ndarray, optional
        ``P_0``, the covariance of every vehicle's state at the window's start (default 0: at rest,
        as the simulator starts).

    Attributes
    ----------
    bounds : (V,) ndarray
        ``MSE_j`` for the records of vehicles ``1..j``, (m/s)^2, the mean over the scored samples and
        both tracks (the reproduction's MSE).
    """

    def __init__(self, grid: SegmentGrid, scored: slice, lag_moment: np.ndarray, plants: Sequence[DiscretePlant],
                 noise_std: Sequence[float], *, initial_state_cov: np.ndarray | None = None) -> None:
        N = grid.n_samples
        s0, s1, _ = scored.indices(N)
        if not 0 <= s0 < s1 <= N:
            raise ParameterError(f"scored must be a non-empty slice of the {N} window samples, got {scored}")
        lag_moment = np.asarray(lag_moment, dtype=float)
        if lag_moment.shape != (2 * N - 1, 2, 2):
            raise ParameterError(f"lag_moment must have shape ({2 * N - 1}, 2, 2), got {lag_moment.shape}")
        if len(plants) != len(noise_std) or not plants:
            raise ParameterError(f"plants and noise_std must have one entry per vehicle, got {len(plants)} "
                                 f"and {len(noise_std)}")
        self.grid, self.scored, self.m = grid, slice(s0, s1), s1 - s0
        self.plants = list(plants)
        self.sigma = [check_positive(f"noise_std[{i}]", s) for i, s in enumerate(noise_std)]
        V, n = len(plants), 2 * N
        P0h = np.zeros((4, 0)) if initial_state_cov is None else _psd_factor("initial_state_cov", initial_state_cov)
        q = P0h.shape[1]                      # unknowns per vehicle's initial state
        # Prior factor L (2N x 2N, time-major: index 2 k + c), with a white floor.
        idx = np.arange(N)
        R = lag_moment[idx[:, None] - idx[None, :] + N - 1].transpose(0, 2, 1, 3).reshape(n, n)
        R[np.diag_indices(n)] += PRIOR_FLOOR * np.trace(R) / n
        L = scipy.linalg.cholesky(R, lower=True, overwrite_a=True, check_finite=False)
        del R
        self._L = L
        # Target operator G (m x N), the same on both tracks; K = G L, (2m, 2N + V q).
        g = scipy.fft.irfft(grid.weight, n=grid.nfft)
        G = g[(s0 + np.arange(self.m)[:, None] - idx[None, :]) % grid.nfft]
        Lt = L.reshape(N, 2, n)
        K = np.zeros((self.m, 2, n + V * q))
        for c in range(2):
            K[:, c, :n] = G @ Lt[:, c, :]
        self._G = G
        self._K = K.reshape(2 * self.m, -1)
        self._free = [respond(p, np.zeros((N, 2, q)), P0h) for p in self.plants]   # O_i P0^{1/2}, (N, 2, q)
        # A_j = I + sum_{i<=j} J_i^T J_i / sigma_i^2 and its Cholesky factor per prefix.
        A = np.asfortranarray(np.eye(n + V * q))
        self._chol: list[np.ndarray] = []
        bounds = []
        for i, p in enumerate(self.plants):
            J = np.zeros((N, 2, n + V * q))
            J[:, :, :n] = respond(p, Lt)
            J[:, :, n + i * q:n + (i + 1) * q] = self._free[i]
            Jm = J.reshape(n, -1)
            # syrk on J^T (F-ordered view): the upper triangle of A + J^T J / sigma^2.
            A = scipy.linalg.blas.dsyrk(1.0 / self.sigma[i] ** 2, Jm.T, beta=1.0, c=A, trans=0, lower=0,
                                          overwrite_c=1)
            del J, Jm
            U = scipy.linalg.cholesky(A, lower=False, check_finite=False)
            self._chol.append(U)
            X = scipy.linalg.solve_triangular(U, self._K.T, trans="T", check_finite=False)
            bounds.append(float(np.sum(X * X)) / (2 * self.m))
            del X
        self.bounds = np.array(bounds)

    def target(self, w: np.ndarray) -> np.ndarray:
        """The scored quantity ``t = G w`` of a road velocity (what the reproduction scores).

        Parameters
        ----------
        w : (N, 2) ndarray
            m/s.

        Returns
        -------
        (m, 2) ndarray
        """
        return self._G @ np.asarray(w, dtype=float)

    def estimate(self, records: Sequence[np.ndarray]) -> np.ndarray:
        """The linear MMSE estimate of ``t`` from the first ``len(records)`` vehicles' records.

        Parameters
        ----------
        records : sequence of (N, 2) ndarray
            Accelerations, m/s^2, vehicles ``1..j`` in order.

        Returns
        -------
        (m, 2) ndarray
            m/s.
        """
        return self._estimate([np.asarray(y, dtype=float)[:, :, None] for y in records])[:, :, 0]

    def _estimate(self, records: Sequence[np.ndarray]) -> np.ndarray:
        """Batched :meth:`estimate`: records (N, 2, M) -> (m, 2, M)."""
        j = len(records)
        if not 1 <= j <= len(self.plants):
            raise ParameterError(f"records must hold 1..{len(self.plants)} records, got {j}")
        N, n = self.grid.n_samples, 2 * self.grid.n_samples
        M = records[0].shape[2]
        b = np.zeros((self._K.shape[1], M))
        q = self._free[0].shape[2]
        for i, y in enumerate(records):
            if y.shape[:2] != (N, 2):
                raise ParameterError(f"records[{i}] must have shape ({N}, 2), got {y.shape[:2]}")
            b[:n] += self._L.T @ respond_adjoint(self.plants[i], y).reshape(n, M) / self.sigma[i] ** 2
            b[n + i * q:n + (i + 1) * q] += np.einsum("kcq,kcm->qm", self._free[i], y) / self.sigma[i] ** 2
        u = scipy.linalg.cho_solve((self._chol[j - 1], False), b, check_finite=False)
        return (self._K @ u).reshape(self.m, 2, M)

    def expected_error(self, apply: Callable[[list[np.ndarray]], np.ndarray], j: int, *, chunk: int = 256) -> float:
        """Expected MSE of any estimator linear in the records, in closed form under this model.

        .. math:: \\frac{1}{2m}\\Big(\\big\\|K - \\sum_{i\\le j} E_i J_i\\big\\|_F^2
                  + \\sum_{i\\le j} \\sigma_i^2 \\|E_i\\|_F^2\\Big)

        Parameters
        ----------
        apply : callable
            ``apply(records) -> (m, 2, M)``: the estimator applied to ``j`` batches of records, each
            ``(N, 2, M)``, column by column (it must be linear).
        j : int
            Vehicles ``1..j`` whose records it uses.
        chunk : int
            Columns per call of ``apply``.

        Returns
        -------
        float
            (m/s)^2; ``>= bounds[j - 1]`` for every linear estimator (equal for :meth:`estimate`).
        """
        j = check_int("j", j, low=1, high=len(self.plants))
        N, n = self.grid.n_samples, 2 * self.grid.n_samples
        total = 0.0
        Lt = self._L.reshape(N, 2, n)
        cols = self._K.shape[1]
        q = self._free[0].shape[2]
        for a in range(0, cols, chunk):      # signal part: K - sum E_i J_i, by columns of u
            sl = slice(a, min(a + chunk, cols))
            recs = []
            for i in range(j):
                J = np.zeros((N, 2, sl.stop - sl.start))
                lo, hi = max(sl.start, 0), min(sl.stop, n)
                if lo < hi:
                    J[:, :, lo - a:hi - a] = respond(self.plants[i], Lt[:, :, lo:hi])
                f0, f1 = max(sl.start, n + i * q), min(sl.stop, n + (i + 1) * q)
                if f0 < f1:
                    J[:, :, f0 - a:f1 - a] = self._free[i][:, :, f0 - n - i * q:f1 - n - i * q]
                recs.append(J)
            D = self._K[:, sl] - np.asarray(apply(recs)).reshape(2 * self.m, -1)
            total += float(np.sum(D * D))
        for i in range(j):                   # noise part: sigma_i^2 ||E_i||_F^2, by unit records
            for a in range(0, n, chunk):
                cnt = min(chunk, n - a)
                recs = [np.zeros((N, 2, cnt)) for _ in range(j)]
                e = recs[i].reshape(n, cnt)
                e[a + np.arange(cnt), np.arange(cnt)] = 1.0
                E = np.asarray(apply(recs))
                total += self.sigma[i] ** 2 * float(np.sum(E * E))
        return total / (2 * self.m)


def _psd_factor(name: str, P) -> np.ndarray:
    """A factor ``F`` with ``F F^T = P`` of a (4, 4) positive semi-definite matrix."""
    P = np.asarray(P, dtype=float)
    if P.shape != (4, 4) or not np.all(np.isfinite(P)) or not np.allclose(P, P.T):
        raise ParameterError(f"{name} must be a finite symmetric (4, 4) matrix, got shape {P.shape}")
    lam, V = np.linalg.eigh(P)
    if lam[0] < -1e-12 * max(lam[-1], 1e-300):
        raise ParameterError(f"{name} must be positive semi-definite, smallest eigenvalue {lam[0]:g}")
    keep = lam > 1e-14 * max(lam[-1], 1e-300)
    return V[:, keep] * np.sqrt(lam[keep])
