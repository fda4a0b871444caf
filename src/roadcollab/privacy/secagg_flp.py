"""The validity proof of :mod:`.secagg_validity`: a fully linear PCP on secret-shared bounded inputs.

Every vehicle proves, to two non-colluding aggregators ``A`` (the roadside service, the *leader*) and ``B``
(a second aggregator, e.g. the road agency), that its input lies in a public box, and only inputs whose
proof checks are added. A vehicle therefore moves the average of ``n`` accepted inputs by at most
``2 B_l / n`` in coordinate ``l``, whatever it sends.

Construction (Boneh, Boyle, Corrigan-Gibbs, Gilboa, Ishai, "Zero-knowledge proofs on secret-shared data
via fully linear PCPs", CRYPTO 2019; the FLP of draft-irtf-cfrg-vdaf, Prio3SumVec with a ParallelSum of Mul
gadgets; Corrigan-Gibbs and Boneh, "Prio", NSDI 2017). No Prio/VDAF library can be installed here (no
``vdaf-poc`` or equivalent in the package index), so it is written out below, over the prime field
``F_p``, ``p = 2^64 - 2^32 + 1`` (2-adicity 32, so NTTs of any power-of-two size), with Python ints in
numpy object arrays.

Encoding (:class:`ValidityEncoding`): coordinate ``l`` with public bound ``B_l`` gets
``b_l = ceil(log2(2 B_l / delta + 1))`` bits and the scale ``s_l = 2 B_l / (2^b_l - 1)`` (so that the
``b_l``-bit range is exactly ``[-B_l, B_l]``); ``u_l`` is sent as ``q_l = round((u_l + B_l) / s_l)`` in
``[0, 2^b_l)`` together with its bits. The input vector is ``x = (q_1..q_L, bits)``, length
``L + T``, ``T = sum b_l``.

Validity circuit: every bit ``x_j`` satisfies ``x_j (x_j - 1) = 0`` (checked as
``sum_j rho_j x_j (x_j - 1) = 0`` with joint randomness ``rho``), and ``q_l = sum_k 2^k bit_{l,k}``
(checked as ``sum_l s_l (q_l - sum_k 2^k bit_{l,k}) = 0``, a linear query with the aggregators' secret
``s``). The bits are grouped ``c`` per call of the gadget ``G(a_1, b_1, .., a_c, b_c) = sum_t a_t b_t``
(``a = rho_j x_j``, ``b = x_j - 1``), ``M = ceil(T / c)`` calls. The prover interpolates each of the
``2c`` wires on the ``P``-th roots of unity (``P >= M + 1``, a random seed at ``alpha^0`` for zero
knowledge) and sends the ``2P - 1`` coefficients of ``g = G(w_1, .., w_2c)``: the proof has
``2c + 2P - 1`` elements. Each aggregator evaluates, on its share, the wires and ``g`` at a random
``r`` outside the domain and the circuit output ``sum_i g(alpha^i)``; the two verifier shares are
exchanged and added; the input is accepted iff the output and the sum check are 0 and
``g(r) = G(w(r))``.

Soundness: a cheating vehicle is accepted with probability at most ``(2P - 2) / (p - P) + 2 / p`` per
attempt (Schwartz-Zippel on ``g - G(w)``, of degree ``<= 2P - 2``; the two random linear combinations),
about ``2^-54`` for ``P = 512``. ``rho`` is derived Fiat-Shamir style from both shares (Prio3's joint
randomness parts), so a vehicle that grinds ``2^k`` candidate inputs gains a factor ``2^k`` on the
``1 / p`` term only. ``r`` and ``s`` come from a key the two aggregators share and no vehicle knows.

Privacy (honest-verifier zero knowledge): ``B``'s share is expanded from a 16-byte seed and ``A``'s is
``x - XOF(seed)``, uniform to ``A``; with ``r`` outside the domain every ``w_k(r)`` is uniform (its seed),
``g(r)`` is a function of them and the two checks are 0 for an honest vehicle, so the joint verifier and
thus the other aggregator's verifier share is simulated without the input. The joint-randomness parts are
hashes of each share under a blind that only its aggregator sees (no dictionary test of guesses).
Privacy needs that ``A`` and ``B`` do not collude; the sum is correct only if neither deviates
(docs/security-secagg.md, threat model).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from dataclasses import field as dc_field

import numpy as np
from numpy.typing import ArrayLike

from .._validation import check_int, check_real
from ..errors import ParameterError
from ._prio_field import GOLDILOCKS, Field, _intt, _ntt

__all__ = ["Field", "GOLDILOCKS", "ValidityEncoding", "Proof", "prove", "query", "decide"]


@dataclass(frozen=True)
class ValidityEncoding:
    """The public box ``[-B_l, B_l]`` per coordinate, its fixed-point encoding and the FLP layout.

    Parameters
    ----------
    bounds : (L,) array_like
        ``B_l >= 0`` per coordinate, in the input's units (0: the coordinate must be 0).
    resolution : float
        Target step ``delta`` (same units); the actual step per coordinate is :attr:`scale`.
    chunk : int, optional
        ``c``, bits per gadget call; default ``ceil(sqrt(T))``.
    field : Field
    norm : float, optional
        ``R > 0``: also prove ``||u||_2 <= R`` (every non-zero bound must then be the same). With
        ``d_l = 2 q_l - (2^b - 1) = 2 u_l / s`` (exact integers) the circuit adds ``rho_0 (sum_l d_l^2 + v - N)``,
        ``N = floor((2 R / s)^2)``, the ``sum_l d_l^2`` from ``L`` more Mul-gadget inputs ``(rho_0 d_l, d_l)``
        and ``v`` a slack in ``[0, 2^bit_length(N))`` sent as bits after the coordinates' (so
        ``sum d_l^2 <= N``; libprio's Prio3FixedPointBoundedL2VecSum). No sum wraps modulo ``p``
        (checked: ``L (2^b)^2 + 2^bits(N) < p``).

    Attributes
    ----------
    bits : (L,) ndarray of int
        ``b_l``.
    scale : (L,) ndarray
        ``s_l = 2 B_l / (2^b_l - 1)`` (0 where ``b_l = 0``).
    """

    bounds: np.ndarray
    resolution: float
    chunk: int = 0
    field: Field = GOLDILOCKS
    norm: float = 0.0
    bits: np.ndarray = dc_field(init=False, repr=False)
    scale: np.ndarray = dc_field(init=False, repr=False)
    norm_q: int = dc_field(init=False, repr=False, default=0)
    slack_bits: int = dc_field(init=False, repr=False, default=0)

    def __post_init__(self) -> None:
        B = np.asarray(self.bounds, float).ravel()
        if B.size == 0 or not np.all(np.isfinite(B)) or np.any(B < 0):
            raise ParameterError(f"bounds must be a non-empty array of finite values >= 0, got {self.bounds!r}")
        d = check_real("resolution", self.resolution, low=0.0, low_open=True)
        bits = np.where(B > 0, np.ceil(np.log2(2 * B / d + 1)), 0).astype(np.int64)
        if int(bits.max()) > 48:
            raise ParameterError(f"bounds / resolution needs {int(bits.max())} bits, at most 48 (coarser resolution)")
        object.__setattr__(self, "bounds", B)
        object.__setattr__(self, "bits", bits)
        with np.errstate(divide="ignore", invalid="ignore"):
            object.__setattr__(self, "scale", np.where(bits > 0, 2 * B / (2.0 ** bits - 1), 0.0))
        if self.norm:
            self._norm_layout(B, bits)
        c = self.chunk or max(1, math.isqrt(max(self.n_pairs - 1, 0)) + 1)
        object.__setattr__(self, "chunk", check_int("chunk", c, low=1))

    def _norm_layout(self, B: np.ndarray, bits: np.ndarray) -> None:
        R = check_real("norm", self.norm, low=0.0, low_open=True)
        nz = B[B > 0]
        if nz.size == 0 or np.any(nz != nz[0]):
            raise ParameterError("norm: every non-zero bound must be the same (one fixed-point scale)")
        s = float(self.scale[B > 0][0])
        N = int(math.floor((2 * R / s) ** 2))
        if B.size * (2 ** int(bits.max())) ** 2 + 2 ** N.bit_length() >= self.field.p:
            raise ParameterError(f"norm: {B.size} squares of {int(bits.max())}-bit values wrap the field "
                                 "(coarser resolution or fewer coordinates)")
        object.__setattr__(self, "norm_q", N)
        object.__setattr__(self, "slack_bits", N.bit_length())

    @property
    def coordinate_bits(self) -> int:
        """``sum b_l``: the bits of the coordinates (without the norm slack)."""
        return int(self.bits.sum())

    @property
    def n_rho(self) -> int:
        """Elements of the joint randomness: one per bit, plus ``rho_0`` with a norm."""
        return self.n_bits + (1 if self.norm else 0)

    @property
    def n_pairs(self) -> int:
        """Inputs of the gadget: ``T`` bits, plus ``L`` squares with a norm."""
        return self.n_bits + (self.length if self.norm else 0)

    @property
    def honest_radius(self) -> float:
        """The largest ``||u||`` that stays inside the norm after rounding: ``(sqrt(N) - sqrt(L)) s / 2``."""
        s = float(np.max(self.scale))
        return max(0.0, (math.isqrt(self.norm_q) - math.sqrt(self.length)) * s / 2)

    def onto_ball(self, u: ArrayLike) -> tuple[np.ndarray, bool]:
        """``u`` scaled down onto :attr:`honest_radius` if longer (what an honest vehicle sends), and whether it was.

        Parameters
        ----------
        u : (L,) array_like
            Input, finite.
        """
        u = np.asarray(u, float).ravel()
        r, n = self.honest_radius, float(np.sqrt(np.sum(u * u)))
        return (u, False) if n <= r else (u * (r / n), True)

    @property
    def length(self) -> int:
        """``L``, coordinates."""
        return self.bounds.size

    @property
    def n_bits(self) -> int:
        """``T = sum b_l``, plus the norm slack's bits."""
        return self.coordinate_bits + self.slack_bits

    @property
    def calls(self) -> int:
        """``M = ceil(pairs / c)`` gadget calls (at least 1)."""
        return max(1, -(-self.n_pairs // self.chunk))

    @property
    def domain(self) -> int:
        """``P``: the smallest power of two ``>= M + 1``."""
        return 1 << self.calls.bit_length()

    @property
    def proof_length(self) -> int:
        """Elements of a proof: ``2c`` wire seeds and ``2P - 1`` coefficients of ``g``."""
        return 2 * self.chunk + 2 * self.domain - 1

    def max_fleet(self) -> int:
        """Most inputs whose sum of ``q`` cannot wrap modulo ``p``."""
        return (self.field.p - 1) // (2 ** int(self.bits.max()) - 1 if self.bits.max() else 1)

    def clip(self, u: ArrayLike) -> tuple[np.ndarray, int]:
        """``u`` clipped into the box (what an honest vehicle sends) and how many coordinates were outside.

        Parameters
        ----------
        u : (L,) array_like
            Input, finite.
        """
        u = np.asarray(u, float).ravel()
        if u.shape != self.bounds.shape or not np.all(np.isfinite(u)):
            raise ParameterError(f"the input must be {self.length} finite values, got shape {u.shape}")
        return np.clip(u, -self.bounds, self.bounds), int(np.sum(np.abs(u) > self.bounds))

    def encode(self, u: ArrayLike) -> np.ndarray:
        """``x = (q, bits)`` of an input inside the box, object array of length ``L + T``.

        Parameters
        ----------
        u : (L,) array_like
            Input inside the box.

        Raises
        ------
        ParameterError
            A coordinate outside ``[-B_l, B_l]`` (clip first: :meth:`clip`).
        """
        u, outside = self.clip(u)
        if outside:
            raise ParameterError(f"{outside} coordinates of the input are outside the public bounds")
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(self.bits > 0, np.rint((u + self.bounds) / self.scale), 0).astype(np.int64)
        if self.norm and self.squares(q) > self.norm_q:
            raise ParameterError(f"the input's norm is outside the public bound {self.norm:g} (onto_ball first)")
        return self.encode_raw(q)

    def squares(self, q: ArrayLike) -> int:
        """``sum_l d_l^2``, ``d_l = 2 q_l - (2^b_l - 1)``: the norm check's integer (``(2 ||u|| / s)^2``).

        Parameters
        ----------
        q : (L,) array_like of int
            Offset values.
        """
        return sum((2 * int(v) - (1 << int(b)) + 1) ** 2 for v, b in zip(np.asarray(q).ravel(), self.bits))

    def quantize(self, u: ArrayLike) -> np.ndarray:
        """What the aggregate holds of an input inside the box: ``q s - B`` per coordinate, (L,) float.

        Parameters
        ----------
        u : (L,) array_like
            Input inside the box.
        """
        u, outside = self.clip(u)
        if outside:
            raise ParameterError(f"{outside} coordinates of the input are outside the public bounds")
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.where(self.bits > 0, np.rint((u + self.bounds) / self.scale), 0.0)
        out: np.ndarray = q * self.scale - np.where(self.bits > 0, self.bounds, 0.0)
        return out

    def encode_raw(self, q: ArrayLike, bits: Sequence[int] | None = None) -> np.ndarray:
        """``x`` from integer values ``q`` and (default: the true) bits; a cheater's tool in tests.

        Parameters
        ----------
        q : (L,) array_like of int
            Offset values.
        bits : sequence of int, optional
            ``T`` bits (any field elements); default the bits of ``q``.
        """
        q = [int(v) for v in np.asarray(q).ravel()]
        if bits is None:
            bits = [(v >> k) & 1 for v, b in zip(q, self.bits) for k in range(int(b))]
            # The slack N - sum d^2 (modulo its range if the norm is exceeded: a cheater's best guess).
            v = (self.norm_q - self.squares(q)) % (1 << self.slack_bits) if self.norm else 0
            bits += [(v >> k) & 1 for k in range(self.slack_bits)]
        return np.array(q + [int(b) for b in bits], dtype=object) % self.field.p

    def decode_sum(self, total_q: np.ndarray, n: int) -> np.ndarray:
        """``sum u`` of ``n`` inputs from the sum of their ``q`` (integers in ``[0, p)``), (L,) float.

        Parameters
        ----------
        total_q : (L,) array_like of int
            Combined sum of the ``q``.
        n : int
            Inputs summed.
        """
        t = np.array([int(v) for v in total_q], float)
        out: np.ndarray = t * self.scale - n * self.bounds
        return out

    def weights(self) -> np.ndarray:
        """``(L, T)``-free form of ``q_l - sum_k 2^k bit_{l,k}``: the power ``2^k`` of every bit, (T,)."""
        return np.array([1 << k for b in self.bits for k in range(int(b))], dtype=object)

    def owner(self) -> np.ndarray:
        """Coordinate ``l`` of every bit, (T,) int."""
        return np.repeat(np.arange(self.length), self.bits)


@dataclass(frozen=True)
class Proof:
    """An FLP proof (or a share of one): ``2c`` wire seeds, then the ``2P - 1`` coefficients of ``g``."""

    elements: np.ndarray


def _wires(enc: ValidityEncoding, x: np.ndarray, rho: np.ndarray, leader: bool) -> np.ndarray:
    """Wire values (shares) at the call points: ``(2c, M)``; ``a = rho x``, ``b = x - 1`` (the 1 is the leader's)
    for every bit, then ``a = rho_0 d``, ``b = d`` for every coordinate with a norm (``d = 2 q - (2^b - 1)``)."""
    p, c, M, L, T = enc.field.p, enc.chunk, enc.calls, enc.length, enc.n_bits
    one = 1 if leader else 0
    bits = x[L:]
    a, b = bits * rho[:T] % p, (bits - one) % p
    if enc.norm:
        off = np.array([(1 << int(k)) - 1 for k in enc.bits], dtype=object) * one
        d = (2 * x[:L] - off) % p
        a, b = np.concatenate([a, d * int(rho[T]) % p]), np.concatenate([b, d])
    pad = c * M - a.size
    a = np.concatenate([a, np.zeros(pad, dtype=object)])
    b = np.concatenate([b, np.full(pad, (-one) % p, dtype=object)])
    w = np.empty((2 * c, M), dtype=object)
    w[0::2] = a.reshape(M, c).T
    w[1::2] = b.reshape(M, c).T
    return w


def prove(enc: ValidityEncoding, x: np.ndarray, rho: np.ndarray, seeds: np.ndarray) -> Proof:
    """The FLP proof of ``x`` (module docstring).

    Parameters
    ----------
    enc : ValidityEncoding
    x : (L + T,) object ndarray
        From :meth:`ValidityEncoding.encode`.
    rho : (T,) object ndarray
        Joint randomness (:attr:`ValidityEncoding.n_rho` elements).
    seeds : (2c,) object ndarray
        Uniform wire seeds (zero knowledge).

    Returns
    -------
    Proof
    """
    f, P, M = enc.field, enc.domain, enc.calls
    vals = np.zeros((2 * enc.chunk, P), dtype=object)
    vals[:, 0] = seeds
    vals[:, 1:M + 1] = _wires(enc, x, rho, True)
    coef = _intt(vals, f.root(P), f)
    ext = np.zeros((2 * enc.chunk, 2 * P), dtype=object)
    ext[:, :P] = coef
    ev = _ntt(ext, f.root(2 * P), f.p)
    g_vals = (ev[0::2] * ev[1::2]).sum(axis=0) % f.p
    g = _intt(g_vals[None, :], f.root(2 * P), f)[0]
    return Proof(np.concatenate([np.asarray(seeds, dtype=object), g[:2 * P - 1]]))


def _lagrange(f: Field, P: int, r: int) -> np.ndarray:
    """Barycentric weights ``lambda_i(r)`` of the ``P``-th roots of unity, (P,)."""
    p, a = f.p, f.root(P)
    pts = [pow(a, i, p) for i in range(P)]
    k = (pow(r, P, p) - 1) * f.inv(P) % p
    return np.array([pi * k * f.inv((r - pi) % p) % p for pi in pts], dtype=object)


def query(enc: ValidityEncoding, x: np.ndarray, proof: Proof, rho: np.ndarray, r: int, s: np.ndarray,
          leader: bool) -> np.ndarray:
    """One aggregator's verifier share: ``(w_1(r), ..., w_2c(r), g(r), sum_i g(alpha^i), sum check)``.

    Parameters
    ----------
    enc : ValidityEncoding
    x : (L + T,) object ndarray
        This aggregator's share of the input.
    proof : Proof
        Its share of the proof.
    rho : (T,) object ndarray
    r : int
        Query point, ``r^P != 1``.
    s : (L,) object ndarray
        Coefficients of the sum check.
    leader : bool
        Whether this is aggregator ``A`` (which adds the circuit's constants).

    Returns
    -------
    (2c + 3,) object ndarray
    """
    f, P, M, c, L = enc.field, enc.domain, enc.calls, enc.chunk, enc.length
    p = f.p
    pi = proof.elements
    vals = np.zeros((2 * c, P), dtype=object)
    vals[:, 0] = pi[:2 * c]
    vals[:, 1:M + 1] = _wires(enc, x, rho, leader)
    w_r = vals.dot(_lagrange(f, P, r)) % p
    g = pi[2 * c:]
    g_r = 0
    for coef in g[::-1]:
        g_r = (g_r * r + int(coef)) % p
    folded = np.zeros(P, dtype=object)
    folded[:] = g[:P]
    folded[:P - 1] = (folded[:P - 1] + g[P:]) % p
    out = int(_ntt(folded[None, :], f.root(P), p)[0, 1:M + 1].sum() % p)
    Tc = enc.coordinate_bits
    if enc.norm:             # + rho_0 (v - N): the squares plus the slack must be N
        v = sum(int(xb) << k for k, xb in enumerate(x[L + Tc:]))
        out = (out + int(rho[enc.n_bits]) * (v - (enc.norm_q if leader else 0))) % p
    weights = enc.weights()
    dec = np.zeros(L, dtype=object)
    np.add.at(dec, enc.owner(), x[L:L + Tc] * weights % p)
    check = int(((x[:L] - dec) % p * s).sum() % p)
    return np.concatenate([w_r, np.array([g_r, out, check], dtype=object)])


def decide(enc: ValidityEncoding, verifier: np.ndarray) -> str:
    """``""`` if the joint verifier (sum of both shares) accepts, else what failed.

    Parameters
    ----------
    enc : ValidityEncoding
    verifier : (2c + 3,) object ndarray
        Sum of both aggregators' :func:`query` results.
    """
    p, c = enc.field.p, enc.chunk
    v = verifier % p
    w, g_r, out, check = v[:2 * c], v[2 * c], v[2 * c + 1], v[2 * c + 2]
    if check != 0:
        return "its values are not the sums of its bits"
    if out != 0:
        return "the circuit output is not 0 (a bit is not 0 or 1, a norm over its bound, or a wrong proof)"
    if (w[0::2] * w[1::2]).sum() % p != g_r:
        return "the proof does not match the wires"
    return ""
