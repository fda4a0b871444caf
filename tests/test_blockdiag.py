"""The block-diagonalised Schur evaluation against dense solves, and the caches keyed by content."""

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from roadcollab.experiments.bench.naive import direct_response
from roadcollab.lti.blockdiag import block_response, block_schur
from roadcollab.lti.kernels import compiled_available, use_kernels
from roadcollab.lti.realisation import StateSpaceData, SystemCache, random_orthogonal, series, similarity
from roadcollab.lti.response import FrequencyResponseCache, received_response
from roadcollab.lti.stability import spectral_radius_and_gain

#: The compiled path is slow on a fresh install (it compiles the kernels): .ci/run's slow pass runs it.
COMPILED = pytest.param("compiled", marks=pytest.mark.slow)


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def _hidden(A, B, C, D, rng):
    Q = random_orthogonal(A.shape[0], rng)
    return StateSpaceData(Q.T @ A @ Q, Q.T @ B, C @ Q, D, 0.005)


@pytest.mark.parametrize("path", [COMPILED, "reference"])
@pytest.mark.parametrize("case", ["distinct", "doubled", "jordan", "series"])
def test_block_response_agrees_with_dense_solves(case, path):
    rng = np.random.default_rng(7)
    om = np.linspace(1e-3, np.pi - 1e-3, 400)
    if case == "distinct":
        lam = rng.uniform(0.2, 0.95, 6)
        A = np.diag(lam)
    elif case == "doubled":     # exactly repeated eigenvalues (the obfuscators' modal form)
        A = np.kron(np.diag([0.9, 0.5, -0.3]), np.eye(2))
    elif case == "jordan":      # defective: one block of 3, decoupling impossible inside it
        A = scipy.linalg.block_diag(0.97 * np.eye(3) + np.diag([1.0, 1.0], 1), np.diag([0.2, -0.5]))
    else:                       # a system in series with itself: its poles twice
        base = _hidden(np.diag([0.98, 0.9, 0.6]) + np.diag([0.3, 0.1], 1), rng.standard_normal((3, 2)),
                       rng.standard_normal((2, 3)), np.eye(2), rng)
        s = series(base, base)
        A = s.A
    n = A.shape[0]
    sys = _hidden(A, rng.standard_normal((n, 2)), rng.standard_normal((2, n)), rng.standard_normal((2, 2)), rng)
    with use_kernels(path):
        bs = block_schur(sys.A, sys.B, sys.C)
        got = block_response(bs, sys.D, np.exp(1j * om))
    assert _rel(got, direct_response(sys, om)) < 1e-11
    assert sum(b - a for a, b in bs.blocks) == n
    if case == "jordan":
        assert max(b - a for a, b in bs.blocks) >= 3


@pytest.mark.parametrize("path", [COMPILED, "reference"])
def test_merged_clusters_still_exact(path):
    """A tight coupling bound forces merges (down to one block): the result is the Schur back
    substitution, equally exact."""
    rng = np.random.default_rng(3)
    sys = similarity(_hidden(np.diag([0.99, 0.985, 0.7, 0.3]) + np.diag([0.5, 0.2, 0.1], 1),
                             rng.standard_normal((4, 2)), rng.standard_normal((2, 4)), np.eye(2), rng),
                     np.eye(4), balance=True)
    om = np.linspace(1e-3, 3.0, 300)
    with use_kernels(path):
        bs = block_schur(sys.A, sys.B, sys.C, max_coupling=1e-6)
    assert bs.blocks == [(0, 4)]
    assert _rel(block_response(bs, sys.D, np.exp(1j * om)), direct_response(sys, om)) < 1e-11


@pytest.mark.slow  # the compiled path: it compiles the kernels on a fresh install (14 s in CI)
@pytest.mark.skipif(not compiled_available(), reason="numba not importable")
def test_compiled_block_diagonalisation_equals_the_lapack_pass():
    """The compiled pass (reordering, Sylvester splits, Bw, Cw) gives the LAPACK path's blocks and, per
    block, the same eigenvalues; the responses agree to round-off (obfuscated T~, S~ of the bench's
    vehicles and bench segment 133's S~, which needs the merges)."""
    from roadcollab.experiments.bench.study import _config_for
    from roadcollab.experiments.pipeline import FleetPipeline
    from roadcollab.models.vehicle import sample_fleet
    from roadcollab.privacy.obfuscation import ObfuscationChannel

    cfg = _config_for(4000)
    rng = np.random.default_rng(5)
    pipe = FleetPipeline(cfg, sample_fleet(2, cfg.fleet, rng=rng))
    est = pipe.estimators[1]
    d = np.load(Path(__file__).parent / "data" / "bench_segment133_S.npz")
    systems = [StateSpaceData(d["A"], d["B"], d["C"], d["D"], 0.005)]
    for _ in range(4):
        ch = ObfuscationChannel.draw(est.T_ss, est.S_ss, pipe.grid, cfg.obfuscation, rng=rng)
        systems += [ch.T, ch.S]
    z = np.exp(1j * np.linspace(1e-3, 3.0, 500))
    for sys in systems:
        schur = scipy.linalg.schur(sys.A, output="complex")
        with use_kernels("reference"):
            ref = block_schur(sys.A, sys.B, sys.C, schur=schur)
            H_ref = block_response(ref, sys.D, z)
        with use_kernels("compiled"):
            got = block_schur(sys.A, sys.B, sys.C, schur=schur)
            H_got = block_response(got, sys.D, z)
        assert got.blocks == ref.blocks
        assert np.allclose(np.diag(got.R), np.diag(ref.R), rtol=0, atol=1e-12)
        assert np.all(np.tril(got.R, -1) == 0)
        for a, b in got.blocks:                 # nothing couples one block to the next
            assert np.all(got.R[a:b, b:] == 0)
        assert _rel(H_got, H_ref) < 1e-12


@pytest.mark.slow  # the compiled path: it compiles the kernels on a fresh install
@pytest.mark.skipif(not compiled_available(), reason="numba not importable")
@pytest.mark.parametrize("max_coupling", [1e2, 1.0, 0.05])
def test_the_compiled_loop_is_the_python_loop_over_compiled_passes(max_coupling):
    """block_schur on the compiled path is one call (clusters, passes, merges: _blockdiag_kernel.block_form);
    it gives exactly what the Python loop over the compiled clusters and passes gives (the route it
    replaced), bit for bit, with the merges that tighter coupling bounds force (bench segment 133's S~
    and obfuscated T~, S~)."""
    from roadcollab.experiments.bench.study import _config_for
    from roadcollab.experiments.pipeline import FleetPipeline
    from roadcollab.lti import blockdiag
    from roadcollab.models.vehicle import sample_fleet
    from roadcollab.privacy.obfuscation import ObfuscationChannel

    cfg = _config_for(4000)
    rng = np.random.default_rng(11)
    pipe = FleetPipeline(cfg, sample_fleet(2, cfg.fleet, rng=rng))
    est = pipe.estimators[1]
    d = np.load(Path(__file__).parent / "data" / "bench_segment133_S.npz")
    systems = [StateSpaceData(d["A"], d["B"], d["C"], d["D"], 0.005)]
    for _ in range(3):
        ch = ObfuscationChannel.draw(est.T_ss, est.S_ss, pipe.grid, cfg.obfuscation, rng=rng)
        systems += [ch.T, ch.S]
    merges = 0
    with use_kernels("compiled"):
        for sys in systems:
            T0, U0 = scipy.linalg.schur(sys.A, output="complex")
            got = block_schur(sys.A, sys.B, sys.C, schur=(T0, U0), max_coupling=max_coupling)
            lam = np.diag(T0)
            clusters = blockdiag._compiled_clusters(lam, blockdiag.CLUSTER_TOL, blockdiag.CLUSTER_REL)
            first = len(clusters)
            while True:                         # the loop of block_schur before it was compiled
                ref = blockdiag._decouple(T0, U0, sys.B, sys.C, clusters, max_coupling)
                if isinstance(ref, blockdiag.BlockSchur):
                    break
                rest = clusters[ref + 1:]
                dist = [np.min(np.abs(lam[clusters[ref]][:, None] - lam[c][None, :])) for c in rest]
                near = rest[int(np.argmin(dist))]
                clusters = [sorted(c + near) if k == ref else c for k, c in enumerate(clusters) if c is not near]
            merges += first - len(ref.blocks)
            assert got.blocks == ref.blocks
            for a, b in ((got.R, ref.R), (got.Bw, ref.Bw), (got.Cw, ref.Cw)):
                assert a.tobytes() == b.tobytes()
    assert merges > 0


def test_schur_certificate_agrees_with_the_eigen_one():
    rng = np.random.default_rng(5)
    A = _hidden(np.diag([0.99, 0.9, 0.5, -0.4]) + np.diag([2.0, 0.0, 1.0], 1), np.zeros((4, 2)),
                np.zeros((2, 4)), np.eye(2), rng).A
    r0, g0 = spectral_radius_and_gain(A)
    r1, g1 = spectral_radius_and_gain(A, schur=scipy.linalg.schur(A, output="complex"))
    assert abs(r0 - r1) < 1e-12 and abs(g0 - g1) < 1e-6 * g0
    jordan = 0.99 * np.eye(64) + np.diag(np.ones(63), 1)
    jordan[-1, 0] = 1e-16        # computed radius 0.99, true radius 1.55: no certificate
    assert spectral_radius_and_gain(jordan, schur=scipy.linalg.schur(jordan, output="complex"))[1] == np.inf


def test_caches_hit_only_on_identical_bytes():
    rng = np.random.default_rng(1)
    A = np.diag([0.9, 0.5])
    B, C, D = rng.standard_normal((2, 2)), rng.standard_normal((2, 2)), np.eye(2)
    systems = SystemCache()
    first = systems.get(A, B, C, D, 0.01)
    assert systems.get(A.copy(), B.copy(), C.copy(), D.copy(), 0.01) is first
    A2 = A.copy()
    A2[0, 0] = np.nextafter(0.9, 1.0)          # one ulp: a different system
    assert systems.get(A2, B, C, D, 0.01) is not first
    assert systems.get(A, B, C, D, 0.02) is not first
    cache = FrequencyResponseCache()
    om = np.linspace(0.1, 1.0, 5)
    H = cache.response(first, om)
    assert not cache._store                     # seen once: only its hash is remembered
    H2 = cache.response(StateSpaceData(A.copy(), B, C, D, 0.01), om)
    assert H2 is not H and np.array_equal(H2, H)  # seen twice: kept
    assert cache.response(StateSpaceData(A.copy(), B, C, D, 0.01), om) is H2
    H = H2
    assert not np.array_equal(cache.response(StateSpaceData(A2, B, C, D, 0.01), om), H)
    assert np.allclose(cache.response(first, om, inverse=True) @ H, np.eye(2))
    # A decoded (received) system keeps no response memo of its own (its receiver's cache does);
    # one built in memory does, and both give the same response.
    local = StateSpaceData(A.copy(), B, C, D, 0.01)
    assert np.array_equal(first.frequency_response(om), local.frequency_response(om))
    assert "_response" not in first.__dict__ and "_response" in local.__dict__
    assert np.array_equal(local.frequency_response(om), first.frequency_response(om))


def test_decode_reuses_a_certified_system_only_for_the_same_bytes():
    from roadcollab.errors import MessageError
    from roadcollab.wire import protocol
    from roadcollab.wire.examples import example_message

    data = protocol.encode(example_message("none", rng=0))
    systems = SystemCache()
    first = protocol.decode(data, systems=systems)
    again = protocol.decode(data, systems=systems)
    assert again.T is first.T and again.S is first.S
    assert first.T.__dict__.get("_stability") is not None       # certified once, memo kept
    # An unstable T with the same shape is not served from the cache: it is refused.
    T = first.T
    bad = bytearray(data)
    A = np.array(T.A, copy=True)
    A[0, 0] += 5.0
    off = protocol.EXCHANGE_HEADER_NBYTES
    bad[off:off + A.nbytes] = A.astype("<f8").tobytes()
    with pytest.raises(MessageError, match="stable"):
        protocol.decode(bytes(bad), systems=systems)


def test_unit_circle_is_exp_j_omega_and_kept_only_for_an_equal_vector():
    from roadcollab.lti.response import unit_circle

    om = np.linspace(0.0, np.pi, 3001)
    z = unit_circle(om)
    np.testing.assert_array_equal(z, np.exp(1j * om))
    assert unit_circle(om.copy()) is z                     # an equal vector: the kept one
    shifted = om.copy()
    shifted[1000] = np.nextafter(shifted[1000], 4.0)       # one element one ulp away: computed anew
    z2 = unit_circle(shifted)
    assert z2 is not z and z2[1000] == np.exp(1j * shifted[1000])
    np.testing.assert_array_equal(unit_circle(om[:10]), np.exp(1j * om[:10]))
    with pytest.raises(ValueError):
        z[0] = 0.0                                          # read-only: callers cannot spoil it


@pytest.mark.parametrize("path", [COMPILED, "reference"])
def test_close_eigenvalues_near_the_circle_stay_in_one_block(path):
    """Bench segment 133's ``S~`` (vehicle 2, order 18; the 300-segment exactness stream): real eigenvalues
    0.9776, 0.9812, 0.9828 (each twice), 1.6e-3..5e-3 apart at 0.02 from the unit circle. Split into
    three blocks their contributions cancelled (1e7 each where |H| = 10) and the response was 1.5e-9
    (compiled) / 9.4e-10 (numpy) off a dense solve; clustered by their distance to the circle, one block."""
    from roadcollab.lti import kernels

    d = np.load(Path(__file__).parent / "data" / "bench_segment133_S.npz")
    sys = StateSpaceData(d["A"], d["B"], d["C"], d["D"], 0.005)
    om = np.pi * np.arange(1, 3001) / 3000 * 0.9
    bs = block_schur(sys.A, sys.B, sys.C)
    lam = np.diag(bs.R)
    (i0, i1), = [b for b in bs.blocks if np.any(np.abs(lam[b[0]:b[1]] - 0.9812) < 1e-3)]
    assert i1 - i0 == 8 and np.all(np.abs(lam[i0:i1].real - 0.980) < 0.003)
    with kernels.use_kernels(path):
        got = block_response(bs, sys.D, np.exp(1j * om))
    ref = direct_response(sys, om)
    per_bin = np.linalg.norm(got - ref, axis=(1, 2)) / np.linalg.norm(ref, axis=(1, 2))
    assert per_bin.max() < 4e-10


@pytest.mark.skipif(not compiled_available(), reason="numba not importable")
def test_compiled_clusters_equal_the_label_propagation():
    """The compiled clustering gives the numpy label propagation's clusters: chains of close eigenvalues
    (single linkage), eigenvalues close only relative to their distance to the circle, isolated ones."""
    from roadcollab.lti._blockdiag_kernel import clusters
    from roadcollab.lti.blockdiag import CLUSTER_REL, CLUSTER_TOL, _clusters

    rng = np.random.default_rng(11)
    cases = [np.array([0.5, 0.5005, 0.501, 0.9, -0.3 + 0.1j, 0.9008, 0.2]),
             np.array([0.9776, 0.9812, 0.9828, 0.9776, 0.9812, 0.9828, 0.5 + 0.5j]),
             np.array([0.3])]
    cases += [rng.uniform(0.9, 0.999, 12) * np.exp(1j * rng.choice([0.0, 0.01, 0.5], 12)) for _ in range(20)]
    for lam in cases:
        lam = lam.astype(complex)
        assert clusters(lam, CLUSTER_TOL, CLUSTER_REL) == _clusters(lam, CLUSTER_TOL, CLUSTER_REL)
    assert len(clusters(cases[0], CLUSTER_TOL, CLUSTER_REL)) == 4


def test_unit_circle_finds_a_frozen_array_by_identity_only_while_it_stays_frozen():
    from roadcollab.lti.response import unit_circle

    om = np.linspace(0.0, np.pi, 2999)
    om.setflags(write=False)
    z = unit_circle(om)
    np.testing.assert_array_equal(z, np.exp(1j * om))
    assert unit_circle(om) is z
    om.setflags(write=True)         # its owner made it writable and changed it: no identity shortcut
    om[5] = 1.0
    z2 = unit_circle(om)
    assert z2[5] == np.exp(1j * 1.0) and z2 is not z


def test_the_response_cache_keys_the_frequencies_by_content_not_by_the_array_object():
    rng = np.random.default_rng(4)
    A = np.diag(rng.uniform(0.1, 0.9, 4))
    sys = StateSpaceData(A, rng.standard_normal((4, 2)), rng.standard_normal((2, 4)), np.zeros((2, 2)), 0.005)
    cache = FrequencyResponseCache()
    om = np.linspace(0.01, 3.0, 50)
    om.setflags(write=False)
    for _ in range(3):                              # seen twice, then kept: the third call is a hit
        first = cache.response(sys, om)
    assert cache.response(sys, om) is first
    assert cache.response(sys, om.copy()) is first       # an equal vector: the same key
    other = np.array(om)
    other[7] += 1e-3
    np.testing.assert_array_equal(cache.response(sys, other), received_response(sys, other))
    om2 = np.array(om)                              # a writable vector changed in place after use
    cache.response(sys, om2)
    om2[3] += 0.5
    np.testing.assert_array_equal(cache.response(sys, om2), received_response(sys, om2))


@pytest.mark.skipif(not compiled_available(), reason="numba not importable")
@pytest.mark.slow
def test_the_unrolled_four_state_blocks_give_the_general_back_substitution_bit_for_bit():
    """Two outputs take the unrolled path for a block of four; a third (zero) output row sends the same
    system through the general one, whose first two outputs must then be the same bits."""
    from roadcollab.lti._eval_kernel import block_eval

    rng = np.random.default_rng(11)
    n = 10
    lam = np.concatenate([0.9 * np.exp(1j * rng.uniform(0, np.pi, 4)), rng.uniform(-0.9, 0.9, 6)])
    R = np.triu(rng.standard_normal((n, n)) + 1j * rng.standard_normal((n, n)), 1) * 0.3 + np.diag(lam)
    Bw = rng.standard_normal((n, 2)) + 1j * rng.standard_normal((n, 2))
    Cw = rng.standard_normal((2, n)) + 1j * rng.standard_normal((2, n))
    D = rng.standard_normal((2, 2))
    blocks = [(0, 4), (4, 6), (6, 10)]
    z = np.exp(1j * np.linspace(0.01, 3.1, 777))                # not a multiple of the tile
    fast = block_eval(R, Bw, Cw, D, blocks, z)
    general = block_eval(R, Bw, np.vstack([Cw, np.zeros((1, n))]), np.vstack([D, np.zeros((1, 2))]), blocks, z)
    np.testing.assert_array_equal(fast, general[:, :2, :])
    dense = np.array([Cw @ np.linalg.solve(zk * np.eye(n) - np.triu(R) * _mask(blocks, n), Bw) + D for zk in z])
    assert _rel(fast, dense) < 1e-12


def _mask(blocks, n):
    """1 inside the diagonal blocks, 0 between them (block_eval reads only the blocks)."""
    M = np.zeros((n, n))
    for i0, i1 in blocks:
        M[i0:i1, i0:i1] = 1.0
    return M
