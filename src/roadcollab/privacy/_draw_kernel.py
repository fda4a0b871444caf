"""The rejection loop of :func:`~roadcollab.privacy.obfuscator_design.draw_obfuscator`, compiled (numba).

The loop draws candidates from the caller's ``numpy.random.Generator`` itself (numba's
``Generator.integers`` and ``Generator.uniform`` are ports of numpy's and advance the same bit
generator: the same numbers, and the same generator state afterwards), and decides on every check
of the reference loop: pole separation, transmission zeros, condition number and gain range on the
grid. It records the values the accepted candidate drew; the caller replays them through the
reference code (:func:`~roadcollab.privacy.obfuscator_design._candidate`), so the draw returned is
the reference path's bit for bit. A check may decide differently from the reference only for a
candidate within round-off of its threshold (the loop sums in another order and takes its roots
from ``zgeev`` instead of ``dgeev``).

Measured (docs/speed.md): a ``paper`` message's two draws went from 4.6 to 0.9 ms.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ..lti.kernels import compiled_available, jit_options

__all__ = ["draw_loop"]

_KERNEL: dict[str, Any] = {}


def _build() -> Any:   # Long: the kernels are defined here so that numba is imported on first use only
    """Define and compile the loop on first use (``None`` without numba)."""
    if "loop" in _KERNEL:
        return _KERNEL["loop"]
    if not compiled_available():
        _KERNEL["loop"] = None
        return None
    import numba

    jit: Callable[[Callable[..., Any]], Callable[..., Any]] = numba.njit(**jit_options())

    @jit
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

    @jit
    def poly_into(roots: np.ndarray, n: int, c: np.ndarray) -> None:   # pragma: no cover - compiled
        # Coefficients of prod (s - r), highest power first, complex (real part used).
        c[0] = 1.0
        for k in range(1, n + 1):
            c[k] = 0.0
        for i in range(n):
            r = roots[i]
            for k in range(i + 1, 0, -1):
                c[k] = c[k] - r * c[k - 1]

    @jit
    def zeros_ok(num: np.ndarray, n: int, min_zero_distance: float) -> bool:   # pragma: no cover - compiled
        # det N = N00 N11 - N01 N10 (degree 2n), its roots: the transmission zeros.
        det = np.zeros(2 * n + 1)
        for i in range(n + 1):
            for k in range(n + 1):
                det[i + k] += num[0, i] * num[3, k] - num[1, i] * num[2, k]
        f = 0
        while f < 2 * n + 1 and det[f] == 0.0:
            f += 1
        deg = 2 * n - f
        if deg < 2 * n:       # a leading zero: fewer than 2 n zeros
            return False
        comp = np.zeros((deg, deg), np.complex128)
        for k in range(deg):
            comp[0, k] = -det[k + 1] / det[0]
        for k in range(1, deg):
            comp[k, k - 1] = 1.0
        zr = np.linalg.eigvals(comp)
        worst = -np.inf
        for k in range(deg):
            if zr[k].real > worst:
                worst = zr[k].real
        if worst > -min_zero_distance:
            return False
        return True

    @jit
    def axis_ratios(num: np.ndarray, den: np.ndarray, n: int, powers: np.ndarray) -> tuple[float, float]:
        # pragma: no cover - compiled
        K = powers.shape[1]
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
        for q in range(K):
            r0 = r1 = r2 = r3 = rd = 0.0
            i0 = i1 = i2 = i3 = idd = 0.0
            for k in range(n + 1):
                wk = powers[k, q]
                r0 += cre[k, 0] * wk
                r1 += cre[k, 1] * wk
                r2 += cre[k, 2] * wk
                r3 += cre[k, 3] * wk
                rd += cre[k, 4] * wk
                i0 += cim[k, 0] * wk
                i1 += cim[k, 1] * wk
                i2 += cim[k, 2] * wk
                i3 += cim[k, 3] * wk
                idd += cim[k, 4] * wk
            fro2 = r0 * r0 + i0 * i0 + r1 * r1 + i1 * i1 + r2 * r2 + i2 * i2 + r3 * r3 + i3 * i3
            det_re = r0 * r3 - i0 * i3 - (r1 * r2 - i1 * i2)
            det_im = r0 * i3 + i0 * r3 - (r1 * i2 + i1 * r2)
            det2 = det_re * det_re + det_im * det_im
            adet = np.sqrt(det2)
            if not adet > 0.0:
                return np.inf, np.inf
            rc = fro2 / adet / 2
            if rc > r_cond:
                r_cond = rc
            smax = np.sqrt((fro2 + np.sqrt(max(fro2 * fro2 - 4 * det2, 0.0))) / 2)
            rg = np.sqrt(rd * rd + idd * idd) * smax / adet
            if rg > r_gain:
                r_gain = rg
        return r_cond, r_gain

    @jit
    def loop(rng: Any, lo: int, hi: int, plf0: float, plf1: float, pd0: float, pd1: float, zlf0: float,
             zlf1: float, zd0: float, zd1: float, cf: float, gl0: float, gl1: float, coupling: float,
             min_sep: float, min_zero_distance: float, max_condition: float, max_gain_range: float,
             powers: np.ndarray, max_attempts: int, rec: np.ndarray, poles: np.ndarray,
             num: np.ndarray) -> tuple[int, int]:   # pragma: no cover
        # poles (hi,) complex and num (4, hi + 1) receive the accepted candidate (its first n, n + 1).
        nmax = hi
        zeros = np.empty(nmax, np.complex128)
        cz = np.empty(nmax + 1, np.complex128)
        den = np.empty(nmax + 1, np.complex128)
        for attempt in range(max_attempts):
            nrec = 0
            n = rng.integers(lo, hi + 1)
            rec[nrec] = n
            nrec += 1
            nrec = roots_into(rng, n, plf0, plf1, pd0, pd1, cf, poles, rec, nrec)
            sep = np.inf
            for i in range(n):
                for k in range(n):
                    if i != k:
                        a, b = abs(poles[i]), abs(poles[k])
                        d = abs(poles[i] - poles[k]) / max(a, b)
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
                    num[e, k] = gain * cz[k].real
            if not zeros_ok(num, n, min_zero_distance):
                continue
            poly_into(poles, n, den)
            r_cond, r_gain = axis_ratios(num, den, n, powers)
            if not r_cond < np.inf:
                continue
            if r_cond + np.sqrt(max(r_cond * r_cond - 1.0, 0.0)) > max_condition:
                continue
            # ||N_lead||_2 (2x2, real): sqrt((F + sqrt(F^2 - 4 det^2)) / 2).
            a, b, c, d = num[0, 0], num[1, 0], num[2, 0], num[3, 0]
            F = a * a + b * b + c * c + d * d
            dl = a * d - b * c
            lead = np.sqrt((F + np.sqrt(max(F * F - 4 * dl * dl, 0.0))) / 2)
            if lead * r_gain > max_gain_range:
                continue
            return attempt, n
        return max_attempts, -1

    @jit
    def realise(poles: np.ndarray, num: np.ndarray, n: int, dt: float) -> tuple[np.ndarray, np.ndarray,
                                                                                np.ndarray, np.ndarray]:
        # pragma: no cover - compiled
        # obfuscator_design._realise (modal blocks, scaled) then bilinear_discretize, in one pass.
        den = np.empty(n + 1, np.complex128)
        poly_into(poles, n, den)
        dden = np.empty(n, np.complex128)
        for k in range(n):
            dden[k] = den[k].real * (n - k)
        A = np.zeros((2 * n, 2 * n))
        B = np.zeros((2 * n, 2))
        C = np.zeros((2, 2 * n))
        i = 0
        for q in range(n):
            p = poles[q]
            if p.imag < 0:
                continue
            dv = 0j
            for k in range(n):
                dv = dv * p + dden[k]
            R = np.empty(4, np.complex128)
            for e in range(4):
                v = 0j
                for k in range(n + 1):
                    v = v * p + num[e, k]
                R[e] = v / dv
            if p.imag == 0:
                cn = np.sqrt(R[0].real ** 2 + R[1].real ** 2 + R[2].real ** 2 + R[3].real ** 2)
                sc = np.sqrt(max(cn, 1e-12) / np.sqrt(2.0))
                for a in range(2):
                    A[i + a, i + a] = p.real
                    B[i + a, a] = sc
                    for b in range(2):
                        C[a, i + b] = R[2 * a + b].real / sc
                i += 2
            else:
                cn = 0.0
                for e in range(4):
                    cn += 4 * (R[e].real ** 2 + R[e].imag ** 2)
                sc = np.sqrt(max(np.sqrt(cn), 1e-12) / np.sqrt(2.0))
                for a in range(2):
                    A[i + a, i + a] = p.real
                    A[i + 2 + a, i + 2 + a] = p.real
                    A[i + a, i + 2 + a] = -p.imag
                    A[i + 2 + a, i + a] = p.imag
                    B[i + a, a] = sc
                    for b in range(2):
                        C[a, i + b] = 2 * R[2 * a + b].real / sc
                        C[a, i + 2 + b] = -2 * R[2 * a + b].imag / sc
                i += 4
        h = 0.5 * dt
        ima = np.eye(2 * n) - h * A
        Ad = np.linalg.solve(ima, np.eye(2 * n) + h * A)
        Bd = np.linalg.solve(ima, dt * B)
        Cd = np.linalg.solve(ima.T.copy(), C.T.copy()).T.copy()
        Dd = np.empty((2, 2))
        for a in range(2):
            for b in range(2):
                v = num[2 * a + b, 0]
                for k in range(2 * n):
                    v += 0.5 * C[a, k] * Bd[k, b]
                Dd[a, b] = v
        return Ad, Bd, Cd, Dd

    _KERNEL["loop"] = loop
    _KERNEL["realise"] = realise
    return loop


def draw_loop(spec: Any, powers: np.ndarray, rng: np.random.Generator, max_attempts: int, dt: float
              ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]] | None:
    """Run the rejection loop compiled, and realise the accepted candidate.

    Parameters
    ----------
    spec : ObfuscationSpec
    powers : (degree + 1, K) ndarray
        ``w^k`` at the warped frequencies (``obfuscator_design._warped_powers``).
    rng : numpy.random.Generator
        Advanced exactly as the reference loop advances it.
    max_attempts : int
    dt : float
        Sample period of the discretisation, s.

    Returns
    -------
    (poles, numerators, (Ad, Bd, Cd, Dd)) or None
        Poles (n,) rad/s, numerators (2, 2, n + 1) and the discrete realisation (order 2 n) of the
        accepted candidate; None if no candidate was accepted in ``max_attempts``.
    """
    loop = _build()
    plf = np.log(spec.pole_frequency_range)
    zlf = np.log(spec.zero_frequency_range)
    lo, hi = spec.order_range
    rec = np.empty(1 + 6 * 3 * hi + 8)
    poles = np.empty(hi, complex)
    num = np.empty((4, hi + 1))
    _, n = loop(rng, int(lo), int(hi), float(plf[0]), float(plf[1]), float(spec.pole_damping_range[0]),
                float(spec.pole_damping_range[1]), float(zlf[0]), float(zlf[1]),
                float(spec.zero_damping_range[0]), float(spec.zero_damping_range[1]),
                float(spec.complex_fraction), float(np.log(0.5)), float(np.log(2.0)), float(spec.coupling),
                float(spec.min_pole_separation), float(spec.min_zero_distance), float(spec.max_condition),
                float(spec.max_gain_range), np.ascontiguousarray(powers), int(max_attempts), rec, poles, num)
    if n < 0:
        return None
    poles, num = poles[:n].copy(), np.ascontiguousarray(num[:, :n + 1])
    return poles, num.reshape(2, 2, n + 1), _KERNEL["realise"](poles, num, n, float(dt))
