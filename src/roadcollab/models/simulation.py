"""Sampled-data simulation of a vehicle driven by the road.

Exactness: the road elevation is linear between samples (see
:meth:`roadcollab.models.profile.RoadProfile.sample`), so the road velocity ``w`` is constant over
each sample period and the zero-order-hold discretisation of the plant is exact:

.. math:: x_{k+1} = e^{A\\,dt} x_k + \\int_0^{dt} e^{A s} ds\\, B\\, w_k,\\qquad y_k = C x_k + D w_k.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validation import check_nonnegative, check_positive, check_signal
from ..lti.response import dlti_frequency_response
from ..lti.discretisation import zoh_discretize
from ..lti.modal import modal_states
from ..models.vehicle import HalfCarModel

__all__ = ["DiscretePlant", "discretize_plant", "simulate_response", "add_sensor_noise"]


@dataclass(frozen=True, eq=False)
class DiscretePlant:
    """ZOH-exact discrete plant with its modal decomposition (for fast simulation).

    Attributes
    ----------
    Ad, Bd : (4, 4), (4, 2) ndarray
    C, D : (2, 4), (2, 2) ndarray
    dt : float
        s.
    """

    Ad: np.ndarray
    Bd: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float
    # Derived in __post_init__: the modal form used by simulate_response.
    _modal: bool = field(init=False, repr=False)
    _keep: np.ndarray = field(init=False, repr=False)
    _weight: np.ndarray = field(init=False, repr=False)
    _lam: np.ndarray | None = field(init=False, repr=False, default=None)
    _CV: np.ndarray | None = field(init=False, repr=False, default=None)
    _VinvB: np.ndarray | None = field(init=False, repr=False, default=None)
    _Vinv: np.ndarray | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        lam, V = np.linalg.eig(self.Ad)
        # Keep one mode of each complex-conjugate pair (the other is its conjugate for a real
        # input): half the recursions. Real modes are kept as they are.
        keep = lam.imag >= 0
        pairs = np.isclose(lam[keep].imag, 0.0)
        modal = np.linalg.cond(V) < 1e8 and np.sum(lam.imag > 0) == np.sum(lam.imag < 0)
        object.__setattr__(self, "_modal", modal)
        object.__setattr__(self, "_keep", keep)
        object.__setattr__(self, "_weight", np.where(pairs, 1.0, 2.0))
        if modal:
            object.__setattr__(self, "_lam", lam)
            object.__setattr__(self, "_CV", self.C @ V)
            object.__setattr__(self, "_VinvB", np.linalg.solve(V, self.Bd))
            object.__setattr__(self, "_Vinv", np.linalg.inv(V))

    def frequency_response(self, omega_dt: np.ndarray) -> np.ndarray:
        """``P_d(e^{j omega dt})``.

        Parameters
        ----------
        omega_dt : (M,) array_like
            Normalised frequencies, rad/sample.

        Returns
        -------
        (M, 2, 2) complex ndarray
        """
        return dlti_frequency_response(self.Ad, self.Bd, self.C, self.D, omega_dt)

    def to_control(self):
        """The plant as a discrete :class:`control.StateSpace`."""
        import control

        return control.ss(self.Ad, self.Bd, self.C, self.D, self.dt)


def discretize_plant(model: HalfCarModel, dt: float) -> DiscretePlant:
    """ZOH discretisation of a half-car model (exact for piecewise-constant ``w``).

    Parameters
    ----------
    model : HalfCarModel
    dt : float
        Sample period, s.

    Returns
    -------
    DiscretePlant
    """
    dt = check_positive("dt", dt)
    Ad, Bd, C, D = zoh_discretize(model.A, model.B, model.C, model.D, dt)
    return DiscretePlant(Ad, Bd, C, D, dt)


def simulate_response(plant: DiscretePlant, w, *, x0=None) -> np.ndarray:
    """Body-tip accelerations of a plant (eqs. 1-3, ZOH-exact) driven by road velocity ``w``.

    Parameters
    ----------
    plant : DiscretePlant
    w : (N, 2) array_like
        Road velocity per sample, m/s (held constant over each sample period).
    x0 : (4,) array_like, optional
        Initial state; zero by default (vehicle at rest on a level road).

    Returns
    -------
    y : (N, 2) ndarray
        Noise-free accelerations, m/s^2.

    Examples
    --------
    >>> import numpy as np
    >>> import roadcollab as rc
    >>> plant = rc.discretize_plant(rc.half_car_model(rc.HalfCarParameters()), 0.01)
    >>> y = rc.simulate_response(plant, np.zeros((200, 2)))   # level road, vehicle at rest
    >>> y.shape, float(np.abs(y).max())
    ((200, 2), 0.0)
    """
    w = check_signal("w", w, 2)
    x0 = np.zeros(4) if x0 is None else np.asarray(x0, dtype=float).reshape(4)
    lam, CV, VinvB, Vinv = plant._lam, plant._CV, plant._VinvB, plant._Vinv
    if not plant._modal or lam is None or CV is None or VinvB is None or Vinv is None:  # defective Ad: recursion
        import scipy.signal  # heavy (about 1 s); imported when needed, not with the package

        _, y, _ = scipy.signal.dlsim((plant.Ad, plant.Bd, plant.C, plant.D, plant.dt), w, x0=x0)
        return y
    # Modal form: one first-order complex recursion per mode, x = V xi (lti.modal).
    keep = plant._keep
    u = w @ VinvB[keep].T                                   # (N, k) complex
    xi = modal_states(lam[keep], u, (Vinv @ x0)[keep])[:-1]
    # y = C V xi: a conjugate pair contributes 2 Re(c v xi) of the kept mode.
    return (xi @ (CV[:, keep] * plant._weight).T).real + w @ plant.D.T


def add_sensor_noise(y, noise_std: float, *, rng=None) -> np.ndarray:
    """Add white Gaussian accelerometer noise of standard deviation ``noise_std`` (m/s^2).

    Parameters
    ----------
    y : (N, p) array_like
        Noise-free accelerations, m/s^2 (finite).
    noise_std : float
        Standard deviation of the noise, m/s^2, >= 0 (independent per sample and channel).
    rng : numpy.random.Generator | int | None

    Returns
    -------
    (N, p) ndarray
        ``y`` plus the noise, m/s^2.
    """
    y = check_signal("y", y)
    noise_std = check_nonnegative("noise_std", noise_std)
    rng = np.random.default_rng(rng)
    return y + noise_std * rng.standard_normal(y.shape)
