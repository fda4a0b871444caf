"""Compiled (numba) pass of the Bavely-Stewart block diagonalisation (:mod:`~roadcollab.lti.blockdiag`,
the ``"compiled"`` path of :mod:`~roadcollab.lti.kernels`).

One call does what :func:`~roadcollab.lti.blockdiag._decouple` does with a Python loop over LAPACK
calls: the reordering of the complex Schur form (adjacent swaps by Givens rotations, the algorithm of
LAPACK ``ztrexc``), ``Bw = U^H B``, ``Cw = C U``, and per split the triangular Sylvester equation
``R11 X - X R22 = -R12`` (the column-by-column substitution of LAPACK ``ztrsyl``, with its test of a
near-singular pivot), the coupling test ``||X||_F <= max_coupling`` and the updates of ``Bw``, ``Cw``.
The numpy path took 0.27-0.34 ms per obfuscated ``T~`` or ``S~`` in that loop's Python glue and small
LAPACK calls (docs/speed.md, "Fourth pass"). The result differs from the LAPACK path by round-off only
(another rounding of the same rotations and substitutions).

Plain loops over complex scalars: numba's array expressions cost seconds of first-run compilation each.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .kernels import compiled_available, jit_options, read_only

__all__ = ["decouple", "clusters", "block_form"]

_KERNEL: dict[str, Any] = {}

#: The functions compiled by :func:`_build` (rebound in place, so compiled callers find compiled callees).
_COMPILED_NAMES = ("_swap", "_sylvester", "_decouple_pass", "_cluster_labels", "_block_form")
#: Those only compiled kernels call (no entry point from Python: :func:`~roadcollab.lti.kernels.jit_options`).
_INTERNAL_NAMES = ("_swap", "_sylvester")


def _build() -> dict[str, Any]:
    """The compiled pass (``None`` without numba); numba is imported on first use."""
    if _KERNEL:
        return _KERNEL
    if not compiled_available():
        _KERNEL.update(decouple=None, labels=None, form=None)
        return _KERNEL
    import numba

    for name in _COMPILED_NAMES:
        globals()[name] = numba.njit(**jit_options(internal=name in _INTERNAL_NAMES))(globals()[name])
    _KERNEL.update(decouple=globals()["_decouple_pass"], labels=globals()["_cluster_labels"],
                   form=globals()["_block_form"])
    return _KERNEL


def _cluster_labels(lam: np.ndarray, tol: float, rel: float) -> np.ndarray:   # pragma: no cover - compiled
    """Per eigenvalue the smallest index of its connected component in the graph
    ``|lam_i - lam_k| <= max(tol, rel min(d_i, d_k))``, ``d_i = |1 - |lam_i||`` (the fixed point of
    :func:`~roadcollab.lti.blockdiag._clusters`' label propagation)."""
    n = lam.size
    d = np.empty(n)
    for i in range(n):
        d[i] = abs(1.0 - abs(lam[i]))
    label = np.arange(n)
    changed = True
    while changed:
        changed = False
        for i in range(n):
            for k in range(n):
                if label[k] < label[i] and abs(lam[i] - lam[k]) <= max(tol, rel * min(d[i], d[k])):
                    label[i] = label[k]
                    changed = True
    return label


def _swap(T: np.ndarray, U: np.ndarray, k: int) -> None:   # pragma: no cover - compiled
    """Swap the diagonal entries ``k``, ``k + 1`` of the upper triangular ``T`` (``ztrexc``'s step):
    the rotation ``[[c, s], [-conj(s), c]]`` that zeroes ``(T_k,k+1, T_k+1,k+1 - T_kk)`` (``zlartg``),
    applied to rows ``k, k+1`` right of the pair, to columns ``k, k+1`` above it and to ``U``."""
    n = T.shape[0]
    t11 = T[k, k]
    t22 = T[k + 1, k + 1]
    f = T[k, k + 1]
    g = t22 - t11
    af = abs(f)
    ag = abs(g)
    if ag == 0.0:
        c = 1.0
        s = 0.0 + 0.0j
    elif af == 0.0:
        c = 0.0
        s = np.conj(g) / ag
    else:
        d = np.sqrt(af * af + ag * ag)
        c = af / d
        s = (f / af) * np.conj(g) / d
    for j in range(k + 2, n):                   # rows k, k+1: zrot(cs, sn)
        x, y = T[k, j], T[k + 1, j]
        T[k, j] = c * x + s * y
        T[k + 1, j] = c * y - np.conj(s) * x
    sc = np.conj(s)
    for i in range(k):                          # columns k, k+1: zrot(cs, conj(sn))
        x, y = T[i, k], T[i, k + 1]
        T[i, k] = c * x + sc * y
        T[i, k + 1] = c * y - s * x
    T[k, k] = t22
    T[k + 1, k + 1] = t11
    for i in range(n):
        x, y = U[i, k], U[i, k + 1]
        U[i, k] = c * x + sc * y
        U[i, k + 1] = c * y - s * x


def _sylvester(T: np.ndarray, start: int, stop: int, X: np.ndarray) -> bool:   # pragma: no cover - compiled
    """``X`` (``stop - start`` by ``n - stop``) of ``R11 X - X R22 = -R12`` for the blocks of ``T``
    split at ``[start, stop)``, by ``ztrsyl``'s substitution (columns forward, rows backward). False
    when a pivot ``R11_kk - R22_ll`` is at most ``ztrsyl``'s ``smin`` (LAPACK then perturbs it and
    reports ``info = 1``; the caller merges the blocks instead)."""
    n = T.shape[0]
    m1 = stop - start
    m2 = n - stop
    amax = 0.0
    for i in range(start, stop):
        for j in range(i, stop):
            amax = max(amax, abs(T[i, j]))
    bmax = 0.0
    for i in range(stop, n):
        for j in range(i, n):
            bmax = max(bmax, abs(T[i, j]))
    eps = np.finfo(np.float64).eps              # dlamch('P'), as ztrsyl
    smlnum = np.finfo(np.float64).tiny * (m1 * m2) / eps
    smin = max(smlnum, eps * amax, eps * bmax)
    for l in range(m2):
        for k in range(m1 - 1, -1, -1):
            acc = -T[start + k, stop + l]
            for j in range(k + 1, m1):          # suml = R11[k, k+1:] X[k+1:, l]
                acc -= T[start + k, start + j] * X[j, l]
            for j in range(l):                  # sgn * sumr = -X[k, :l] R22[:l, l]
                acc += X[k, j] * T[stop + j, stop + l]
            a11 = T[start + k, start + k] - T[stop + l, stop + l]
            if abs(a11.real) + abs(a11.imag) <= smin:
                return False
            X[k, l] = acc / a11
    return True


def _decouple_pass(T: np.ndarray, U: np.ndarray, B: np.ndarray, C: np.ndarray, order: np.ndarray,
                   sizes: np.ndarray, max_coupling: float, Bw: np.ndarray, Cw: np.ndarray) -> int:   # pragma: no cover - compiled
    """One pass of :func:`~roadcollab.lti.blockdiag._decouple` on ``T``, ``U`` (copies, changed in
    place): reorder to ``order`` (the clusters' eigenvalue indices, concatenated), form ``Bw``, ``Cw``,
    split after every cluster of ``sizes`` but the last. -1 on success, else the index of the first
    cluster whose split failed."""
    n = T.shape[0]
    pos = np.arange(n)                          # pos[i]: current place of the eigenvalue first at i
    for target in range(n):
        src = pos[order[target]]
        if src != target:
            for k in range(src - 1, target - 1, -1):
                _swap(T, U, k)
            for i in range(n):
                if target <= pos[i] < src:
                    pos[i] += 1
                elif pos[i] == src:
                    pos[i] = target
    for i in range(n):                          # Bw = U^H B, Cw = C U
        for j in range(B.shape[1]):
            acc = 0.0 + 0.0j
            for r in range(n):
                acc += np.conj(U[r, i]) * B[r, j]
            Bw[i, j] = acc
    for i in range(C.shape[0]):
        for j in range(n):
            acc = 0.0 + 0.0j
            for r in range(n):
                acc += C[i, r] * U[r, j]
            Cw[i, j] = acc
    start = sizes.size * 0           # int64, not Literal[int](0): one specialisation of _sylvester
    for c in range(sizes.size - 1):
        stop = start + sizes[c]
        X = np.empty((stop - start, n - stop), dtype=np.complex128)
        if not _sylvester(T, start, stop, X):
            return c
        norm2 = 0.0
        for i in range(stop - start):
            for j in range(n - stop):
                norm2 += X[i, j].real ** 2 + X[i, j].imag ** 2
        if not np.sqrt(norm2) <= max_coupling:
            return c
        for i in range(stop - start):           # Bw[start:stop] -= X Bw[stop:]
            for j in range(Bw.shape[1]):
                acc = 0.0 + 0.0j
                for r in range(n - stop):
                    acc += X[i, r] * Bw[stop + r, j]
                Bw[start + i, j] -= acc
        for i in range(Cw.shape[0]):            # Cw[:, stop:] += Cw[:, start:stop] X
            for j in range(n - stop):
                acc = 0.0 + 0.0j
                for r in range(stop - start):
                    acc += Cw[i, start + r] * X[r, j]
                Cw[i, stop + j] += acc
        for i in range(start, stop):
            for j in range(stop, n):
                T[i, j] = 0.0
        start = stop
    return -1


def _block_form(T0: np.ndarray, U0: np.ndarray, B: np.ndarray, C: np.ndarray, tol: float, rel: float,
                max_coupling: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:   # pragma: no cover - compiled
    """The whole of :func:`~roadcollab.lti.blockdiag.block_schur` after the Schur form, in one call: the
    clusters of :func:`_cluster_labels` (ordered by their first index, each ascending, as
    :func:`clusters`), then :func:`_decouple_pass` until it succeeds, a failed cluster merged with the
    nearest cluster after it (the smallest ``|lam_i - lam_k|``, the first on a tie, NaN first as
    ``numpy.argmin``) as the Python loop does. Returns the pass's ``R``, ``Bw``, ``Cw`` and the cluster
    sizes."""
    # Long: the clustering, the passes and the merges in one compiled body; split into callees, numba compiles
    # each callee's code into every caller again (docs/speed.md, "Eleventh pass", "Twelfth pass").
    n = T0.shape[0]
    lam = np.empty(n, dtype=np.complex128)
    for i in range(n):
        lam[i] = T0[i, i]
    label = _cluster_labels(lam, tol, rel)
    order = np.empty(n, dtype=np.int64)         # the clusters' indices, concatenated
    sizes = np.empty(n, dtype=np.int64)
    nc = 0
    pos = 0
    for lab in range(n):                        # a label is its cluster's first index
        cnt = 0
        for i in range(n):
            if label[i] == lab:
                order[pos] = i
                pos += 1
                cnt += 1
        if cnt:
            sizes[nc] = cnt
            nc += 1
    Bw = np.empty((n, B.shape[1]), dtype=np.complex128)
    Cw = np.empty((C.shape[0], n), dtype=np.complex128)
    while True:
        T = T0.copy()
        U = U0.copy()
        out = _decouple_pass(T, U, B, C, order, sizes[:nc].copy(), max_coupling, Bw, Cw)
        if out < 0:
            return T, Bw, Cw, sizes[:nc].copy()
        starts = np.empty(nc + 1, dtype=np.int64)
        starts[0] = 0
        for c in range(nc):
            starts[c + 1] = starts[c] + sizes[c]
        near = -1
        best = np.inf
        for c in range(out + 1, nc):            # np.min over the pairs, then np.argmin over the clusters
            d = np.inf
            nan = False
            for a in range(starts[out], starts[out + 1]):
                for b in range(starts[c], starts[c + 1]):
                    v = abs(lam[order[a]] - lam[order[b]])
                    if np.isnan(v):
                        nan = True
                    elif v < d:
                        d = v
            if nan:
                near = c
                break
            if near < 0 or d < best:
                near = c
                best = d
        merged = np.empty(sizes[out] + sizes[near], dtype=np.int64)
        a, b = starts[out], starts[near]        # sorted(c + near): a merge of two ascending runs (no
        for k in range(merged.size):            # sort: numba's quicksort cost 1.9 s of compilation)
            if b == starts[near + 1] or (a < starts[out + 1] and order[a] < order[b]):
                merged[k] = order[a]
                a += 1
            else:
                merged[k] = order[b]
                b += 1
        new = np.empty(n, dtype=np.int64)
        k = 0
        for c in range(nc):
            if c == out:
                for v in merged:
                    new[k] = v
                    k += 1
            elif c != near:
                for a in range(starts[c], starts[c + 1]):
                    new[k] = order[a]
                    k += 1
        order = new
        sizes[out] += sizes[near]
        for c in range(near, nc - 1):
            sizes[c] = sizes[c + 1]
        nc -= 1


def block_form(T0: np.ndarray, U0: np.ndarray, B: np.ndarray, C: np.ndarray, tol: float, rel: float,
               max_coupling: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[int, int]]]:
    """:func:`~roadcollab.lti.blockdiag.block_schur` from a complex Schur form, compiled in one call
    (clustering, decoupling passes and merges; :func:`_block_form`): the same clusters, merges and
    arithmetic as :func:`clusters` and :func:`decouple` in the Python loop, so the same output bit for
    bit, without that loop's glue (about 30 us per obfuscated system, docs/speed.md, "Eleventh pass").

    Parameters
    ----------
    T0, U0 : (n, n) complex ndarray
        ``A = U0 T0 U0^H``, ``n >= 1`` (not modified).
    B : (n, m) real ndarray
    C : (p, n) real ndarray
    tol, rel, max_coupling : float
        As :func:`~roadcollab.lti.blockdiag.block_schur`'s ``cluster_tol``, ``cluster_rel``,
        ``max_coupling``.

    Returns
    -------
    R, Bw, Cw : ndarray
        As :class:`~roadcollab.lti.blockdiag.BlockSchur`.
    blocks : list of (int, int)
        ``[start, stop)`` of each diagonal block.
    """
    c = np.ascontiguousarray
    T, Bw, Cw, sizes = _build()["form"](read_only(c(T0, dtype=np.complex128)), read_only(c(U0, dtype=np.complex128)),
                                        read_only(c(B, dtype=float)), read_only(c(C, dtype=float)), float(tol),
                                        float(rel), float(max_coupling))
    blocks, start = [], 0
    for size in sizes.tolist():
        blocks.append((start, start + size))
        start += size
    return T, Bw, Cw, blocks


def decouple(T0: np.ndarray, U0: np.ndarray, B: np.ndarray, C: np.ndarray, clusters: list[list[int]],
             max_coupling: float) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One compiled pass of the block diagonalisation (module docstring).

    Parameters
    ----------
    T0, U0 : (n, n) complex ndarray
        A complex Schur form ``A = U0 T0 U0^H`` (not modified).
    B : (n, m) real ndarray
    C : (p, n) real ndarray
    clusters : list of list of int
        Eigenvalue indices (positions on ``T0``'s diagonal) of each cluster, in order.
    max_coupling : float
        Largest ``||X||_F`` of a split.

    Returns
    -------
    status : int
        -1 on success, else the index of the first cluster that could not be split from the rest.
    R, U, Bw, Cw : ndarray
        The reordered, decoupled ``R`` (zero between blocks), its ``U``, ``U^H B`` and ``C U`` after
        the splits (meaningful on success only).
    """
    T = np.array(T0, dtype=np.complex128, order="C")
    U = np.array(U0, dtype=np.complex128, order="C")
    B = read_only(np.ascontiguousarray(B, dtype=float))
    C = read_only(np.ascontiguousarray(C, dtype=float))
    order = np.array([i for g in clusters for i in g], dtype=np.int64)
    sizes = np.array([len(g) for g in clusters], dtype=np.int64)
    Bw = np.empty((T.shape[0], B.shape[1]), dtype=np.complex128)
    Cw = np.empty((C.shape[0], T.shape[0]), dtype=np.complex128)
    status = int(_build()["decouple"](T, U, B, C, order, sizes, float(max_coupling), Bw, Cw))
    return status, T, U, Bw, Cw


def clusters(lam: np.ndarray, tol: float, rel: float) -> list[list[int]]:
    """:func:`~roadcollab.lti.blockdiag._clusters` with the label propagation compiled.

    Parameters
    ----------
    lam : (n,) complex ndarray
        Eigenvalues.
    tol, rel : float
        As :func:`~roadcollab.lti.blockdiag.block_schur`'s ``cluster_tol``, ``cluster_rel``.

    Returns
    -------
    list of list of int
        Each cluster's indices in ascending order, the clusters ordered by their first index.
    """
    label = _build()["labels"](np.ascontiguousarray(lam, dtype=np.complex128), float(tol), float(rel))
    groups: dict[int, list[int]] = {}
    for i, g in enumerate(label.tolist()):
        groups.setdefault(g, []).append(i)
    return sorted(groups.values(), key=lambda g: g[0])
