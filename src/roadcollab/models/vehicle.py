"""Reduced front half-car model (eqs. 1-3) and heterogeneous fleets.

The body is a rigid beam with heave ``z`` and roll ``theta``; each side has a spring
(stiffness ``k_s``) and a damper (``c_s``) between the body tip and a wheel that follows the
road (no unsprung mass: the "reduced" model). With the road elevation ``zr_i`` under wheel
``i`` and the body-tip heights ``z1 = z + L1 theta``, ``z2 = z - L2 theta``:

.. math::

    q_1 = z_1 - z_{r1},\\quad q_2 = z_2 - z_{r2},\\qquad
    \\dot q_1 = \\dot z + L_1\\dot\\theta - w_l,\\quad \\dot q_2 = \\dot z - L_2\\dot\\theta - w_r

    m_b \\ddot z = F_1 + F_2,\\quad \\tfrac12 I_x \\ddot\\theta = L_1 F_1 - L_2 F_2,\\quad
    F_i = -k_s q_i - c_s \\dot q_i

The roll equation is eq. 1 as printed: the front half-car carries half of the vehicle's roll
inertia ``I_x`` (``roll_inertia``), so its roll mode is ``omega^2 = 2 k_s (L1^2 + L2^2) / I_x``.

Substituting ``q_dot`` into the force equations gives non-zero B rows 3-4, and the body-tip
accelerations ``y = [z1_ddot, z2_ddot]`` have a direct feed-through ``D`` that is invertible,
so ``P(s) = C (sI - A)^-1 B + D`` is biproper with transmission zeros at ``0, 0`` and
``-k_s/c_s`` (double).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from .._validation import check_int, check_positive, check_real
from ..errors import ParameterError
from ..lti.response import ss_response

__all__ = [
    "HalfCarParameters",
    "HalfCarModel",
    "half_car_model",
    "FleetSpec",
    "Vehicle",
    "sample_fleet",
]


@dataclass(frozen=True)
class HalfCarParameters:
    """Physical parameters of the reduced front half-car, SI units.

    Parameters
    ----------
    sprung_mass : float
        ``m_b``, body mass carried by the front axle, kg.
    roll_inertia : float
        ``I_x``, the *vehicle's* roll moment of inertia about the centre of gravity, kg m^2.
        The front half-car carries half of it (eq. 1: ``(1/2) I_x theta''``).
    left_arm, right_arm : float
        ``L1``, ``L2``, lateral distance from the centre of gravity to the left/right body
        tip (suspension mount), m.
    stiffness : float
        ``k_s``, suspension stiffness of each side, N/m.
    damping : float
        ``c_s``, suspension damping of each side, N s/m.
    """

    sprung_mass: float = 750.0
    roll_inertia: float = 550.0
    left_arm: float = 0.75
    right_arm: float = 0.75
    stiffness: float = 22_000.0
    damping: float = 1_800.0

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, check_positive(f.name, getattr(self, f.name)))

    def as_dict(self) -> dict[str, float]:
        """Return the parameters as a plain dict (for configuration files)."""
        return asdict(self)

    def scaled(self, factors: dict[str, float]) -> "HalfCarParameters":
        """Return a copy with each named field multiplied by its factor.

        Parameters
        ----------
        factors : dict of str to float
            Field name -> multiplier.

        Returns
        -------
        HalfCarParameters
        """
        unknown = set(factors) - {f.name for f in fields(self)}
        if unknown:
            raise ParameterError(f"factors has unknown parameter names {sorted(unknown)}")
        return replace(self, **{k: getattr(self, k) * v for k, v in factors.items()})


@dataclass(frozen=True, eq=False)
class HalfCarModel:
    """Continuous-time state-space model ``x' = A x + B w``, ``y = C x + D w``.

    Attributes
    ----------
    A : (4, 4) ndarray
        State matrix, state ``x = [q1, q2, zdot, thetadot]`` (m, m, m/s, rad/s).
    B : (4, 2) ndarray
        Input matrix, input ``w = [wl, wr]`` road velocity under each wheel (m/s).
    C : (2, 4) ndarray
        Output matrix, output ``y`` = body-tip vertical accelerations (m/s^2).
    D : (2, 2) ndarray
        Feed-through, invertible for physical parameters.
    params : HalfCarParameters
        The parameters the model was built from.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    params: HalfCarParameters

    def to_control(self):
        """Return the model as a :class:`control.StateSpace`."""
        import control

        return control.ss(self.A, self.B, self.C, self.D)

    def poles(self) -> np.ndarray:
        """Eigenvalues of A, rad/s, sorted by imaginary part."""
        ev = np.linalg.eigvals(self.A)
        return ev[np.argsort(ev.imag)]

    def frequency_response(self, s: np.ndarray) -> np.ndarray:
        """``P(s)`` at complex frequencies.

        Parameters
        ----------
        s : (M,) complex array_like
            rad/s.

        Returns
        -------
        (M, 2, 2) complex ndarray
        """
        return ss_response(self.A, self.B, self.C, self.D, s)


def half_car_model(params: HalfCarParameters) -> HalfCarModel:
    """Build the state-space matrices of the reduced half-car (eqs. 1-3).

    Parameters
    ----------
    params : HalfCarParameters

    Returns
    -------
    HalfCarModel
        With ``A`` (4, 4), ``B`` (4, 2), ``C`` (2, 4), ``D`` (2, 2).

    Raises
    ------
    ParameterError
        If ``params`` is not a :class:`HalfCarParameters`.

    Examples
    --------
    >>> m = half_car_model(HalfCarParameters(500, 400, 0.75, 0.75, 20e3, 1.5e3))
    >>> [round(float(f), 2) for f in sorted(set(np.round(abs(m.poles()) / (2 * np.pi), 6)))]  # heave, roll (Hz)
    [1.42, 1.69]
    """
    if not isinstance(params, HalfCarParameters):
        raise ParameterError(f"params must be a HalfCarParameters, got {type(params).__name__}")
    # Eq. 1: (1/2) I_x theta'' = L1 F1 - L2 F2; the front half carries half the roll inertia.
    m, I = params.sprung_mass, 0.5 * params.roll_inertia
    L1, L2 = params.left_arm, params.right_arm
    k, c = params.stiffness, params.damping
    # Rows 1-2: q_dot = [1, L1; 1, -L2] [zdot, thetadot] - w.
    # Rows 3-4: [m zddot; (I_x/2) thetaddot] = [1, 1; L1, -L2] (-k q - c q_dot); q_dot carries -w,
    # hence the non-zero B rows 3-4.
    G = np.array([[1.0, L1], [1.0, -L2]])          # tip velocity = G [zdot, thetadot]
    M_inv = np.diag([1.0 / m, 1.0 / I])
    H = M_inv @ G.T                                  # generalised accel per unit tip force
    A = np.zeros((4, 4))
    A[:2, 2:] = G
    A[2:, :2] = -k * H
    A[2:, 2:] = -c * H @ G
    B = np.zeros((4, 2))
    B[:2, :] = -np.eye(2)
    B[2:, :] = c * H
    # Tip accelerations y = G [zddot, thetaddot] = G (rows 3-4 of A x + B w).
    C = G @ A[2:, :]
    D = G @ B[2:, :]
    return HalfCarModel(A=A, B=B, C=C, D=D, params=params)


@dataclass(frozen=True)
class FleetSpec:
    """How a heterogeneous fleet is drawn around nominal parameters.

    Parameters
    ----------
    nominal : HalfCarParameters
        Centre of the fleet.
    spread : float
        Relative half-width of the uniform spread of each true parameter around nominal
        (0.15 means +-15 %).
    estimate_uncertainty : float
        Relative standard deviation of each vehicle's *estimate* of its own parameters. The
        estimate is unbiased: ``theta_hat = theta * (1 + u * n)``, ``n ~ N(0, 1)``, truncated
        to +-3 sigma so it stays physical.
    symmetric : bool
        If True, left and right arms are equal for each vehicle.
    """

    nominal: HalfCarParameters = HalfCarParameters()
    spread: float = 0.15
    estimate_uncertainty: float = 0.10
    symmetric: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.nominal, HalfCarParameters):
            raise ParameterError(f"nominal must be a HalfCarParameters, got {type(self.nominal).__name__}")
        check_real("spread", self.spread, low=0.0, high=0.9)
        check_real("estimate_uncertainty", self.estimate_uncertainty, low=0.0, high=0.3)


@dataclass(frozen=True, eq=False)
class Vehicle:
    """One vehicle of a fleet: its true plant and the nominal model it believes in."""

    index: int
    true_params: HalfCarParameters
    estimated_params: HalfCarParameters

    @property
    def true_model(self) -> HalfCarModel:
        return half_car_model(self.true_params)

    @property
    def nominal_model(self) -> HalfCarModel:
        return half_car_model(self.estimated_params)


def sample_fleet(n_vehicles: int, spec: FleetSpec = FleetSpec(), *, rng=None) -> list[Vehicle]:
    """Draw ``n_vehicles`` heterogeneous vehicles and their parameter estimates.

    Parameters
    ----------
    n_vehicles : int
        Fleet size, >= 1.
    spec : FleetSpec
    rng : numpy.random.Generator | int | None

    Returns
    -------
    list of Vehicle

    Examples
    --------
    >>> import roadcollab as rc
    >>> fleet = rc.sample_fleet(3, rng=0)
    >>> [v.index for v in fleet]
    [0, 1, 2]
    >>> fleet[0].true_params == fleet[0].estimated_params   # each vehicle only knows an estimate
    False
    """
    n_vehicles = check_int("n_vehicles", n_vehicles, low=1)
    if not isinstance(spec, FleetSpec):
        raise ParameterError(f"spec must be a FleetSpec, got {type(spec).__name__}")
    rng = np.random.default_rng(rng)
    names = [f.name for f in fields(HalfCarParameters)]
    fleet = []
    for j in range(n_vehicles):
        true_f = 1.0 + spec.spread * rng.uniform(-1.0, 1.0, len(names))
        est_f = 1.0 + spec.estimate_uncertainty * np.clip(rng.standard_normal(len(names)), -3, 3)
        if spec.symmetric:
            i_l, i_r = names.index("left_arm"), names.index("right_arm")
            true_f[i_r], est_f[i_r] = true_f[i_l], est_f[i_l]
        true_p = spec.nominal.scaled(dict(zip(names, true_f)))
        est_p = true_p.scaled(dict(zip(names, est_f)))
        fleet.append(Vehicle(index=j, true_params=true_p, estimated_params=est_p))
    return fleet
