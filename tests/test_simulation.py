"""Sampled-data simulation: ZOH exactness and the fast modal recursion."""

import numpy as np
import pytest
import scipy.integrate
import scipy.signal

from roadcollab import HalfCarParameters, half_car_model
from roadcollab.lti import kernels
from roadcollab.models.simulation import add_sensor_noise, discretize_plant, simulate_response

MODEL = half_car_model(HalfCarParameters())


def test_zoh_is_exact_for_piecewise_linear_elevation():
    # Integrate the continuous ODE with w held constant over each sample (elevation linear
    # between samples) and compare with the discrete recursion.
    dt = 0.005
    rng = np.random.default_rng(1)
    w = rng.standard_normal((60, 2)) * 0.2
    x = np.zeros(4)
    ys = []
    for k in range(w.shape[0]):
        ys.append(MODEL.C @ x + MODEL.D @ w[k])
        sol = scipy.integrate.solve_ivp(lambda t, s, wk=w[k]: MODEL.A @ s + MODEL.B @ wk, (0, dt), x,
                                        rtol=1e-12, atol=1e-14, method="DOP853")
        x = sol.y[:, -1]
    y = simulate_response(discretize_plant(MODEL, dt), w)
    np.testing.assert_allclose(y, np.array(ys), atol=1e-8 * np.abs(ys).max())


def test_modal_recursion_equals_dlsim_with_initial_state():
    plant = discretize_plant(MODEL, 0.005)
    rng = np.random.default_rng(2)
    w = rng.standard_normal((3000, 2))
    x0 = np.array([0.01, -0.02, 0.1, 0.05])
    _, ref, _ = scipy.signal.dlsim((plant.Ad, plant.Bd, plant.C, plant.D, plant.dt), w, x0=x0)
    np.testing.assert_allclose(simulate_response(plant, w, x0=x0), ref, atol=1e-10 * np.abs(ref).max())


def test_sensor_noise_is_seeded_and_has_the_requested_std():
    y = np.zeros((200000, 2))
    a = add_sensor_noise(y, 0.05, rng=3)
    np.testing.assert_array_equal(a, add_sensor_noise(y, 0.05, rng=3))
    assert abs(a.std() - 0.05) < 0.05 * 0.01


def test_modal_states_equal_the_stepped_recursion():
    # Oracle: xi[k+1] = lam xi[k] + u[k] stepped one sample at a time, xi[0] = xi0.
    from roadcollab.lti.modal import modal_states
    rng = np.random.default_rng(4)
    lam = np.array([0.9 + 0.3j, 0.5, -0.2j])
    u = rng.standard_normal((50, 3)) + 1j * rng.standard_normal((50, 3))
    xi0 = np.array([1.0, -2.0 + 1j, 0.5j])
    ref = [xi0]
    for k in range(50):
        ref.append(lam * ref[-1] + u[k])
    got = modal_states(lam, u, xi0)
    assert got.shape == (51, 3)
    np.testing.assert_allclose(got, np.array(ref), rtol=0, atol=1e-13)


@pytest.mark.skipif(not kernels.compiled_available(), reason="numba not importable")
def test_compiled_modal_states_are_the_bits_of_lfilter():
    # The compiled recursion (lti._modal_kernel) does lfilter's complex product and sum per step
    # (b = [0, 1], a = [1, -lam]): the same bits, over random poles, inputs from 1e-8 to 1e3 and lengths.
    from roadcollab.lti.modal import modal_states
    rng = np.random.default_rng(5)
    for _ in range(60):
        k, n = int(rng.integers(1, 5)), int(rng.integers(0, 3000))
        lam = rng.uniform(0.3, 0.999, k) * np.exp(1j * rng.uniform(-3, 3, k))
        u = (rng.standard_normal((n, k)) + 1j * rng.standard_normal((n, k))) * 10.0 ** rng.uniform(-8, 3)
        xi0 = rng.standard_normal(k) + 1j * rng.standard_normal(k)
        with kernels.use_kernels("reference"):
            ref = modal_states(lam, u, xi0)
        with kernels.use_kernels("compiled"):
            got = modal_states(lam, u, xi0)
        assert got.shape == ref.shape == (n + 1, k)
        np.testing.assert_array_equal(got.view(float), ref.view(float))


def test_the_half_car_simulation_is_the_same_on_both_kernel_paths():
    plant = discretize_plant(MODEL, 0.005)
    w = np.random.default_rng(6).standard_normal((2000, 2))
    with kernels.use_kernels("reference"):
        ref = simulate_response(plant, w)
    with kernels.use_kernels("compiled"):
        got = simulate_response(plant, w)
    np.testing.assert_array_equal(got, ref)
