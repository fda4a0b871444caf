"""Half-car model (eqs. 1-3) against hand-derived entries and closed-form modes."""

import dataclasses

import control
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from roadcollab import HalfCarParameters, ParameterError, half_car_model, sample_fleet
from roadcollab.models.vehicle import FleetSpec

EXAMPLE = HalfCarParameters(sprung_mass=500.0, roll_inertia=400.0, left_arm=0.75, right_arm=0.75,
                            stiffness=20e3, damping=1.5e3)


def test_hand_derived_entries():
    m = half_car_model(EXAMPLE)
    # q1' = zdot + L1 thetadot - wl ; q2' = zdot - L2 thetadot - wr
    np.testing.assert_allclose(m.A[0], [0, 0, 1, 0.75])
    np.testing.assert_allclose(m.A[1], [0, 0, 1, -0.75])
    np.testing.assert_allclose(m.B[:2], -np.eye(2))
    # m zddot = -k (q1 + q2) - c (q1' + q2'): -k/m = -40, -2c/m = -6, c/m = 3
    np.testing.assert_allclose(m.A[2], [-40, -40, -6, 0])
    np.testing.assert_allclose(m.B[2], [3, 3])
    # Eq. 1: (1/2) I_x thetaddot = L1 F1 - L2 F2 with I_x / 2 = 200:
    # -k L1/200 = -75, -c (L1^2 + L2^2)/200 = -8.4375, c L1/200 = 5.625
    np.testing.assert_allclose(m.A[3], [-75, 75, 0, -8.4375])
    np.testing.assert_allclose(m.B[3], [5.625, -5.625])
    # y1 = zddot + L1 thetaddot: D[0] = [3 + 0.75 * 5.625, 3 - 0.75 * 5.625]
    np.testing.assert_allclose(m.D, [[7.21875, -1.21875], [-1.21875, 7.21875]])
    np.testing.assert_allclose(m.C[0], m.A[2] + 0.75 * m.A[3])
    np.testing.assert_allclose(m.C[1], m.A[2] - 0.75 * m.A[3])


def test_closed_form_modes_for_symmetric_arms():
    m = half_car_model(EXAMPLE)
    p = EXAMPLE
    wn_heave = np.sqrt(2 * p.stiffness / p.sprung_mass)
    zeta_heave = p.damping / (p.sprung_mass * wn_heave)
    # Eq. 1 carries (1/2) I_x: omega^2 = 2 k (L1^2 + L2^2) / I_x.
    wn_roll = np.sqrt(2 * p.stiffness * (p.left_arm**2 + p.right_arm**2) / p.roll_inertia)
    zeta_roll = p.damping * (p.left_arm**2 + p.right_arm**2) / (p.roll_inertia * wn_roll)
    ev = m.poles()
    wn = np.sort(np.abs(ev))
    np.testing.assert_allclose(wn, np.sort([wn_roll, wn_roll, wn_heave, wn_heave]), rtol=1e-10)
    zeta = -ev.real / np.abs(ev)
    np.testing.assert_allclose(np.sort(np.unique(zeta.round(12))), np.sort([zeta_roll, zeta_heave]), rtol=1e-9)
    # The paper's example: heave 1.42 Hz (zeta 0.34), roll 1.69 Hz (zeta 0.40).
    assert wn_heave / (2 * np.pi) == pytest.approx(1.4235, abs=1e-3)
    assert zeta_heave == pytest.approx(0.335, abs=1e-3)
    assert wn_roll / (2 * np.pi) == pytest.approx(1.6882, abs=1e-3)
    assert zeta_roll == pytest.approx(0.398, abs=1e-3)


@given(st.floats(300, 1200), st.floats(200, 900), st.floats(0.5, 1.0), st.floats(0.5, 1.0),
       st.floats(1e4, 4e4), st.floats(500, 4000))
def test_transmission_zeros_double_at_dc_and_at_minus_k_over_c(m, I, L1, L2, k, c):
    model = half_car_model(HalfCarParameters(m, I, L1, L2, k, c))
    assert abs(np.linalg.det(model.D)) > 0
    z = np.sort_complex(control.ss(model.A, model.B, model.C, model.D).zeros())
    np.testing.assert_allclose(np.sort(np.abs(z)), [0, 0, k / c, k / c], atol=1e-6 * k / c)
    # P(0) = 0: accelerations cannot see a constant road velocity.
    np.testing.assert_allclose(model.frequency_response(np.array([0.0]))[0], 0, atol=1e-9)


@pytest.mark.parametrize("field,value,match", [
    ("sprung_mass", -500.0, "sprung_mass must be > 0, got -500"),
    ("damping", 0.0, "damping must be > 0, got 0"),
    ("stiffness", float("nan"), "stiffness must be finite"),
    ("roll_inertia", "heavy", "roll_inertia must be a real number"),
])
def test_bad_parameters_are_named(field, value, match):
    with pytest.raises(ParameterError, match=match):
        dataclasses.replace(EXAMPLE, **{field: value})


def test_fleet_is_heterogeneous_unbiased_and_seeded():
    spec = FleetSpec(spread=0.15, estimate_uncertainty=0.1)
    a = sample_fleet(400, spec, rng=7)
    b = sample_fleet(400, spec, rng=7)
    assert [v.true_params for v in a] == [v.true_params for v in b]
    ratio = np.array([v.estimated_params.stiffness / v.true_params.stiffness for v in a])
    # Unbiased with 10 % relative std: mean 1 +- 3 sigma/sqrt(n) = 0.015
    assert abs(ratio.mean() - 1) < 0.015
    assert 0.085 < ratio.std() < 0.115
    k = np.array([v.true_params.stiffness for v in a])
    assert k.min() >= spec.nominal.stiffness * 0.85 - 1e-9 and k.max() <= spec.nominal.stiffness * 1.15 + 1e-9
    with pytest.raises(ParameterError, match="n_vehicles must be >= 1, got 0"):
        sample_fleet(0, spec)
    with pytest.raises(ParameterError, match="estimate_uncertainty must be <= 0.3"):
        FleetSpec(estimate_uncertainty=0.5)
