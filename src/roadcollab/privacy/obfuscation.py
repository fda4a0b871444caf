"""Algorithm 2: obfuscating dynamics (Theorem 1).

Before sending, vehicle ``j`` draws two random, stable, invertible 2x2 systems ``Psi^S1``
and ``Psi^S2`` and sends (eq. 17)

.. math::

    \\tilde T_j = \\Psi^{S1} T_j,\\quad \\tilde S_j = \\Psi^{S1} S_j \\Psi^{S2},\\quad
    \\tilde e_j = \\Psi^{S1} e_j,\\quad \\tilde w^f_j = (\\Psi^{S2})^{-1} w^f_j.

The receiver's ``z = T^-1 (e - S w^f)`` is unchanged:
``T~^-1 (e~ - S~ w~f) = T^-1 Psi1^-1 (Psi1 e - Psi1 S Psi2 Psi2^-1 w^f) = z`` (Theorem 1),
so every estimate is exactly what it would be without privacy.

Each ``Psi`` has a common denominator of random order ``n`` with random left-half-plane
poles, and four numerators (one per entry: the "four groups of zeros"), each of degree ``n``
so ``Psi`` is biproper and ``Psi^-1`` proper. A draw is rejected unless every transmission
zero of ``Psi`` has real part <= ``-min_zero_distance``, ``Psi`` is well conditioned on the
grid and its poles are separated by ``min_pole_separation``: otherwise exactness would become
round-off amplification. The
continuous design is discretised with the bilinear transform, which maps left-half-plane
poles and zeros inside the unit circle. Realisations are hidden with a random orthogonal
similarity so no block of ``T`` or ``S`` is visible verbatim.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..wire.message import ExchangeMessage
from ..lti.composed_schur import series_schur
from ..lti.realisation import StateSpaceData, random_similarity, series
from ..estimation.grid import SegmentGrid, bin_index
from ..lti.batch2x2 import diff_norms, inv2x2, matvec, receiver_z
from ..lti._pole_kernel import pole_residue_apply
from ..lti.kernels import kernel_path
from ..lti.response import unit_circle
from .obfuscator_design import ObfuscationSpec, Obfuscator, draw_obfuscator, draw_obfuscator_pair

__all__ = ["ObfuscationSpec", "Obfuscator", "ObfuscationChannel", "draw_obfuscator", "obfuscate", "obfuscate_spectra",
           "theorem1_errors"]


@dataclass(frozen=True, eq=False)
class ObfuscationChannel:
    """One draw of Algorithm 2's private dynamics for a sender, with everything per-segment
    obfuscation needs precomputed on the grid.

    The paper redraws ``Psi`` for every message (:func:`obfuscate` without ``channel``); a
    vehicle may instead keep one channel for many segments (``refresh="vehicle"``), which
    turns obfuscation into a few per-bin products. Either way the realisations sent are the
    same objects the responses were computed from, so Theorem 1 stays exact.

    Attributes
    ----------
    psi1, psi2 : Obfuscator
        The private draws (never sent).
    T, S : StateSpaceData
        ``Psi1 T`` and ``Psi1 S Psi2``, hidden by random orthogonal similarity transforms.
    grid : SegmentGrid
        The grid of the responses.
    psi1_all, psi2_inv_all : (n_bins, 2, 2) complex ndarray
        ``Psi1`` and ``Psi2^-1`` on every bin (one evaluation each: in band and outside it),
        computed on first use: a channel kept for many segments applies them every segment, while
        a fresh ``paper`` draw on the compiled path applies ``Psi`` without forming them
        (``Psi1 E`` and ``Psi2^-1 W^f`` from the poles and residues in one compiled pass).
    T_f, S_f : (K, 2, 2) complex ndarray
        Responses of ``T~`` and ``S~`` on the active bins, computed on first use: only the
        ``consistent`` construction needs them. Computing them for every draw cost the sender of
        ``paper`` two Schur evaluations per message (3.1 ms of 10-11 ms, measured).
    psi1_f, psi2_inv_f, psi1_out, psi2_inv_out : (K, 2, 2) / (K', 2, 2) complex ndarray
        Views of ``psi1_all``, ``psi2_inv_all`` on the active bins and outside them.
    """

    psi1: Obfuscator
    psi2: Obfuscator
    T: StateSpaceData
    S: StateSpaceData
    grid: SegmentGrid

    @classmethod
    def draw(cls, T: StateSpaceData, S: StateSpaceData, grid: SegmentGrid, spec: ObfuscationSpec = ObfuscationSpec(),
             *, rng: np.random.Generator | int | None = None) -> "ObfuscationChannel":
        """Draw ``Psi1``, ``Psi2`` and build ``T~``, ``S~`` for a sender's ``T`` and ``S``.

        Parameters
        ----------
        T, S : StateSpaceData
            The sender's clear ``T_j`` and ``S_j`` (2x2 discrete systems).
        grid : SegmentGrid
        spec : ObfuscationSpec
        rng : numpy.random.Generator | int | None

        Returns
        -------
        ObfuscationChannel
        """
        rng = np.random.default_rng(rng)
        psi1, psi2 = draw_obfuscator_pair(spec, grid, rng=rng)     # draw_obfuscator twice, from rng in turn
        T_t = series(T, psi1.system)                        # Psi1 T
        S_in = series(psi2.system, S)
        S_t = series(S_in, psi1.system)                     # Psi1 S Psi2
        form_T = form_S = None
        if kernel_path() == "compiled":
            # Schur forms of T~, S~ before hiding from those of the parts (T, S memoised, Psi small):
            # the sender certifies what it sends without a 20-22 state Schur decomposition each.
            p1 = psi1.system.schur()
            form_T = series_schur(T.schur(), p1, T_t.A)
            form_S = series_schur(series_schur(psi2.system.schur(), S.schur(), S_in.A), p1, S_t.A)
        T_t = random_similarity(T_t, rng, schur=form_T)     # similarity(T_t, random_orthogonal(n, rng), balance=True)
        S_t = random_similarity(S_t, rng, schur=form_S)
        return cls(psi1=psi1, psi2=psi2, T=T_t, S=S_t, grid=grid)

    @functools.cached_property
    def psi1_all(self) -> np.ndarray:
        if kernel_path() == "compiled":
            # From the design's poles and residues (Obfuscator.frequency_response): no eigendecomposition
            # of the realisation, 0.2 instead of 0.5-0.7 ms per Psi on every bin (docs/speed.md).
            return self.psi1.frequency_response(self.grid.omega_dt)
        return self.psi1.system.frequency_response(self.grid.omega_dt)

    @functools.cached_property
    def psi2_inv_all(self) -> np.ndarray:
        om = self.grid.omega_dt
        return inv2x2(self.psi2.frequency_response(om) if kernel_path() == "compiled" else
                      self.psi2.system.frequency_response(om))

    @functools.cached_property
    def T_f(self) -> np.ndarray:
        return self.T.frequency_response(self.grid.omega_dt[self.grid.active])

    @functools.cached_property
    def S_f(self) -> np.ndarray:
        return self.S.frequency_response(self.grid.omega_dt[self.grid.active])

    @property
    def psi1_f(self) -> np.ndarray:
        out: np.ndarray = self.psi1_all[self.grid.active]
        return out

    @property
    def psi2_inv_f(self) -> np.ndarray:
        out: np.ndarray = self.psi2_inv_all[self.grid.active]
        return out

    @property
    def psi1_out(self) -> np.ndarray:
        out: np.ndarray = self.psi1_all[~self.grid.active]
        return out

    @property
    def psi2_inv_out(self) -> np.ndarray:
        out: np.ndarray = self.psi2_inv_all[~self.grid.active]
        return out


def obfuscate(message: ExchangeMessage, grid: SegmentGrid, spec: ObfuscationSpec = ObfuscationSpec(), *,
              rng: np.random.Generator | int | None = None, T_response: np.ndarray | None = None, S_response: np.ndarray | None = None,
              channel: ObfuscationChannel | None = None, construction: str = "direct",
              spectra: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[ExchangeMessage, Obfuscator, Obfuscator]:
    """Apply Algorithm 2 to a plain message (eq. 17).

    By default (``construction="direct"``) the signals are obfuscated as eq. 17 reads:
    ``e~ = Psi1 e`` and ``w~f = Psi2^-1 w^f``, per bin with the responses of the realisations of
    ``Psi1`` and ``Psi2`` that the sender drew. Theorem 1 then holds at the receiver only as far as
    the sent realisations ``T~`` and ``S~`` equal ``Psi1 T`` and ``Psi1 S Psi2`` in floating point,
    so comparing the receiver's estimate with and without privacy is a measurement that can
    fail. The realisations are balanced before the random similarity that hides them
    (:func:`~roadcollab.lti.realisation.similarity`), and a receiver evaluates them through their
    Schur form, block-diagonalised into clusters of close eigenvalues with a bounded transformation
    (:mod:`~roadcollab.lti.blockdiag`; :func:`~roadcollab.lti.response.ss_response`).
    Measured on the default reproduction (900 messages, the receiver's estimate from the
    obfuscated vs. the clear message): worst change 1.4e-8 with neither, 1.2e-9 with balancing,
    1.4e-10 with both. What remains is the float64 rounding of a dense order-14..22
    realisation whose poles sit near ``z = 1``, amplified at the low end of the band by
    ``cond(T~)`` (up to 7e3).

    ``construction="consistent"`` forms ``e~`` as ``T~ z + S~ w~f`` with ``z = T^-1 (e - S w^f)``
    from the responses of the realisations actually sent, which is ``Psi1 e`` in exact
    arithmetic and makes the receiver recover ``z`` to round-off by construction (estimates within
    3e-14), at the price of ``e~`` deviating from ``Psi1 e`` (up to 9e-6 relative over the band in
    1000 messages; :func:`theorem1_errors` measures it).

    Parameters
    ----------
    message : ExchangeMessage
        ``mechanism == "none"``.
    grid : SegmentGrid
    spec : ObfuscationSpec
    rng : numpy.random.Generator | int | None
    T_response, S_response : (K, 2, 2) complex ndarray, optional
        Responses of ``message.T`` and ``message.S`` on the active bins, if already known
        (used by the ``consistent`` construction only).
    channel : ObfuscationChannel, optional
        Reuse this draw (it must have been drawn for ``message.T`` and ``message.S``); by
        default a fresh one is drawn for every message, as in the paper.
    construction : {"direct", "consistent"}
        How ``e~`` is formed (see above).
    spectra : ((n_bins, 2), (n_bins, 2)) complex ndarray, optional
        The spectra ``E``, ``W^f`` that ``message.e`` and ``message.wf`` are the inverse FFTs of (the
        sender has them): saves the FFT round trip (two rffts of ``nfft x 2``, about 0.1 ms), and
        changes ``e~``, ``w~f`` only by that round trip's rounding.

    Returns
    -------
    (ExchangeMessage, Obfuscator, Obfuscator)
        The obfuscated message (``mechanism == "paper"``) and the private draws ``Psi1``,
        ``Psi2`` (kept by the sender, never sent).
    """
    if message.mechanism != "none":
        raise ParameterError(f"message.mechanism must be 'none', got {message.mechanism!r}")
    if construction not in ("direct", "consistent"):
        raise ParameterError(f"construction must be 'direct' or 'consistent', got {construction!r}")
    E, Wf = (grid.rfft(message.e), grid.rfft(message.wf)) if spectra is None else spectra
    consistent: tuple[np.ndarray, np.ndarray] | None = None
    if construction == "consistent":
        om = grid.omega_dt[grid.active]
        consistent = (message.T.frequency_response(om) if T_response is None else T_response,
                      message.S.frequency_response(om) if S_response is None else S_response)
    return obfuscate_spectra(message.T, message.S, E, Wf, grid, spec, rng=rng, channel=channel,
                             consistent=consistent)


def obfuscate_spectra(T: StateSpaceData, S: StateSpaceData, E: np.ndarray, Wf: np.ndarray, grid: SegmentGrid,
                      spec: ObfuscationSpec = ObfuscationSpec(), *, rng: np.random.Generator | int | None = None,
                      channel: ObfuscationChannel | None = None,
                      consistent: tuple[np.ndarray, np.ndarray] | None = None
                      ) -> tuple[ExchangeMessage, Obfuscator, Obfuscator]:
    """:func:`obfuscate` from the sender's ``T``, ``S`` and spectra, without a clear message.

    A sender that keeps its clear message only for measuring Theorem 1 builds it when asked
    (:class:`~roadcollab.collaboration.relay.RelayStep`): building and checking it cost 0.31 ms of
    every ``paper`` message, for a message never sent.

    Parameters
    ----------
    T, S : StateSpaceData
        The sender's clear ``T_j``, ``S_j``.
    E, Wf : (n_bins, 2) complex ndarray
        Spectra of ``e_j`` and ``w^f_j`` on the grid.
    grid : SegmentGrid
    spec : ObfuscationSpec
    rng : numpy.random.Generator | int | None
    channel : ObfuscationChannel, optional
        Reuse this draw (see :func:`obfuscate`).
    consistent : (T_f, S_f), optional
        The ``consistent`` construction of :func:`obfuscate` with these responses of ``T``, ``S``
        on the active bins; by default ``direct``.

    Returns
    -------
    (ExchangeMessage, Obfuscator, Obfuscator)
    """
    ch = ObfuscationChannel.draw(T, S, grid, spec, rng=rng) if channel is None else channel
    act = grid.active
    # Every bin is obfuscated, also outside the band, where the receiver uses nothing (W = 0):
    # the time signals hold no clear component.
    if channel is None and kernel_path() == "compiled":
        # A fresh draw is applied once: Psi1 E and Psi2^-1 W^f straight from the poles and residues,
        # the same bits as the products with the responses below (_apply_fresh).
        Wf_t = _apply_fresh(ch.psi2, grid, Wf, inverse=True)
        E_t = _apply_fresh(ch.psi1, grid, E)
    else:
        Wf_t = matvec(ch.psi2_inv_all, Wf)
        E_t = matvec(ch.psi1_all, E)
    if consistent is not None:
        z = receiver_z(consistent[0], consistent[1], E[act], Wf[act])
        E_t[act] = matvec(ch.T_f, z) + matvec(ch.S_f, Wf_t[act])
    out = ExchangeMessage(mechanism="paper", sample_rate=grid.sample_rate, n_samples=grid.n_samples,
                          T=ch.T, S=ch.S, e=grid.irfft(E_t), wf=grid.irfft(Wf_t))
    return out, ch.psi1, ch.psi2


def _apply_fresh(psi: Obfuscator, grid: SegmentGrid, X: np.ndarray, *, inverse: bool = False) -> np.ndarray:
    """``Psi X`` (``Psi^-1 X`` if ``inverse``) on every bin of ``grid`` in one compiled pass from the design's
    poles and residues: the bits of ``matvec(psi1_all, X)`` (``psi2_inv_all``), without the (n_bins, 2, 2)
    response, its inverse and the product in memory (about 24 us less per fresh draw, measured)."""
    zp, res, direct = psi.pole_residues()
    return pole_residue_apply(zp, res.reshape(zp.size, 4), direct, unit_circle(grid.omega_dt), X, inverse=inverse)


def theorem1_errors(clear: ExchangeMessage, sent: ExchangeMessage, psi1: Obfuscator, psi2: Obfuscator,
                    grid: SegmentGrid, *, band_weight: float = 0.5) -> tuple[float, float, float, float]:
    """Measure eq. 17 on the grid, independently of how the sender formed the message.

    Parameters
    ----------
    clear : ExchangeMessage
        The message before obfuscation (``e``, ``w^f``).
    sent : ExchangeMessage
        The obfuscated message (``e~``, ``w~f``).
    psi1, psi2 : Obfuscator
        The sender's private draws.
    grid : SegmentGrid
    band_weight : float
        Bins with band weight ``W >= band_weight`` count (the evaluation band).

    Returns
    -------
    e_bin, wf_bin, e_band, wf_band : float
        Per bin: ``max_k |e~_k - Psi1_k e_k| / |Psi1_k e_k|`` and
        ``max_k |w~f_k - Psi2_k^-1 w^f_k| / |Psi2_k^-1 w^f_k|`` over the in-band bins (2-norms
        per bin; bins where the reference is below 1e-12 of its in-band maximum are skipped).
        Over the band: ``||e~ - Psi1 e|| / ||Psi1 e||`` and the same for ``w~f``.
    """
    band = bin_index(grid.weight >= band_weight)

    def rel(got: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
        num, den = diff_norms(got, ref)
        keep = den > 1e-12 * max(float(den.max()), 1e-300)
        per_bin = float(np.max(num[keep] / den[keep])) if keep.any() else 0.0
        return per_bin, float(np.linalg.norm(num) / max(float(np.linalg.norm(den)), 1e-300))

    # Evaluated on every bin (the realisations memoise that response: the sender computed it).
    om = grid.omega_dt
    ref_e = matvec(psi1.system.frequency_response(om)[band], grid.rfft(clear.e)[band])
    ref_wf = matvec(inv2x2(psi2.system.frequency_response(om)[band]), grid.rfft(clear.wf)[band])
    (e_bin, e_band), (wf_bin, wf_band) = rel(grid.rfft(sent.e)[band], ref_e), rel(grid.rfft(sent.wf)[band], ref_wf)
    return e_bin, wf_bin, e_band, wf_band
