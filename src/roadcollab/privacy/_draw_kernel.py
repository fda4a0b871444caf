"""The rejection loop of :func:`~roadcollab.privacy.obfuscator_design.draw_obfuscator`, compiled (numba);
the Python entry points that call it are in :mod:`._draw_calls`.

The loop draws candidates from the caller's ``numpy.random.Generator`` itself (numba's
``Generator.integers`` and ``Generator.uniform`` are ports of numpy's and advance the same bit
generator: the same numbers, and the same generator state afterwards), and decides on every check
of the reference loop: pole separation, transmission zeros (Routh-Hurwitz on the shifted ``det N``
instead of its roots), condition number and gain range on the grid. A check may decide differently
from the reference only for a candidate within round-off of its threshold. The accepted candidate
is realised here too (modal blocks, then the bilinear map block by block in closed form), equal to
the reference's realisation up to round-off.

Measured (docs/speed.md, "Second pass"): 0.34-0.39 ms per draw against 2.0-2.2 ms on the numpy path.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..lti.kernels import compiled_available, jit_options

__all__ = ["pole_residues"]

_KERNEL: dict[str, Any] = {}


#: The functions compiled by :func:`_build`, which rebinds each module-level name to its compiled version.
_COMPILED_NAMES = ("roots_into", "poly_into", "zeros_ok", "axis_ratios", "loop", "realise", "_residues")
#: Those only compiled kernels call (no entry point from Python: :func:`~roadcollab.lti.kernels.jit_options`).
_INTERNAL_NAMES = ("roots_into", "poly_into", "zeros_ok", "axis_ratios")


def _build() -> Any:
    """The compiled loop (``None`` without numba).

    numba is imported here, on first use (0.3-0.5 s). The functions below are module-level and
    compiled in place: each name is rebound to its compiled version, so the compiled ``loop`` calls
    the compiled helpers by their global names. Closures would not do: numba's on-disk cache cannot
    load a function that calls a jitted closure (its key holds the closure's cell, different in every
    process), and every process compiled the loop again (18-20 s).
    """
    if "loop" in _KERNEL:
        return _KERNEL["loop"]
    if not compiled_available():
        _KERNEL["loop"] = None
        return None
    import numba

    for name in _COMPILED_NAMES:
        globals()[name] = numba.njit(**jit_options(internal=name in _INTERNAL_NAMES))(globals()[name])
    _KERNEL.update(loop=globals()["loop"], realise=globals()["realise"], residues=globals()["_residues"])
    return _KERNEL["loop"]


def roots_into(rng: Any, n: int, lf0: float, lf1: float, d0: float, d1: float, cf: float, out: np.ndarray,
               rec: np.ndarray, nrec: int) -> int:   # pragma: no cover - compiled
    # _random_roots: the same draws in the same order, recorded.
    k = 0
    while k < n:
        u = rng.uniform(lf0, lf1)
        rec[nrec] = u
        nrec += 1
        wn = 2 * np.pi * np.exp(u)
        cplx = False
        if n - k >= 2:
            v = rng.uniform()
            rec[nrec] = v
            nrec += 1
            cplx = v < cf
        if cplx:
            zeta = rng.uniform(d0, d1)
            rec[nrec] = zeta
            nrec += 1
            wd = wn * np.sqrt(max(1.0 - zeta * zeta, 0.0))
            out[k] = complex(-zeta * wn, wd)
            out[k + 1] = complex(-zeta * wn, -wd)
            k += 2
        else:
            out[k] = complex(-wn, 0.0)
            k += 1
    return nrec

def poly_into(roots: np.ndarray, n: int, c: np.ndarray) -> None:   # pragma: no cover - compiled
    # Coefficients of prod (s - r), highest power first, complex (real part used).
    c[0] = 1.0
    for k in range(1, n + 1):
        c[k] = 0.0
    for i in range(n):
        r = roots[i]
        for k in range(i + 1, 0, -1):
            c[k] = c[k] - r * c[k - 1]

def zeros_ok(num: np.ndarray, n: int, min_zero_distance: float) -> bool:   # pragma: no cover - compiled
    # Every root of det N = N00 N11 - N01 N10 (degree 2 n: the transmission zeros) has real part
    # below -min_zero_distance: the Routh-Hurwitz test of det N(x - min_zero_distance), the same
    # decision as the reference's np.roots except for a zero within round-off of the bound (no
    # eigenvalue solver here: it cost 2.7 s of compilation).
    d = 2 * n
    c = np.zeros(d + 1)
    for i in range(n + 1):
        for k in range(n + 1):
            c[i + k] += num[0, i] * num[3, k] - num[1, i] * num[2, k]
    if c[0] == 0.0:           # a leading zero: fewer than 2 n zeros
        return False
    for i in range(d):        # Taylor shift: c(x) <- c(x - sigma)
        for j in range(1, d - i + 1):
            c[j] -= min_zero_distance * c[j - 1]
    if c[0] < 0:
        for j in range(d + 1):
            c[j] = -c[j]
    w = d // 2 + 1
    r1 = np.zeros(w + 1)
    r2 = np.zeros(w + 1)
    for j in range(w):
        if 2 * j <= d:
            r1[j] = c[2 * j]
        if 2 * j + 1 <= d:
            r2[j] = c[2 * j + 1]
    for _ in range(d):
        if not r2[0] > 0.0:
            return False
        nxt = np.zeros(w + 1)
        for j in range(w):
            nxt[j] = (r2[0] * r1[j + 1] - r1[0] * r2[j + 1]) / r2[0]
        r1, r2 = r2, nxt
    return True


def axis_ratios(num: np.ndarray, den: np.ndarray, n: int, powers: np.ndarray, q0: int, q1: int
                ) -> tuple[float, float]:   # pragma: no cover - compiled
    # The maxima over the bins q0..q1 - 1 of `powers` (each bin's figures the same bits whatever the range).
    K = q1 - q0
    # Condition number and gain range on the warped axis (obfuscator_design's closed forms):
    # N_e(j w) = sum_k num[e, n - k] j^k w^k, d(j w) likewise.
    r_cond = 0.0
    r_gain = 0.0
    # Coefficients of w^k in Re / Im of N_e(j w) and d(j w): c_k j^k (j^k = 1, j, -1, -j).
    cre = np.zeros((n + 1, 5))
    cim = np.zeros((n + 1, 5))
    for k in range(n + 1):
        sgn = 1.0 if k % 4 < 2 else -1.0
        tgt = cre if k % 2 == 0 else cim
        for e in range(4):
            tgt[k, e] = sgn * num[e, n - k]
        tgt[k, 4] = sgn * den[n - k].real
    # The bins in the inner loops, each sum over k in the same order as per bin before (the same values,
    # bit for bit), with no branch in them: LLVM vectorises them (the per-bin loop with its running maxima
    # did not). The maxima of the same values, so the same decisions.
    acc = np.zeros((10, K))
    for k in range(n + 1):
        pk = powers[k, q0:q1]
        for j in range(5):
            a, b = cre[k, j], cim[k, j]
            ra, ia = acc[j], acc[5 + j]
            for q in range(K):
                wk = pk[q]
                ra[q] += a * wk
                ia[q] += b * wk
    r0, r1, r2, r3, rd = acc[0], acc[1], acc[2], acc[3], acc[4]
    i0, i1, i2, i3, idd = acc[5], acc[6], acc[7], acc[8], acc[9]
    rc = np.empty(K)
    rg = np.empty(K)
    bad = 0
    for q in range(K):
        fro2 = r0[q] * r0[q] + i0[q] * i0[q] + r1[q] * r1[q] + i1[q] * i1[q] + r2[q] * r2[q] + i2[q] * i2[q] \
            + r3[q] * r3[q] + i3[q] * i3[q]
        det_re = r0[q] * r3[q] - i0[q] * i3[q] - (r1[q] * r2[q] - i1[q] * i2[q])
        det_im = r0[q] * i3[q] + i0[q] * r3[q] - (r1[q] * i2[q] + i1[q] * r2[q])
        det2 = det_re * det_re + det_im * det_im
        adet = np.sqrt(det2)
        bad += 0 if adet > 0.0 else 1
        rc[q] = fro2 / adet / 2
        smax = np.sqrt((fro2 + np.sqrt(max(fro2 * fro2 - 4 * det2, 0.0))) / 2)
        rg[q] = np.sqrt(rd[q] * rd[q] + idd[q] * idd[q]) * smax / adet
    if bad:
        return np.inf, np.inf
    for q in range(K):
        if rc[q] > r_cond:
            r_cond = rc[q]
        if rg[q] > r_gain:
            r_gain = rg[q]
    return r_cond, r_gain

def loop(rng: Any, lo: int, hi: int, plf0: float, plf1: float, pd0: float, pd1: float, zlf0: float,
         zlf1: float, zd0: float, zd1: float, cf: float, gl0: float, gl1: float, coupling: float,
         min_sep: float, min_zero_distance: float, max_condition: float, max_gain_range: float,
         powers: np.ndarray, max_attempts: int, rec: np.ndarray, poles: np.ndarray,
         num: np.ndarray) -> tuple[int, int]:   # pragma: no cover
    # Long: the draws in this kernel itself, not in a kernel it calls (below).
    # count = poles.shape[0] (1 or 2) draws in a row, the second only after the first accepted a candidate, from
    # the generator as the first left it: row j of poles (count, hi) complex and num (count, 4, hi + 1) receives
    # draw j's accepted candidate (its first n, n + 1). Returns (n_0, n_1), -1 for a draw that found nothing or
    # was not made. The draws in this kernel itself, not in a kernel it calls: a caller recompiles its callees'
    # code (a pair kernel calling a one-draw kernel cost 0.7 s more of a fresh installation's first run).
    nmax = hi
    zeros = np.empty(nmax, np.complex128)
    cz = np.empty(nmax + 1, np.complex128)
    den = np.empty(nmax + 1, np.complex128)
    first = -1
    for j in range(poles.shape[0]):
        pz = poles[j]
        nm = num[j]
        accepted = -1
        for _attempt in range(max_attempts):
            nrec = 0
            n = rng.integers(lo, hi + 1)
            rec[nrec] = n
            nrec += 1
            nrec = roots_into(rng, n, plf0, plf1, pd0, pd1, cf, pz, rec, nrec)
            sep = np.inf
            for i in range(n):
                for k in range(n):
                    if i != k:
                        a, b = abs(pz[i]), abs(pz[k])
                        d = abs(pz[i] - pz[k]) / max(a, b)
                        if d < sep:
                            sep = d
            if sep < min_sep:
                continue
            g0 = rng.uniform(gl0, gl1)
            g1 = rng.uniform(gl0, gl1)
            rec[nrec] = g0
            rec[nrec + 1] = g1
            nrec += 2
            dg0, dg1 = np.exp(g0), np.exp(g1)
            for e in range(4):
                nrec = roots_into(rng, n, zlf0, zlf1, zd0, zd1, cf, zeros, rec, nrec)
                if e == 0:
                    gain = dg0
                elif e == 3:
                    gain = dg1
                else:
                    u = rng.uniform(-1.0, 1.0)
                    rec[nrec] = u
                    nrec += 1
                    gain = coupling * u * np.sqrt(dg0 * dg1)
                poly_into(zeros, n, cz)
                for k in range(n + 1):
                    nm[e, k] = gain * cz[k].real
            if not zeros_ok(nm, n, min_zero_distance):
                continue
            poly_into(pz, n, den)
            # ||N_lead||_2 (2x2, real): sqrt((F + sqrt(F^2 - 4 det^2)) / 2).
            a, b, c, d = nm[0, 0], nm[1, 0], nm[2, 0], nm[3, 0]
            F = a * a + b * b + c * c + d * d
            dl = a * d - b * c
            lead = np.sqrt((F + np.sqrt(max(F * F - 4 * dl * dl, 0.0))) / 2)
            # The lowest bins first: a candidate that fails there fails on the grid (its maxima over every bin are
            # at least these, and the tests below are monotone in them), and every rejected candidate measured
            # failed within the first three bins: the other bins are computed only for the rest (docs/speed.md,
            # "Eleventh pass"). The maxima over all bins, and so the decisions, are those of one pass.
            K = powers.shape[1]
            head = min(K, 32)
            # q0 as an int64 like the second call's: a literal 0 compiled axis_ratios a second time (1.2-1.7 s).
            r_cond, r_gain = axis_ratios(nm, den, n, powers, head - head, head)
            if not r_cond < np.inf:
                continue
            if r_cond + np.sqrt(max(r_cond * r_cond - 1.0, 0.0)) > max_condition:
                continue
            if lead * r_gain > max_gain_range:
                continue
            if head < K:
                c2, g2 = axis_ratios(nm, den, n, powers, head, K)
                r_cond = c2 if c2 > r_cond else r_cond
                r_gain = g2 if g2 > r_gain else r_gain
                if not r_cond < np.inf:
                    continue
                if r_cond + np.sqrt(max(r_cond * r_cond - 1.0, 0.0)) > max_condition:
                    continue
                if lead * r_gain > max_gain_range:
                    continue
            accepted = n
            break
        if j == 0:
            first = accepted
            if accepted < 0:
                return -1, -1
        else:
            return first, accepted
    return first, -1

def realise(poles: np.ndarray, num: np.ndarray, n: int, dt: float) -> tuple[np.ndarray, np.ndarray,
                                                                            np.ndarray, np.ndarray,
                                                                            np.ndarray, np.ndarray]:
    # pragma: no cover - compiled
    # Long: one pass over the pole blocks writes the realisation and its Schur form together.
    # obfuscator_design._realise (modal blocks, each scaled) then the bilinear map of
    # bilinear_discretize, block by block in closed form: I - (dt/2) A is block diagonal, its inverse
    # 1 / (1 - h p) on a real pole's block and kron([[a, -b], [b, a]] / (a^2 + b^2), I2) on a complex
    # pair's (a = 1 - h sigma, b = h omega). No dense solves (they cost 14 s of compilation).
    # Also a complex Schur form Ad = U Tz U^H in closed form (Tz diagonal): a real pole's block is
    # diagonal already; a pair's block kron([[a, -b], [b, a]], I2) has the eigenvalues a +- i b with the
    # eigenvectors [1, -+i] / sqrt(2) of the 2x2 factor. The sender certifies its T~, S~ from the
    # Schur forms of the parts (lti.composed_schur): this one saves a dgees per Psi.
    h = 0.5 * dt
    Tz = np.zeros((2 * n, 2 * n), np.complex128)
    Uz = np.zeros((2 * n, 2 * n), np.complex128)
    rt = np.sqrt(0.5)
    den = np.empty(n + 1, np.complex128)
    poly_into(poles, n, den)
    Ad = np.zeros((2 * n, 2 * n))
    Bd = np.zeros((2 * n, 2))
    Cd = np.zeros((2, 2 * n))
    Dd = np.empty((2, 2))
    for e in range(4):
        Dd[e // 2, e % 2] = num[e, 0]
    Cc = np.zeros((2, 2 * n))           # the continuous C, for Dd = D + (1/2) C Bd
    R = np.empty(4, np.complex128)
    i = 0
    for q in range(n):
        p = poles[q]
        if p.imag < 0:
            continue
        dv = 0j
        for k in range(n):
            dv = dv * p + den[k].real * (n - k)
        for e in range(4):
            v = 0j
            for k in range(n + 1):
                v = v * p + num[e, k]
            R[e] = v / dv
        if p.imag == 0:
            cn = np.sqrt(R[0].real ** 2 + R[1].real ** 2 + R[2].real ** 2 + R[3].real ** 2)
            sc = np.sqrt(max(cn, 1e-12) / np.sqrt(2.0))
            g = 1.0 / (1.0 - h * p.real)
            for a in range(2):
                Ad[i + a, i + a] = (1.0 + h * p.real) * g
                Tz[i + a, i + a] = Ad[i + a, i + a]
                Uz[i + a, i + a] = 1.0
                Bd[i + a, a] = dt * sc * g
                for b in range(2):
                    Cc[a, i + b] = R[2 * a + b].real / sc
                    Cd[a, i + b] = Cc[a, i + b] * g
            i += 2
        else:
            cn = 0.0
            for e in range(4):
                cn += 4 * (R[e].real ** 2 + R[e].imag ** 2)
            sc = np.sqrt(max(np.sqrt(cn), 1e-12) / np.sqrt(2.0))
            ca, cb = 1.0 - h * p.real, h * p.imag
            r = 1.0 / (ca * ca + cb * cb)
            m00, m01, m10, m11 = ca * r, -cb * r, cb * r, ca * r          # (I - h A_2x2)^-1
            pa, pb = 1.0 + h * p.real, h * p.imag                         # I + h A_2x2 = [[pa, -pb], [pb, pa]]
            a00, a01 = m00 * pa + m01 * pb, -m00 * pb + m01 * pa
            a10, a11 = m10 * pa + m11 * pb, -m10 * pb + m11 * pa
            for a in range(2):
                Ad[i + a, i + a] = a00
                Ad[i + a, i + 2 + a] = a01
                Ad[i + 2 + a, i + a] = a10
                Ad[i + 2 + a, i + 2 + a] = a11
                # a11 = a00 and a01 = -a10 (products of matrices [[x, -y], [y, x]]): eigenvalue a00 + i a10
                # on [1, -i] / sqrt(2), its conjugate on [1, i] / sqrt(2), per channel a.
                Tz[i + a, i + a] = complex(a00, a10)
                Tz[i + 2 + a, i + 2 + a] = complex(a00, -a10)
                Uz[i + a, i + a] = rt
                Uz[i + 2 + a, i + a] = complex(0.0, -rt)
                Uz[i + a, i + 2 + a] = rt
                Uz[i + 2 + a, i + 2 + a] = complex(0.0, rt)
                # B block [I2; 0] sc: Bd = dt M^-1 B
                Bd[i + a, a] = dt * sc * m00
                Bd[i + 2 + a, a] = dt * sc * m10
                for b in range(2):
                    c0 = 2 * R[2 * a + b].real / sc
                    c1 = -2 * R[2 * a + b].imag / sc
                    Cc[a, i + b] = c0
                    Cc[a, i + 2 + b] = c1
                    # C block [c0 I-col, c1 I-col] times kron(M^-1, I2): columns b and 2 + b
                    Cd[a, i + b] = c0 * m00 + c1 * m10
                    Cd[a, i + 2 + b] = c0 * m01 + c1 * m11
            i += 4
    for a in range(2):
        for b in range(2):
            v = 0.0
            for k in range(2 * n):
                v += Cc[a, k] * Bd[k, b]
            Dd[a, b] += 0.5 * v
    return Ad, Bd, Cd, Dd, Tz, Uz


def _residues(p: np.ndarray, num: np.ndarray, h: float, zp: np.ndarray, res: np.ndarray,
              direct: np.ndarray) -> None:   # pragma: no cover - compiled
    # Obfuscator.pole_residues: R_i = N(p_i) / d'(p_i), d' by Horner on the derivative of the expanded
    # (real) denominator as `realise` computes it, so the residues round like the realisation's (the
    # product of the pole differences rounds differently and made e~ 3x further from the sent
    # realisation's Psi1 e, measured); N by Horner; then the bilinear map of each term.
    n = p.size
    den = np.empty(n + 1, np.complex128)
    poly_into(p, n, den)
    for c in range(4):
        direct[c] = num[c, 0]
    for i in range(n):
        dd = 0.0 + 0.0j
        for k in range(n):
            dd = dd * p[i] + den[k].real * (n - k)
        ci = h / (1.0 - p[i] * h)
        zi = (1.0 + p[i] * h) / (1.0 - p[i] * h)
        zp[i] = zi
        for c in range(4):
            acc = 0.0 + 0.0j
            for k in range(n + 1):
                acc = acc * p[i] + num[c, k]
            r = acc / dd
            direct[c] += ci * r
            res[i, c] = r * ci * (1.0 + zi)


def pole_residues(poles: np.ndarray, numerators: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`~roadcollab.privacy.obfuscator_design.Obfuscator.pole_residues` compiled: one call instead of
    numpy's ``polyder``, ``polyval`` and ``einsum`` on arrays of a few entries (0.11 ms per ``Psi``,
    mostly call overhead). ``d'(p_i)`` is evaluated on the derivative of the expanded denominator, as the
    compiled realisation does.

    Parameters
    ----------
    poles : (n,) complex ndarray
        Distinct continuous poles, rad/s.
    numerators : (2, 2, n + 1) ndarray
        Numerator coefficients, highest power first.
    dt : float
        Sample period, s.

    Returns
    -------
    z_poles : (n,) complex ndarray
    residues : (n, 2, 2) complex ndarray
    direct : (2, 2) complex ndarray
    """
    _build()
    p = np.ascontiguousarray(poles, dtype=np.complex128)
    num = np.ascontiguousarray(np.asarray(numerators, dtype=float).reshape(4, -1))
    zp = np.empty(p.size, np.complex128)
    res = np.empty((p.size, 4), np.complex128)
    direct = np.empty(4, np.complex128)
    _KERNEL["residues"](p, num, 0.5 * float(dt), zp, res, direct)
    return zp, res.reshape(p.size, 2, 2), direct.reshape(2, 2)
