"""Frequency responses from a block-diagonalised Schur form (Bavely-Stewart).

``A = U R U^H`` (complex Schur form) is reordered so that close eigenvalues sit next to each other,
and then decoupled cluster by cluster: for ``R = [[R11, R12], [0, R22]]`` the triangular Sylvester
equation ``R11 X - X R22 = -R12`` gives ``Y = [[I, X], [0, I]]`` with ``Y^-1 R Y = diag(R11, R22)``.
A split is made only when ``||X||_F <= max_coupling``, so the whole transformation has a bounded
condition number; a cluster that cannot be decoupled well is merged with the nearest cluster after
it and the pass is repeated (in the worst case everything is one block: the plain Schur back
substitution). Each bin then costs
``O(sum of block sizes^2)`` instead of ``O(n^2)``: one ``1 / (z - lambda)`` product per isolated
eigenvalue and a short back substitution per cluster.

Why not eigenvectors: the vehicles' ``T = (I - P D) P`` carries the plant's poles twice, so the
obfuscated ``T~ = Psi1 T`` is close to defective and its eigenvector matrix is ill-conditioned
(pole-residue evaluation was off by 1e-8 in the estimate). Here such a pair stays one triangular
2x2 block, evaluated by back substitution like the Schur path.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from scipy.linalg import lapack

from ._cert_kernel import complex_schur as _compiled_schur
from ._eval_kernel import block_eval
from .kernels import kernel_path
from ._blockdiag_kernel import block_form as _compiled_block_form, clusters as _compiled_clusters
from ._blockdiag_kernel import decouple as _compiled_decouple

__all__ = ["MAX_COUPLING", "CLUSTER_TOL", "CLUSTER_REL", "SMALL_BLOCK", "BlockSchur", "block_schur", "block_response",
           "complex_schur"]

#: Largest ``||X||_F`` of one decoupling step (module docstring); larger splits are merged. Measured on
#: 26 obfuscated T~, S~ (order 12-22) against a 40-digit reference: with 1e2 the largest per-bin
#: error equals the full Schur path's in every case (5e-13..3e-11), with blocks of 2 and now and then
#: one merged block of 4-14 (S~, when the plant's heave and roll poles sit 2e-3 apart near z = 1);
#: 1e4 split everything into blocks of 2 but was 4.8x less accurate on one S~; 10 hardly split S~.
MAX_COUPLING = 1e2
#: Blocks up to this size are evaluated through their resolvent entries, larger ones by back substitution.
SMALL_BLOCK = 4
#: Eigenvalues closer than this (absolute, in the z-plane) are put in one cluster before decoupling.
CLUSTER_TOL = 1e-3
#: Eigenvalues closer than this fraction of their distance to the unit circle are put in one cluster too:
#: seen from every point ``z`` on the circle they are nearly one repeated eigenvalue, and splitting them
#: gives blocks whose contributions ``Cw_b (z I - R_b)^-1 Bw_b`` cancel. Measured on bench segment 133 (the
#: 300-segment exactness stream, vehicle 2's ``S~``, order 18): real eigenvalues 0.9776, 0.9812 and 0.9828
#: (each twice), 1.6e-3 to 5e-3 apart at 0.02 from the circle, were split into three blocks whose
#: contributions were 1.4e7-3.3e7 at a bin where ``|H| = 10``; the response was 1.3e-9 (compiled) and up to
#: 9.4e-10 (numpy) off a 40-digit evaluation, each block's own error being round-off (2e-16 of its size).
#: One block of the eight: 1.7e-10 and 1.6e-10. 0.1 still split them (1.2e-9).
CLUSTER_REL = 0.25


class BlockSchur:
    """``A = W diag(R_1, ..., R_k) W^-1`` with ``B_w = W^-1 B``, ``C_w = C W`` (complex), as blocks.

    Attributes
    ----------
    R : (n, n) complex ndarray
        Block upper-triangular with zero coupling between blocks (only the diagonal blocks are used).
    Bw : (n, m) complex ndarray
    Cw : (p, n) complex ndarray
    blocks : list of (int, int)
        ``[start, stop)`` of each diagonal block.
    schur : (T, U)
        The complex Schur form ``A = U T U^H`` the blocks were computed from (before reordering).
    """

    def __init__(self, R: np.ndarray, Bw: np.ndarray, Cw: np.ndarray, blocks: list[tuple[int, int]],
                 schur: tuple[np.ndarray, np.ndarray]) -> None:
        self.R, self.Bw, self.Cw, self.blocks, self.schur = R, Bw, Cw, blocks, schur


def _clusters(lam: np.ndarray, tol: float, rel: float = CLUSTER_REL) -> list[list[int]]:
    """Single-linkage clusters of eigenvalues closer than ``tol`` or than ``rel`` times the distance of
    the nearer one to the unit circle (connected components of the graph
    ``|lam_i - lam_k| <= max(tol, rel min(d_i, d_k))``, ``d_i = |1 - |lam_i||``, by label propagation),
    each in ascending index order, ordered by their first index."""
    n = lam.size
    d = np.abs(1.0 - np.abs(lam))
    close = np.abs(lam[:, None] - lam[None, :]) <= np.maximum(tol, rel * np.minimum(d[:, None], d[None, :]))
    label = np.arange(n)
    while True:
        new = np.where(close, label[None, :], n).min(axis=1)
        if np.array_equal(new, label):
            break
        label = new
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(int(label[i]), []).append(i)
    return sorted(groups.values(), key=lambda g: g[0])


def _reorder(T: np.ndarray, U: np.ndarray, clusters: list[list[int]]) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Move each cluster's eigenvalues next to each other (LAPACK ``ztrexc``); cluster sizes in order."""
    pos = list(range(T.shape[0]))          # pos[i]: current place of the eigenvalue first at i
    target = 0
    for group in clusters:
        for i in group:
            src = pos[i]
            if src != target:
                T, U, info = lapack.ztrexc(T, U, src + 1, target + 1)
                if info != 0:
                    raise np.linalg.LinAlgError(f"ztrexc failed (info={info})")
                # Eigenvalues between target and src shift one place down.
                pos = [p + 1 if target <= p < src else (target if p == src else p) for p in pos]
            target += 1
    return T, U, [len(g) for g in clusters]


def block_schur(A: np.ndarray, B: np.ndarray, C: np.ndarray, *, schur: tuple[np.ndarray, np.ndarray] | None = None,
                max_coupling: float = MAX_COUPLING, cluster_tol: float = CLUSTER_TOL,
                cluster_rel: float = CLUSTER_REL) -> BlockSchur:
    """Block-diagonalise ``(A, B, C)`` (module docstring).

    Parameters
    ----------
    A : (n, n) ndarray
    B : (n, m) ndarray
    C : (p, n) ndarray
    schur : (T, U), optional
        A complex Schur form ``A = U T U^H`` already computed (it is not modified).
    max_coupling : float
        Largest ``||X||_F`` of a decoupling step.
    cluster_tol : float
        Eigenvalues closer than this are kept in one cluster from the start.
    cluster_rel : float
        So are eigenvalues closer than this fraction of their distance to the unit circle
        (:data:`CLUSTER_REL`).

    Returns
    -------
    BlockSchur
    """
    A = np.asarray(A, dtype=float)
    T0, U0 = scipy.linalg.schur(A, output="complex") if schur is None else schur
    if kernel_path() == "compiled" and T0.shape[0] > 0:
        # The loop below in one compiled call, the same clusters, merges and bits (_blockdiag_kernel.block_form):
        # its Python glue cost about 30 of 50 us per obfuscated T~, S~ (docs/speed.md, "Eleventh pass").
        R, Bw, Cw, blocks = _compiled_block_form(T0, U0, B, C, cluster_tol, cluster_rel, max_coupling)
        return BlockSchur(R, Bw, Cw, blocks, (T0, U0))
    lam = np.diag(T0)
    if kernel_path() == "compiled":
        clusters = _compiled_clusters(lam, cluster_tol, cluster_rel)
    else:
        clusters = _clusters(lam, cluster_tol, cluster_rel)
    while True:
        out = _decouple(T0, U0, B, C, clusters, max_coupling)
        if isinstance(out, BlockSchur):
            return out
        # Cluster ``out`` could not be split from the ones after it: merge it with the nearest of
        # those (Bavely-Stewart) and start again. Nearly always done in one pass (at most two or
        # three merges for the obfuscated T~ and S~).
        rest = clusters[out + 1:]
        dist = [np.min(np.abs(lam[clusters[out]][:, None] - lam[c][None, :])) for c in rest]
        near = rest[int(np.argmin(dist))]
        clusters = [sorted(c + near) if k == out else c for k, c in enumerate(clusters) if c is not near]


def _decouple(T0: np.ndarray, U0: np.ndarray, B: np.ndarray, C: np.ndarray, clusters: list[list[int]],
              max_coupling: float) -> BlockSchur | int:
    """One pass of :func:`block_schur`: the form, or the index of the first cluster whose split
    from the rest failed (``||X||_F > max_coupling`` or the Sylvester solve failed). On the compiled
    path the same pass is one call (:mod:`~roadcollab.lti._blockdiag_kernel`)."""
    if kernel_path() == "compiled":
        status, T, _, Bw, Cw = _compiled_decouple(T0, U0, B, C, clusters, max_coupling)
        if status >= 0:
            return status
        bounds = np.cumsum([0] + [len(g) for g in clusters])
        return BlockSchur(T, Bw, Cw, [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])], (T0, U0))
    T, U, sizes = _reorder(T0.copy(), U0.copy(), clusters)
    n = T.shape[0]
    Bw = U.conj().T @ np.asarray(B, dtype=complex)
    Cw = np.asarray(C, dtype=complex) @ U
    blocks, start = [], 0
    for k, size in enumerate(sizes[:-1]):
        stop = start + size
        X, scale, info = lapack.ztrsyl(T[start:stop, start:stop], T[stop:, stop:], -T[start:stop, stop:], isgn=-1)
        if info != 0 or scale != 1.0 or not np.linalg.norm(X) <= max_coupling:
            return k
        Bw[start:stop] -= X @ Bw[stop:]
        Cw[:, stop:] += Cw[:, start:stop] @ X
        T[start:stop, stop:] = 0.0
        blocks.append((start, stop))
        start = stop
    blocks.append((start, n))
    return BlockSchur(T, Bw, Cw, blocks, (T0, U0))


def block_response(bs: BlockSchur, D: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``C (zI - A)^-1 B + D`` at points ``z`` from a :func:`block_schur` form, (M, p, m).

    Parameters
    ----------
    bs : BlockSchur
    D : (p, m) ndarray
    z : (M,) complex ndarray

    Returns
    -------
    (M, p, m) complex ndarray
    """
    R, Bw, Cw = bs.R, bs.Bw, bs.Cw
    if kernel_path() == "compiled":
        # One pass over the bins, per-bin back substitution in registers (lti.kernels): 4x faster
        # than the products below for the obfuscated T~, S~ (measured, see docs/speed.md).
        return block_eval(R, Bw, Cw, np.asarray(D, dtype=float), bs.blocks, z)
    p, m = Cw.shape[0], Bw.shape[1]
    # A block of size k <= SMALL_BLOCK contributes through its resolvent entries, each a product
    # of g_i = 1 / (z - R_ii) (paths through the triangular block); all of them, with the
    # residues C_i B_l, go into one matrix product. A larger (merged) block is solved by back
    # substitution over every z at once, O(k) vector operations instead of O(k^3).
    small = [b for b in bs.blocks if b[1] - b[0] <= SMALL_BLOCK]
    idx = np.concatenate([np.arange(*b) for b in small]) if small else np.zeros(0, int)
    # np.reciprocal, not 1.0 / x: numpy's complex division is Smith's algorithm, 7x slower here
    # (1.2 ms vs 0.18 ms for 3000 x 18, measured).
    lam = np.diag(R)[idx]
    pos = {int(i): c for c, i in enumerate(idx)}
    pairs = [(i0, i0 + 1) for i0, i1 in small if i1 - i0 == 2]
    # Rows of G: g_i for every eigenvalue of a small block, then one resolvent entry per path.
    left, right = list(idx), list(idx)
    G = np.empty((idx.size + len(pairs) + sum((i1 - i0) ** 2 for i0, i1 in small if i1 - i0 > 2), z.size), complex)
    np.reciprocal(z[None, :] - lam[:, None], out=G[:idx.size])
    if pairs:     # 2x2 blocks, all at once: N_01 = g_0 R_01 g_1
        i, l = np.array(pairs).T
        rows_2 = G[idx.size:idx.size + len(pairs)]
        np.multiply(R[i, l][:, None], G[[pos[k] for k in i]], out=rows_2)
        rows_2 *= G[[pos[k] for k in l]]
        left += list(i)
        right += list(l)
    used = idx.size + len(pairs)
    for i0, i1 in (b for b in small if b[1] - b[0] > 2):
        for l in range(i0 + 1, i1):
            N = {l: G[pos[l]]}
            for i in range(l - 1, i0 - 1, -1):
                acc = sum(R[i, j] * N[j] for j in range(i + 1, l + 1))
                N[i] = G[used]
                np.multiply(acc, G[pos[i]], out=N[i])
                left.append(i)
                right.append(l)
                used += 1
    Res = (Cw[:, left].T[:, :, None] * Bw[right][:, None, :]).reshape(len(left), p * m)
    H: np.ndarray = (G[:used].T @ Res).reshape(z.size, p, m)
    for i0, i1 in bs.blocks:
        k = i1 - i0
        if k <= SMALL_BLOCK:
            continue
        Rb = R[i0:i1, i0:i1]
        X = np.empty((k, m, z.size), complex)
        inv_diag = np.reciprocal(z[None, :] - np.diag(Rb)[:, None])
        for i in range(k - 1, -1, -1):
            acc = np.repeat(Bw[i0 + i][:, None], z.size, axis=1)
            if i + 1 < k:
                acc += (Rb[i, i + 1:] @ X[i + 1:].reshape(k - i - 1, m * z.size)).reshape(m, z.size)
            X[i] = acc * inv_diag[i]
        H += (Cw[:, i0:i1] @ X.reshape(k, m * z.size)).reshape(p, m, z.size).transpose(2, 0, 1)
    H += D
    return H


def complex_schur(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A complex Schur form ``A = U T U^H`` of a real ``A``: ``zgees`` (scipy) on the reference path; on the
    compiled path ``dgees`` and compiled Givens rotations (0.37 -> 0.18 ms at n = 22, docs/speed.md, "Third pass").

    Parameters
    ----------
    A : (n, n) real ndarray

    Returns
    -------
    T, U : (n, n) complex ndarray
    """
    if kernel_path() == "compiled" and A.shape[0] > 0 and np.isfinite(A).all():
        T, U = _compiled_schur(A)
    else:
        T, U = scipy.linalg.schur(A, output="complex")
    return np.asarray(T), np.asarray(U)
