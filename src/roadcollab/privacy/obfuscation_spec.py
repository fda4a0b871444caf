"""The distribution Algorithm 2's obfuscating systems ``Psi`` are drawn from (:mod:`.obfuscator_design`
draws them): public under Kerckhoffs' principle, only the draw is private.
"""

from __future__ import annotations

from dataclasses import dataclass

from .._validation import check_int, check_positive, check_real

__all__ = ["ObfuscationSpec"]


@dataclass(frozen=True)
class ObfuscationSpec:
    """Distribution the obfuscating systems are drawn from (public under Kerckhoffs).

    Parameters
    ----------
    order_range : (int, int)
        ``n`` uniform on these integers (inclusive), for ``n1`` and ``n2`` independently.
    pole_frequency_range : (float, float)
        Natural frequencies of the poles, log-uniform, Hz.
    pole_damping_range : (float, float)
        Damping ratios of complex pole pairs, uniform.
    complex_fraction : float
        Probability that a pole (zero) is drawn as a complex pair rather than real.
    zero_frequency_range : (float, float)
        Natural frequencies of the zeros, log-uniform, Hz.
    zero_damping_range : (float, float)
        Damping ratios of complex zero pairs, uniform.
    coupling : float
        Off-diagonal gain relative to the diagonal (0 = diagonal ``Psi``).
    min_zero_distance : float
        Required ``-Re`` of every transmission zero of ``Psi``, rad/s.
    max_condition : float
        Largest allowed condition number of ``Psi`` on the grid.
    max_gain_range : float
        Largest allowed ratio of ``Psi``'s high-frequency gain ``||Psi(inf)||_2`` to its smallest
        singular value on the grid. A ``Psi`` whose gain falls far below its direct term somewhere
        in band (zeros well below its poles) is evaluated from a realisation whose partial
        fractions cancel its direct term there, and ``Psi1 S Psi2`` compounds two of them: without
        this bound (ranges up to 2.6e5 in 150 draws) the sent ``S~`` had evaluation condition
        numbers up to 2e10 at the lowest bins, and the receiver's response of it was 1.2e-7 off a
        40-digit reference on one bin (bench segment 18) and 2 of 300 bench segments missed the 1e-9
        exactness target. With 100, the largest condition number of ``T~`` and ``S~`` over the
        band was 6e6 in the same draws (about 6e-10 relative at float64).
    min_pole_separation : float
        Smallest allowed relative distance ``|p_i - p_k| / max(|p_i|, |p_k|)`` between two poles
        of ``Psi``. Nearly coincident poles make the partial-fraction realisation lose accuracy
        (measured: three poles within 0.2 % of 0.744 Hz gave a realisation of ``Psi1 S Psi2`` that
        was 6e-4 relative off in band), which would break Theorem 1 in floating point.
    """

    order_range: tuple[int, int] = (2, 4)
    pole_frequency_range: tuple[float, float] = (0.3, 30.0)
    pole_damping_range: tuple[float, float] = (0.1, 1.0)
    complex_fraction: float = 0.5
    zero_frequency_range: tuple[float, float] = (0.3, 30.0)
    zero_damping_range: tuple[float, float] = (0.3, 1.0)
    coupling: float = 0.3
    min_zero_distance: float = 0.5
    max_condition: float = 1e4
    min_pole_separation: float = 0.05
    max_gain_range: float = 100.0

    def __post_init__(self) -> None:
        lo, hi = self.order_range
        check_int("order_range[0]", lo, low=1, high=12)
        check_int("order_range[1]", hi, low=lo, high=12)
        for name in ("pole_frequency_range", "zero_frequency_range"):
            a, b = getattr(self, name)
            check_positive(f"{name}[0]", a)
            check_real(f"{name}[1]", b, low=a)
        for name in ("pole_damping_range", "zero_damping_range"):
            a, b = getattr(self, name)
            check_real(f"{name}[0]", a, low=0.0, low_open=True, high=1.0)
            check_real(f"{name}[1]", b, low=a, high=1.0)
        check_real("complex_fraction", self.complex_fraction, low=0.0, high=1.0)
        check_real("coupling", self.coupling, low=0.0, high=1.0)
        check_real("min_pole_separation", self.min_pole_separation, low=0.0, high=1.0)
        check_positive("min_zero_distance", self.min_zero_distance)
        check_real("max_condition", self.max_condition, low=1.0, low_open=True)
        check_real("max_gain_range", self.max_gain_range, low=1.0)
