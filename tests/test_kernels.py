"""Compiled kernels (``lti.kernels``) against the numpy reference path and a direct solve."""

import subprocess
import sys

import numpy as np
import scipy.linalg
import pytest

from roadcollab.errors import ParameterError
from roadcollab.lti import _pole_kernel, kernels
from roadcollab.lti.blockdiag import block_response, block_schur
from roadcollab.lti.response import ss_response

_numba = pytest.mark.skipif(not kernels.compiled_available(), reason="numba not importable")
#: The compiled path: skipped without numba, and slow (the first test of a fresh install compiles every
#: kernel: 30-40 s of the fast suite's wall time in CI, where the cache is always cold).
COMPILED = pytest.param("compiled", marks=[_numba, pytest.mark.slow])


def needs_numba(test):
    """Mark a test of the compiled path (see :data:`COMPILED`)."""
    return pytest.mark.slow(_numba(test))


def _direct(A, B, C, D, z):
    n = A.shape[0]
    X = np.linalg.solve(z[:, None, None] * np.eye(n) - A, np.broadcast_to(B.astype(complex), (z.size,) + B.shape))
    return C @ X + D


def _rel(a, b):
    return float(np.max(np.linalg.norm(a - b, axis=(1, 2)) / np.linalg.norm(b, axis=(1, 2))))


def _system(rng, n, close=False):
    """A random stable (n, 2, 2) discrete system; with ``close``, poles in near pairs (2x2 blocks)."""
    lam = rng.uniform(0.3, 0.95, n) * np.exp(1j * rng.uniform(0, np.pi, n))
    if close:
        lam[1::2] = lam[0::2][: n // 2] + 1e-4
    Q = np.linalg.qr(rng.standard_normal((n, n)))[0]
    T = np.diag(lam.real) + np.triu(rng.standard_normal((n, n)) * 0.3, 1)
    A = Q @ T @ Q.T
    return A, rng.standard_normal((n, 2)), rng.standard_normal((2, n)), rng.standard_normal((2, 2))


@needs_numba
@pytest.mark.parametrize("close", [False, True])
def test_compiled_block_response_equals_reference_and_direct_solve(close):
    rng = np.random.default_rng(11 + close)
    z = np.exp(1j * np.linspace(1e-3, 3.0, 400))
    for n in (1, 4, 9, 16):
        A, B, C, D = _system(rng, n, close)
        bs = block_schur(A, B, C)
        with kernels.use_kernels("compiled"):
            got = block_response(bs, D, z)
        with kernels.use_kernels("reference"):
            ref = block_response(bs, D, z)
        assert _rel(got, ref) < 1e-12
        assert _rel(got, _direct(A, B, C, D, z)) < 1e-10


@needs_numba
def test_compiled_pole_residue_equals_reference():
    rng = np.random.default_rng(5)
    z = np.exp(1j * np.linspace(1e-3, 3.0, 300))
    A = np.diag([0.9, 0.5, -0.3, 0.7])
    B, C, D = rng.standard_normal((4, 2)), rng.standard_normal((2, 4)), rng.standard_normal((2, 2))
    with kernels.use_kernels("compiled"):
        got = ss_response(A, B, C, D, z)
    with kernels.use_kernels("reference"):
        ref = ss_response(A, B, C, D, z)
    assert _rel(got, ref) < 1e-13
    assert _rel(got, _direct(A, B, C, D, z)) < 1e-12


def test_the_parts_of_a_unit_circle_vector_are_split_once_while_it_stays_frozen():
    from roadcollab.lti.response import unit_circle

    w = np.exp(1j * np.linspace(0.0, 3.0, 50))
    w.flags.writeable = False
    re, im = kernels.complex_parts(w)
    assert np.array_equal(re, w.real) and np.array_equal(im, w.imag)
    assert not re.flags.writeable and not im.flags.writeable and re.flags.c_contiguous
    assert kernels.complex_parts(w)[0] is not re              # not one of unit_circle's: split every time
    z = unit_circle(np.linspace(0.0, 3.0, 47))
    re, im = kernels.complex_parts(z)
    assert np.array_equal(re, z.real) and np.array_equal(im, z.imag)
    assert kernels.complex_parts(z)[0] is re                  # unit_circle's, frozen: found by identity
    z.flags.writeable = True
    try:
        assert kernels.complex_parts(z)[0] is not re          # thawed: split again
    finally:
        z.flags.writeable = False                             # unit_circle's, as it was


def test_kernel_choice():
    with kernels.use_kernels("reference"):
        assert kernels.kernel_path() == "reference"
    with pytest.raises(ParameterError, match="kernels must be one of"):
        with kernels.use_kernels("fast"):
            pass


def test_kernel_environment_variable(monkeypatch):
    monkeypatch.setenv("ROADCOLLAB_KERNELS", "reference")
    assert kernels.kernel_path() == "reference"
    monkeypatch.setenv("ROADCOLLAB_KERNELS", "turbo")
    with pytest.raises(ParameterError, match="ROADCOLLAB_KERNELS must be 'compiled' or 'reference', got 'turbo'"):
        kernels.kernel_path()


def _without_numba(code: str) -> str:
    """Run ``code`` (which blocks ``import numba`` itself) in a fresh interpreter; its stripped stdout."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_everything_runs_on_the_numpy_path_without_numba():
    # A fresh interpreter where ``import numba`` fails (as when it is not installed).
    code = (
        "import sys; sys.modules['numba'] = None\n"
        "import numpy as np, roadcollab as rc\n"
        "from roadcollab.lti import kernels\n"
        "assert not kernels.compiled_available() and kernels.kernel_path() == 'reference'\n"
        "cfg = rc.ExperimentConfig(n_vehicles=2, n_runs=1, segment_length=60.0)\n"
        "pipe = rc.FleetPipeline(cfg, rc.sample_fleet(2, cfg.fleet, rng=1))\n"
        "w = pipe.road(np.random.default_rng(0)).velocity[:pipe.grid.n_samples]\n"
        "ys = rc.simulate_measurements(pipe.estimators, w, 0.05, rng=2)\n"
        "steps = rc.Relay(pipe.estimators, rc.Exchange('paper', cfg.obfuscation), rng=3, unguarded=True).run(ys)\n"
        "clear = rc.Relay(pipe.estimators, 'none', unguarded=True).run(ys)\n"
        "a, b = steps[1].result.estimate, clear[1].result.estimate\n"
        "assert np.max(np.abs(a - b)) <= 1e-9 * np.max(np.abs(b))\n"
        "print('ok')\n")
    assert _without_numba(code) == "ok"


def test_the_batch_commands_run_on_the_numpy_path_without_numba(tmp_path):
    # reproduce defaults to the compiled path; where numba does not import it runs on numpy, says so in
    # config.json and starts no second compile process.
    code = (
        "import sys, json; sys.modules['numba'] = None\n"
        "from roadcollab.cli.main import main\n"
        "from roadcollab.experiments.bench import warm\n"
        f"out = {str(tmp_path / 'r')!r}\n"
        "assert main(['reproduce', '--runs', '1', '--vehicles', '2', '--measured-runs', '0', '--out', out]) == 0\n"
        "assert json.load(open(out + '/config.json'))['kernels'] == 'reference'\n"
        "assert warm._STARTED == []\n"
        "print('ok')\n")
    assert _without_numba(code).splitlines()[-1] == "ok"


@needs_numba
@pytest.mark.parametrize("option, expected", [([], "compiled"), (["--kernels", "reference"], "reference")])
def test_reproduce_runs_on_the_compiled_path_unless_told_otherwise(tmp_path, monkeypatch, option, expected):
    import json

    from roadcollab.cli.main import main
    from roadcollab.experiments.bench import warm

    monkeypatch.delenv("ROADCOLLAB_KERNELS", raising=False)
    monkeypatch.setattr(warm, "start_background_compile", lambda: None)
    out = tmp_path / "r"
    assert main(["reproduce", "--runs", "1", "--vehicles", "2", "--measured-runs", "0", "--out", str(out), *option]) == 0
    assert json.loads((out / "config.json").read_text())["kernels"] == expected
    assert f"kernels {expected}" in (out / "report.md").read_text()
    assert kernels.kernel_path() == "reference"     # the command's choice ends with the command


@needs_numba
@pytest.mark.parametrize("tight", [{}, {"max_condition": 40.0}, {"max_gain_range": 8.0}])
def test_compiled_psi_draw_is_the_reference_draw_and_leaves_the_same_generator_state(tight):
    # The compiled rejection loop draws from the caller's generator: the same candidates accepted, the
    # same generator state after every draw; the design and its realisation equal up to round-off. Tighter
    # bounds reject candidates on bins past the lowest ones the compiled check looks at first.
    from roadcollab.estimation.grid import SegmentGrid
    from roadcollab.experiments.bench.naive import direct_response
    from roadcollab.privacy.obfuscator_design import ObfuscationSpec, draw_obfuscator

    grid = SegmentGrid(n_samples=4000, sample_rate=200.0)
    spec = ObfuscationSpec(**tight)
    ra, rb = np.random.default_rng(11), np.random.default_rng(11)
    for _ in range(60):
        with kernels.use_kernels("reference"):
            a = draw_obfuscator(spec, grid, rng=ra)
        with kernels.use_kernels("compiled"):
            b = draw_obfuscator(spec, grid, rng=rb)
        assert ra.bit_generator.state == rb.bit_generator.state
        assert a.order == b.order and a.system.order == b.system.order
        assert np.allclose(b.poles, a.poles, rtol=1e-14, atol=0)
        assert np.allclose(b.numerators, a.numerators, rtol=1e-13, atol=1e-13 * np.abs(a.numerators).max())
        om = grid.omega_dt[::7]
        assert _rel(direct_response(b.system, om), direct_response(a.system, om)) < 1e-10
    # A spec no candidate satisfies fails the same way on both paths.
    strict = ObfuscationSpec(max_condition=1.0000001)
    for path in kernels.KERNELS:
        with kernels.use_kernels(path), pytest.raises(ParameterError, match="max_attempts=5"):
            draw_obfuscator(strict, grid, rng=np.random.default_rng(0), max_attempts=5)


@needs_numba
@pytest.mark.parametrize("path", kernels.KERNELS)
def test_a_pair_of_psi_draws_is_two_draws_in_turn(path):
    """draw_obfuscator_pair (one compiled call for both rejection loops) draws what two draw_obfuscator calls
    draw, bit for bit, and leaves the generator where they leave it; with a spec nothing satisfies, the first
    draw fails and the second is not drawn, as with two calls."""
    from roadcollab.estimation.grid import SegmentGrid
    from roadcollab.privacy.obfuscator_design import ObfuscationSpec, draw_obfuscator, draw_obfuscator_pair

    grid = SegmentGrid(n_samples=1000, sample_rate=200.0)
    ra, rb = np.random.default_rng(21), np.random.default_rng(21)
    with kernels.use_kernels(path):
        for _ in range(15):
            pair = draw_obfuscator_pair(ObfuscationSpec(), grid, rng=ra)
            one = (draw_obfuscator(ObfuscationSpec(), grid, rng=rb), draw_obfuscator(ObfuscationSpec(), grid, rng=rb))
            assert ra.bit_generator.state == rb.bit_generator.state
            for a, b in zip(pair, one):
                assert a.poles.tobytes() == b.poles.tobytes() and a.numerators.tobytes() == b.numerators.tobytes()
                assert a.system.A.tobytes() == b.system.A.tobytes() and a.system.C.tobytes() == b.system.C.tobytes()
        strict = ObfuscationSpec(max_condition=1.0000001)
        ra, rb = np.random.default_rng(0), np.random.default_rng(0)
        with pytest.raises(ParameterError, match="max_attempts=5"):
            draw_obfuscator_pair(strict, grid, rng=ra, max_attempts=5)
        with pytest.raises(ParameterError, match="max_attempts=5"):
            draw_obfuscator(strict, grid, rng=rb, max_attempts=5)
        assert ra.bit_generator.state == rb.bit_generator.state


@pytest.mark.parametrize("path", [COMPILED, "reference"])
def test_psi_response_from_its_poles_and_residues_is_the_realisation_response(path):
    # Obfuscator.frequency_response (the design's poles and residues through the bilinear map) against
    # a dense solve of the discrete realisation: equal up to the realisation's rounding (measured 7.6e-12
    # over 300 draws), at Nyquist too (z = -1).
    from roadcollab.estimation.grid import SegmentGrid
    from roadcollab.experiments.bench.naive import direct_response
    from roadcollab.privacy.obfuscator_design import ObfuscationSpec, draw_obfuscator

    grid = SegmentGrid(n_samples=4000, sample_rate=200.0)
    rng = np.random.default_rng(2)
    for _ in range(20):
        psi = draw_obfuscator(ObfuscationSpec(), grid, rng=rng)
        with kernels.use_kernels(path):
            got = psi.frequency_response(grid.omega_dt)
            zp, res, direct = psi.pole_residues()
        assert _rel(got, direct_response(psi.system, grid.omega_dt)) < 1e-10
        assert np.allclose(direct, psi.system.D, rtol=1e-12, atol=1e-14)
        with kernels.use_kernels("reference"):
            zp_ref, res_ref, _ = psi.pole_residues()
        assert np.allclose(zp, zp_ref, rtol=1e-14, atol=0)
        assert _rel(res, res_ref) < 1e-12


@needs_numba
def test_paper_segments_on_both_paths_leave_the_same_generator_state_and_the_same_estimates():
    # Three vehicles relay `paper` over three segments on each path from one seed: after every segment
    # the relay's generator is in the same state, and every vehicle's estimate agrees to round-off.
    import dataclasses

    from roadcollab.collaboration.relay import Exchange, Relay, simulate_measurements
    from roadcollab.experiments.bench.study import _config_for
    from roadcollab.experiments.pipeline import FleetPipeline
    from roadcollab.models.vehicle import sample_fleet

    cfg = dataclasses.replace(_config_for(2000), n_vehicles=3)
    pipe = FleetPipeline(cfg, sample_fleet(3, cfg.fleet, rng=3))
    roads = np.random.default_rng(4)
    relays = {k: Relay(pipe.estimators, Exchange("paper", cfg.obfuscation), rng=5, unguarded=True) for k in kernels.KERNELS}
    for _ in range(3):
        w = pipe.road(roads).velocity[:pipe.grid.n_samples]
        ys = simulate_measurements(pipe.estimators, w, cfg.sensor_noise_std, rng=roads)
        steps = {}
        for k, relay in relays.items():
            with kernels.use_kernels(k):
                steps[k] = relay.run(ys)
        assert relays["compiled"].rng.bit_generator.state == relays["reference"].rng.bit_generator.state
        for a, b in zip(steps["compiled"], steps["reference"]):
            ref = b.result.estimate
            assert np.max(np.abs(a.result.estimate - ref)) <= 1e-9 * np.max(np.abs(ref))


@needs_numba
def test_compiled_certificate_and_schur_form_agree_with_the_reference():
    """The compiled Schur form is one (unitary, triangular, backward stable); the compiled Lyapunov
    certificate gives the reference's radius and gain up to the solutions' error, and refuses what
    the reference refuses."""
    import scipy.linalg

    from roadcollab.lti._cert_kernel import complex_schur
    from roadcollab.lti.stability import spectral_radius_and_gain

    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 12, 22):
        for close in (False, True):
            A = _system(rng, n, close)[0]
            T, U = complex_schur(A)
            assert not np.tril(T, -1).any()
            assert np.linalg.norm(U @ T @ U.conj().T - A) <= 1e-14 * n * np.linalg.norm(A)
            assert np.linalg.norm(U.conj().T @ U - np.eye(n)) <= 1e-14 * n
            schur = scipy.linalg.schur(A, output="complex")
            with kernels.use_kernels("reference"):
                r0, g0 = spectral_radius_and_gain(A, schur=schur)
            with kernels.use_kernels("compiled"):
                for sch in (schur, (T, U)):
                    r1, g1 = spectral_radius_and_gain(A, schur=sch)
                    # Two verified solutions of the same equation (residual <= 1e-8 relative): equal
                    # gains up to the solutions' own error, as test_blockdiag's Schur-vs-eigen check;
                    # radii from two Schur forms, eigenvalue pairs 1e-4 apart (condition ~1e4).
                    assert abs(r0 - r1) <= 1e-10 and np.isfinite(g1) and abs(g0 - g1) <= 1e-6 * g0
    jordan = 0.99 * np.eye(64) + np.diag(np.ones(63), 1)
    jordan[-1, 0] = 1e-16        # computed radius 0.99, true radius 1.55: no certificate
    with kernels.use_kernels("compiled"):
        assert spectral_radius_and_gain(jordan, schur=scipy.linalg.schur(jordan, output="complex"))[1] == np.inf
        assert spectral_radius_and_gain(jordan, schur=complex_schur(jordan))[1] == np.inf


@needs_numba
def test_a_sender_validates_its_outgoing_message_with_the_receivers_certificate():
    """On the compiled path a sender certifies its obfuscated ``T~``, ``S~`` from the triangular form it
    knows from their parts (no Schur decomposition of its own) and a receiver from the Schur form of the
    decoded bytes: the same radius to 1e-12 and gain to 1e-9 relative; and the fused certificate's
    figures are those of the reference residual check, to round-off. A sender whose form fails the
    check certifies its system as a receiver does, bit for bit."""
    from roadcollab.collaboration.relay import Exchange, Relay
    from roadcollab.experiments.bench.study import _config_for
    from roadcollab.experiments.pipeline import FleetPipeline
    from roadcollab.lti import stability
    from roadcollab.lti._cert_kernel import complex_schur, schur_certificate, schur_lyapunov
    from roadcollab.lti.realisation import SystemCache
    from roadcollab.models.vehicle import sample_fleet
    from roadcollab.wire import protocol

    cfg = _config_for(2000)
    pipe = FleetPipeline(cfg, sample_fleet(2, cfg.fleet, rng=7))
    roads = np.random.default_rng(8)
    relay = Relay(pipe.estimators, Exchange("paper", cfg.obfuscation), rng=9, unguarded=True)
    with kernels.use_kernels("compiled"):
        for _ in range(4):
            w = pipe.road(roads).velocity[:pipe.grid.n_samples]
            sent = relay.send(0, pipe.estimators[0].estimate(w[:pipe.grid.n_samples]))
            got = protocol.decode(protocol.encode(sent.message), systems=SystemCache())
            for name in ("T", "S"):
                mine, theirs = getattr(sent.message, name), getattr(got, name)
                assert "_cert_form" in mine.__dict__
                (r_mine, g_mine), (r_theirs, g_theirs) = mine.stability(), theirs.stability()
                assert abs(r_mine - r_theirs) <= 1e-12 and abs(g_mine - g_theirs) <= 1e-9 * g_theirs
                assert np.isfinite(g_mine)
                # A form that fails its check (here: a wrong Q) leaves the receiver's route.
                key, (Rf, Uf, sc, Q) = mine.__dict__["_cert_form"]
                again = type(mine)(mine.A, mine.B, mine.C, mine.D, mine.dt)
                object.__setattr__(again, "_cert_form", (key, (Rf, Uf, sc, np.eye(Q.shape[0]))))
                assert stability.hidden_radius_and_gain(np.asarray(mine.A), Rf, Uf, sc, np.eye(Q.shape[0]))[1] == np.inf
                assert again.stability() == theirs.stability()
                A = np.asarray(mine.A, dtype=float)
                R, U = complex_schur(A)
                X, resid, scale = schur_certificate(R, U, A)
                X0 = schur_lyapunov(R, U)
                X0 = 0.5 * (X0 + X0.T)
                assert np.linalg.norm(X - X0) <= 1e-12 * np.linalg.norm(X0)
                assert abs(scale - np.linalg.norm(X0) * (1 + np.linalg.norm(A) ** 2)) <= 1e-12 * scale
                resid0 = np.linalg.norm(A.T @ X0 @ A - X0 + np.eye(A.shape[0]))
                assert resid <= stability.LYAPUNOV_RTOL * scale and abs(resid - resid0) <= 1e-6 * scale
    bad = np.full((3, 3), np.nan)
    assert np.isnan(schur_certificate(bad.astype(complex), np.eye(3, dtype=complex), np.eye(3))[1])


def test_the_schur_form_of_a_series_connection_comes_from_its_parts():
    """``series_schur``: ``A = U R U^H`` for the series connection's ``A``, ``U`` unitary, ``R`` upper
    triangular with the parts' eigenvalues on its diagonal (oracle: the definition)."""
    from roadcollab.lti.composed_schur import series_schur
    from roadcollab.lti.realisation import StateSpaceData, series

    rng = np.random.default_rng(11)
    parts = [StateSpaceData(0.3 * rng.standard_normal((n, n)), rng.standard_normal((n, 2)),
                            rng.standard_normal((2, n)), rng.standard_normal((2, 2)), 0.01) for n in (5, 3, 4)]
    forms = [scipy.linalg.schur(p.A, output="complex") for p in parts]     # (R, U) each
    first = series(parts[0], parts[1])
    whole = series(first, parts[2])
    R, U = series_schur(series_schur(forms[0], forms[1], first.A), forms[2], whole.A)
    assert np.allclose(np.tril(R, -1), 0.0, atol=0.0)
    assert np.linalg.norm(U.conj().T @ U - np.eye(12)) <= 1e-13
    assert np.linalg.norm(U @ R @ U.conj().T - whole.A) <= 1e-13 * np.linalg.norm(whole.A)
    ev, d = np.linalg.eigvals(whole.A), np.diag(R)
    assert np.abs(d[:, None] - ev[None, :]).min(axis=1).max() <= 1e-12
    assert np.abs(d[:, None] - ev[None, :]).min(axis=0).max() <= 1e-12


@needs_numba
def test_a_hidden_systems_certificate_from_its_form_is_the_one_of_its_schur_form():
    """``hidden_figures`` on ``A~ = Q^T D^-1 A D Q`` from ``A``'s Schur form, ``D`` and ``Q`` gives the
    radius, residual check and eigenvalues of ``X`` that ``certificate_figures`` gives from ``A~``'s own
    Schur form, to round-off (the Lyapunov solution is unique); an unstable ``A`` gets no certificate."""
    from roadcollab.lti._cert_kernel import certificate_figures, complex_schur, hidden_figures
    from roadcollab.lti import stability

    rng = np.random.default_rng(12)
    for n, spread in ((1, 0), (6, 1), (18, 2), (22, 3)):
        A = rng.standard_normal((n, n))
        A /= 1.3 * np.max(np.abs(np.linalg.eigvals(A)))
        scale = 2.0 ** rng.integers(-spread, spread + 1, n).astype(float)
        Q = np.linalg.qr(rng.standard_normal((n, n)))[0]
        At = Q.T @ (A * scale[None, :] / scale[:, None]) @ Q
        R, U = scipy.linalg.schur(A, output="complex")
        got = hidden_figures(R, U, scale, Q, At)
        ref = certificate_figures(*complex_schur(At), At)
        # The form's radius is A's (1 / 1.3 by construction); At's own Schur form carries the eigenvalue
        # error of At, which grows with the spread of D (3.7e-11 at 2^20, so the spreads here are small).
        assert abs(got[0] - 1 / 1.3) <= 1e-14 and abs(got[0] - ref[0]) <= 1e-11
        assert got[1] <= stability.LYAPUNOV_RTOL * got[2]
        assert abs(got[3] - ref[3]) <= 1e-9 * ref[4] and abs(got[4] - ref[4]) <= 1e-9 * ref[4]
        with kernels.use_kernels("compiled"):
            g = stability.hidden_radius_and_gain(At, R, U, scale, Q)[1]
            g_ref = stability.spectral_radius_and_gain(At, schur=complex_schur(At))[1]
        assert abs(g - g_ref) <= 1e-9 * g_ref
    R, U = scipy.linalg.schur(1.01 * np.eye(3), output="complex")
    assert stability.hidden_radius_and_gain(1.01 * np.eye(3), R, U, np.ones(3), np.eye(3))[1] == np.inf


@needs_numba
def test_one_compiled_call_gives_the_radius_and_gain_of_the_separate_steps():
    """``certificate_figures`` (radius, Stein solve, residual and the eigenvalues of ``X`` in one call) gives
    what ``schur_certificate`` and ``np.linalg.eigvalsh`` give, to round-off; and
    ``spectral_radius_and_gain`` on the compiled path agrees with the numpy path on stable, unstable,
    defective and non-normal matrices (a Jordan block gets a larger gain than its diagonal)."""
    from roadcollab.lti import stability
    from roadcollab.lti._cert_kernel import certificate_figures, complex_schur, schur_certificate

    rng = np.random.default_rng(3)
    jordan = np.diag(np.full(12, 0.9)) + np.diag(np.full(11, 1.0), 1)
    cases = [rng.standard_normal((n, n)) for n in (1, 4, 18, 22)]
    cases = [A / (1.25 * np.max(np.abs(np.linalg.eigvals(A)))) for A in cases] + [1.01 * np.eye(3), jordan,
                                                                               np.diag([0.5, 0.999999])]
    for A in cases:
        R, U = complex_schur(A)
        radius, resid, scale, lo, hi = certificate_figures(R, U, A)
        assert radius == float(np.max(np.abs(np.diag(R))))
        if radius < 1.0:
            X, resid0, scale0 = schur_certificate(R, U, A)
            ev = np.linalg.eigvalsh(X)
            assert (resid, scale) == (resid0, scale0)
            assert abs(lo - ev[0]) <= 1e-12 * ev[-1] and abs(hi - ev[-1]) <= 1e-12 * ev[-1]
        else:
            assert np.isnan(resid) and np.isnan(lo)
        with kernels.use_kernels("compiled"):
            got = stability.spectral_radius_and_gain(A, schur=(R, U))
        with kernels.use_kernels("reference"):
            ref = stability.spectral_radius_and_gain(A, schur=(R, U))
        assert got[0] == ref[0]
        assert (np.isfinite(got[1]), np.isfinite(ref[1])) == (True, True) or got[1] == ref[1] == np.inf
        if np.isfinite(ref[1]):
            assert abs(got[1] - ref[1]) <= 1e-9 * ref[1]
    with kernels.use_kernels("compiled"):
        assert stability.spectral_radius_and_gain(jordan, schur=complex_schur(jordan))[1] > stability.spectral_radius_and_gain(
            np.diag(np.full(12, 0.9)), schur=complex_schur(np.diag(np.full(12, 0.9))))[1]


@needs_numba
def test_compiled_schur_form_calls_dgees_as_scipy_does():
    """``complex_schur`` calls LAPACK's ``dgees`` directly with a cached workspace: the same real Schur
    form as ``scipy.linalg.schur``, bit for bit, before the compiled rotations."""
    import scipy.linalg

    from roadcollab.lti import _cert_kernel

    rng = np.random.default_rng(11)
    for n in (1, 3, 14, 22, 22):
        for close in (False, True):
            A = _system(rng, n, close)[0]
            Tr, Zr = scipy.linalg.schur(A, output="real")
            T, U = np.array(Tr, complex, order="C"), np.array(Zr, complex, order="C")    # as complex_schur
            _cert_kernel._build()["rsf2csf"](T, U)
            T1, U1 = _cert_kernel.complex_schur(A)
            assert np.array_equal(T, T1) and np.array_equal(U, U1)
    with pytest.raises(ValueError, match="finite"):
        _cert_kernel.complex_schur(np.full((2, 2), np.nan))


@needs_numba
def test_compiled_hiding_similarity_is_the_reference_one_to_round_off():
    """``random_similarity`` on the compiled path (Householder ``QR`` and products in one call) gives the
    reference's balanced ``Q^T A Q``, ``Q^T B``, ``C Q`` to round-off and leaves the generator in the same
    state."""
    from roadcollab.lti.realisation import StateSpaceData, random_similarity

    rng = np.random.default_rng(12)
    for n in (1, 2, 9, 22):
        sys = StateSpaceData(0.2 * rng.standard_normal((n, n)), rng.standard_normal((n, 2)),
                             1e3 * rng.standard_normal((2, n)), np.zeros((2, 2)), 0.005)
        out = {}
        for path in kernels.KERNELS:
            gen = np.random.default_rng(13)
            with kernels.use_kernels(path):
                out[path] = random_similarity(sys, gen)
            out[path + "_state"] = gen.bit_generator.state
        assert out["compiled_state"] == out["reference_state"]
        a, b = out["reference"], out["compiled"]
        for x, y in ((a.A, b.A), (a.B, b.B), (a.C, b.C)):
            assert np.max(np.abs(x - y)) <= 1e-13 * np.max(np.abs(x))
        assert np.array_equal(a.D, b.D)


_ONCE = """
import gc, json
from numba.core.registry import CPUDispatcher
from roadcollab.experiments.bench.study import bench_segment
for mechanism in ("paper", "paper_vehicle", "none", "hardened"):
    bench_segment(512, mechanism=mechanism, repeats=2, kernels="compiled")
ours = [d for d in gc.get_objects() if isinstance(d, CPUDispatcher) and d.py_func.__module__.startswith("roadcollab")]
print(json.dumps({"kernels": len(ours), "twice": {f"{d.py_func.__module__}.{d.py_func.__name__}": [str(s) for s in d.signatures]
                                                 for d in ours if len(d.signatures) > 1}}))
"""


@needs_numba
def test_every_kernel_is_compiled_once_for_every_mechanism():
    # A kernel fed read-only (a checked message's) and writable (a vehicle's own) arrays compiled two
    # specialisations, about 5.5 s of a fresh installation's first run (docs/speed.md, "Seventh pass").
    # In a fresh process: what the mechanisms compile, not what other tests called the kernels with.
    import json

    out = subprocess.run([sys.executable, "-c", _ONCE], capture_output=True, text=True, timeout=600, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["kernels"] >= 10
    assert got["twice"] == {}


@needs_numba
def test_a_fresh_draw_applies_psi_without_forming_its_response_with_the_same_bits():
    """``pole_residue_apply`` gives exactly the bits of ``pole_residue_eval``, ``inv2x2`` and ``matvec``; and a
    ``paper`` message from a fresh draw (applied that way) equals, bit for bit, the one obfuscated through the
    same draw's responses (a channel passed in)."""
    from roadcollab.estimation.grid import SegmentGrid
    from roadcollab.lti.batch2x2 import inv2x2, matvec
    from roadcollab.lti.realisation import StateSpaceData
    from roadcollab.lti.response import unit_circle
    from roadcollab.privacy.obfuscation import ObfuscationChannel, ObfuscationSpec, draw_obfuscator, obfuscate_spectra

    grid = SegmentGrid(sample_rate=200.0, n_samples=1000)
    rng = np.random.default_rng(5)
    E = rng.standard_normal((grid.n_bins, 2)) + 1j * rng.standard_normal((grid.n_bins, 2))
    Wf = rng.standard_normal((grid.n_bins, 2)) + 1j * rng.standard_normal((grid.n_bins, 2))
    with kernels.use_kernels("compiled"):
        psi = draw_obfuscator(ObfuscationSpec(), grid, rng=6)
        zp, res, direct = psi.pole_residues()
        z = unit_circle(grid.omega_dt)
        H = _pole_kernel.pole_residue_eval(zp, res.reshape(zp.size, 4), direct, z)
        for inverse in (False, True):
            got = _pole_kernel.pole_residue_apply(zp, res.reshape(zp.size, 4), direct, z, E, inverse=inverse)
            assert got.tobytes() == matvec(inv2x2(H) if inverse else H, E).tobytes()     # every bit, signed zeros too
        with pytest.raises(ValueError, match="2x2 D"):
            _pole_kernel.pole_residue_apply(zp, res.reshape(zp.size, 4), direct, z, E[:-1])
        A = np.diag([0.5, 0.8, -0.3, 0.9])
        T = StateSpaceData(A, rng.standard_normal((4, 2)), rng.standard_normal((2, 4)), np.eye(2), grid.dt)
        S = StateSpaceData(0.9 * A, rng.standard_normal((4, 2)), rng.standard_normal((2, 4)), np.zeros((2, 2)), grid.dt)
        fresh, _, _ = obfuscate_spectra(T, S, E, Wf, grid, rng=np.random.default_rng(11))
        ch = ObfuscationChannel.draw(T, S, grid, rng=np.random.default_rng(11))
        kept, _, _ = obfuscate_spectra(T, S, E, Wf, grid, channel=ch)
    assert np.array_equal(fresh.e, kept.e) and np.array_equal(fresh.wf, kept.wf)
    assert np.array_equal(fresh.T.A, kept.T.A) and np.array_equal(fresh.S.C, kept.S.C)


@needs_numba
def test_the_receivers_inversion_in_one_pass_agrees_with_its_steps():
    """``receiver_z`` with ``T`` on the compiled path (one pass, ``T^-1`` inline) equals the steps with the
    inverse formed first to round-off per bin; a singular bin gives inf/NaN there as in the steps, not an error."""
    from roadcollab.lti.batch2x2 import inv2x2, receiver_z

    rng = np.random.default_rng(12)
    K = 700
    c = lambda *s: rng.standard_normal(s) + 1j * rng.standard_normal(s)   # noqa: E731
    T, S, E, Wf, w = c(K, 2, 2), c(K, 2, 2), c(K, 2), c(K, 2), rng.random(K)
    T[3] = [[1.0, 2.0], [2.0, 4.0]]                  # singular
    with kernels.use_kernels("compiled"), np.errstate(all="ignore"):
        fused = receiver_z(T, S, E, Wf, w)
        steps = receiver_z(None, S, E, Wf, w, T_inv=inv2x2(T))
    ok = np.delete(np.arange(K), 3)
    err = np.abs(fused[ok] - steps[ok]).max(axis=1) / np.abs(steps[ok]).max(axis=1)
    assert err.max() <= 1e-13          # seeded: the worst of 699 random bins
    assert not np.isfinite(fused[3]).all() and not np.isfinite(steps[3]).all() and np.isfinite(np.delete(fused, 3, axis=0)).all()


@pytest.mark.skipif(not kernels.compiled_available(), reason="numba not importable")
def test_compiled_difference_norms_are_numpys_norms_to_the_last_bit():
    """``diff_norms`` (Theorem 1's check) in one compiled pass: the two ``np.linalg.norm`` calls to one unit
    in the last place (numpy's complex product may fuse a multiply-add, the kernel does not), over values
    from 1e-200 to 1e150 (squares near under- and overflow) and an exact match (zero difference)."""
    from roadcollab.lti.batch2x2 import diff_norms

    rng = np.random.default_rng(13)
    K = 5000
    scale = 10.0 ** rng.uniform(-200, 150, (K, 2))
    x = (rng.standard_normal((K, 2)) + 1j * rng.standard_normal((K, 2))) * scale
    ref = x * (1 + 1e-12 * rng.standard_normal((K, 2)))
    ref[7] = x[7]
    with kernels.use_kernels("reference"):
        want = diff_norms(x, ref)
    with kernels.use_kernels("compiled"):
        got = diff_norms(x, ref)
    np.testing.assert_array_equal(want[0], np.linalg.norm(x - ref, axis=1))
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=2.3e-16, atol=0)
    assert got[0][7] == 0.0


_HEAVY = """
import sys
from roadcollab.cli.main import main
main(["reproduce", "--runs", "2", "--measured-runs", "1", "--out", sys.argv[1]])
print(sorted(m for m in ("scipy.signal", "scipy.stats", "scipy.interpolate", "scipy.optimize") if m in sys.modules))
"""


@needs_numba
def test_a_compiled_reproduction_imports_no_heavy_scipy_package(tmp_path):
    # scipy.signal (with scipy.stats) cost every process of a reproduce 0.3-0.45 s on its first run, and
    # scipy.interpolate (with scipy.optimize) 0.1-0.13 s at start-up (docs/speed.md, "Fourteenth pass").
    out = subprocess.run([sys.executable, "-c", _HEAVY, str(tmp_path / "out")], capture_output=True, text=True,
                         timeout=600, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"


_OPT_PROBE = """
import json, os
os.environ.pop("NUMBA_OPT", None) if {unset} else os.environ.__setitem__("NUMBA_OPT", "2")
import numba
from numba.core import config, event
from roadcollab.lti import kernels
kernels.compiled_available()                       # imports numba, installs the package's listener
seen = {{}}

class Record(event.Listener):                      # registered after it: sees the level in force
    def on_start(self, ev):
        seen.setdefault(ev.data["dispatcher"].py_func.__name__, int(config.OPT))
    def on_end(self, ev):
        pass

event.register("numba:compile", Record())

def callee(x):
    return x + 1.0

ns = {{"__name__": "roadcollab.probe", "callee": numba.njit(callee)}}
exec("def ours(x):\\n    return callee(x) * 2.0", ns)
ours = numba.njit(ns["ours"])

def theirs(x):
    return x * 3.0

theirs = numba.njit(theirs)
nameless = {{}}                                    # a function made by exec without __name__: no __module__
exec("def anon(x):\\n    return x - 1.0", nameless)
assert ours(1.0) == 4.0 and theirs(1.0) == 3.0 and numba.njit(nameless["anon"])(1.0) == 0.0
try:
    numba.njit(lambda x: x.nope)(1.0)            # a failing compile of someone else's leaves the level alone
except Exception:
    pass
bad = {{"__name__": "roadcollab.probe"}}
exec("def broken(x):\\n    return x.nope", bad)
try:
    numba.njit(bad["broken"])(1.0)               # nor does a failing compile of the package's
except Exception:
    pass
print(json.dumps({{"seen": seen, "after": int(config.OPT)}}))
"""


@_numba
@pytest.mark.parametrize("unset", [True, False])
def test_the_package_kernels_compile_at_their_own_llvm_level_and_nothing_else_does(unset):
    """The package's functions (and what compiles inside them) compile at KERNEL_OPT_LEVEL, anyone else's at
    numba's level, which is restored after every compile, failed ones too; a user's NUMBA_OPT is kept."""
    import json

    out = subprocess.run([sys.executable, "-c", _OPT_PROBE.format(unset=unset)], capture_output=True, text=True,
                         timeout=300, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    default = 3 if unset else 2
    ours = kernels.KERNEL_OPT_LEVEL if unset else 2
    assert got["seen"]["ours"] == ours and got["seen"]["callee"] == ours          # callee: compiled inside ours
    assert got["seen"]["theirs"] == default and got["seen"]["<lambda>"] == default and got["seen"]["anon"] == default
    assert got["seen"]["broken"] == ours
    assert got["after"] == default


@_numba
def test_the_certificate_eigenvalues_are_the_bits_of_eigvalsh():
    """The certificate kernel's extreme eigenvalues (its own call of LAPACK dsyevd through numba's helper) are
    the bits numba's np.linalg.eigvalsh gives, for symmetric and slightly asymmetric X (the triangle read and
    the Fortran order matter then), n = 1..22; a non-finite entry raises as eigvalsh does."""
    import numba

    from roadcollab.lti import _cert_kernel, _evd_kernel

    _cert_kernel._build()
    ends = _evd_kernel._build()["ends"]
    assert _cert_kernel._eigvalsh_ends is ends                 # what the certificate's figures call

    @numba.njit
    def both(X):
        lo, hi = ends(X)
        ev = np.linalg.eigvalsh(X)
        return lo, hi, ev[0], ev[-1]

    rng = np.random.default_rng(20261206)
    for n in range(1, 23):
        for k in range(8):
            M = rng.standard_normal((n, n))
            X = M @ M.T + 0.1 * np.eye(n)
            if k % 2:
                X = X + 1e-9 * rng.standard_normal((n, n))
            lo, hi, elo, ehi = both(X)
            assert (lo, hi) == (elo, ehi), (n, k)
            assert lo == np.linalg.eigvalsh(X)[0] or abs(lo - np.linalg.eigvalsh(X)[0]) < 1e-9 * abs(hi)
    with pytest.raises(np.linalg.LinAlgError, match="infs or NaNs"):
        both(np.array([[1.0, np.inf], [0.0, 1.0]]))
