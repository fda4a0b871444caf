"""Receivers that cannot be poisoned (issue 9, section 1): the stability certificate, the
receiver guard and the hostile-but-well-formed messages."""

import dataclasses

import numpy as np
import pytest

import roadcollab as rc
from roadcollab.collaboration.guard import GuardReport, ReceiverGuard, fleet_guards, third_octave_bands
from roadcollab.collaboration.relay import Exchange, Relay
from roadcollab.errors import MessageError, ParameterError
from roadcollab.experiments.pipeline import PipelineCache, record_run
from roadcollab.experiments.security.poisoning import CONSTRUCTIONS, PoisoningRow, _jordan_trap, poisoning_rows
from roadcollab.experiments.seeds import SeedPlan, run_stream
from roadcollab.lti.realisation import StateSpaceData
from roadcollab.reporting.records import row_columns
from roadcollab.wire.message import ExchangeMessage
from roadcollab.wire.protocol import decode, encode

SMALL = rc.ExperimentConfig(n_vehicles=3, n_runs=1, segment_length=120.0)
DT = 1 / 200.0


def _exchange_with_T(T):
    z = np.zeros((600, 2))
    S = StateSpaceData(np.array([[0.5]]), np.ones((1, 2)), np.ones((2, 1)), np.eye(2), DT)
    return ExchangeMessage("none", 200.0, 400, T, S, z, z)


def test_jordan_trap_fools_eigvals_but_is_refused():
    T = _jordan_trap(DT)
    assert np.max(np.abs(np.linalg.eigvals(T.A))) < 0.999     # the computed radius is fooled
    with pytest.raises(MessageError, match="T must be discrete-time stable with a Lyapunov certificate"):
        _exchange_with_T(T)


@pytest.mark.parametrize("A", [
    0.9 * np.eye(64) + np.diag(np.ones(63), 1),                  # Jordan block: ||A^k|| ~ 1e70 transient
    np.array([[0.0, 1e200], [0.0, 0.0]]),                        # nilpotent, a 1e200 entry
    np.array([[0.5, 1e9], [0.0, 0.5]]),                          # stable but a 1e9-fold transient
])
def test_non_normal_traps_refused(A):
    n = A.shape[0]
    T = StateSpaceData(A, np.ones((n, 2)), np.ones((2, n)), np.eye(2), DT)
    assert np.max(np.abs(np.linalg.eigvals(A))) < 1.0
    with pytest.raises(MessageError, match="T must be discrete-time stable"):
        _exchange_with_T(T)


def test_radius_margin():
    A = np.array([[1.0 - 1e-7]])
    with pytest.raises(MessageError, match=r"spectral radius of A < 1 - 1e-06"):
        _exchange_with_T(StateSpaceData(A, np.ones((1, 2)), np.ones((2, 1)), np.eye(2), DT))


@pytest.fixture(scope="module")
def default_fleet_run():
    cfg = rc.ExperimentConfig(n_runs=1, segment_length=120.0)      # the default fleet (10 vehicles, seed 0)
    pipe = PipelineCache().pipeline(cfg, 0)
    ss = SeedPlan(0).runs(1)[0]
    _, ys, Ys = record_run(pipe, run_stream(ss, "road"), run_stream(ss, "noise"), cfg.sensor_noise_std)
    return cfg, pipe, ys, Ys


@pytest.mark.parametrize("mechanism", ["none", "paper", "paper_vehicle", "hardened"])
def test_every_honest_message_of_the_default_fleet_decodes_and_passes_the_guard(default_fleet_run, mechanism):
    cfg, pipe, ys, Ys = default_fleet_run
    # The accept/refuse guard without the bounded combination (bounded=False): accepted means exactly Algorithm 1.
    guards = fleet_guards(pipe.estimators, pipe.road_moment, cfg.sensor_noise_std, bounded=False)
    steps = Relay(pipe.estimators, Exchange(mechanism, cfg.obfuscation), rng=3, guard=guards).run(ys, spectra=Ys)
    plain = Relay(pipe.estimators, Exchange(mechanism, cfg.obfuscation), rng=3, unguarded=True).run(ys, spectra=Ys)
    assert steps[0].guard is None and all(s.guard is None for s in plain)
    for s in steps:
        assert decode(encode(s.message)).mechanism == s.message.mechanism
    refused = [s.guard for s in steps[1:] if s.guard.refused]
    assert not refused, refused[0].reasons
    for s, p in zip(steps, plain):     # accepted: exactly Algorithm 1
        np.testing.assert_array_equal(s.result.W_hat, p.result.W_hat)


@pytest.fixture(scope="module")
def poisoning():
    return poisoning_rows(SMALL, seed=1, n_runs=1, receiver=1)


def _row(result, mech, name):
    (row,) = [r for r in result.rows if r.mechanism == mech and r.construction == name]
    return row


@pytest.mark.parametrize("mech,name", [(m, c) for m, cs in CONSTRUCTIONS.items() for c in cs])
def test_hostile_message_cannot_poison_the_receiver(poisoning, mech, name):
    row = _row(poisoning, mech, name)
    assert row.finite
    assert row.next_message_encodes
    assert row.ratio <= 2.0, (row.ratio, row.outcome, row.reason)


def test_outcomes(poisoning):
    assert _row(poisoning, "none", "jordan_trap").outcome == "decode_refused"
    for mech in CONSTRUCTIONS:
        assert _row(poisoning, mech, "honest").outcome == "accepted"
        for name in ("scale_z_1e3", "extreme"):
            assert _row(poisoning, mech, name).outcome == "guard_refused"
            # without the guard the same message ruins the estimate (or makes it NaN)
            assert not _row(poisoning, mech, name).ratio_unguarded <= 100
    assert all(type(r) is PoisoningRow for r in poisoning.to_rows())
    assert row_columns(PoisoningRow)[:4] == ["mechanism", "construction", "run", "outcome"]


def test_guard_report_and_relay_validation(default_fleet_run):
    cfg, pipe, ys, Ys = default_fleet_run
    g = ReceiverGuard(pipe.estimators[1], pipe.road_moment, cfg.sensor_noise_std)
    with pytest.raises(ParameterError, match="guard must hold one ReceiverGuard"):
        Relay(pipe.estimators, "none", guard=[g])
    with pytest.raises(ParameterError, match="road_moment must be a finite"):
        ReceiverGuard(pipe.estimators[1], pipe.road_moment[:5], cfg.sensor_noise_std)
    z, rep = g.check("not a message", Ys[1])
    assert isinstance(rep, GuardReport) and rep.whole_message_refused and not np.any(z)


def test_third_octave_bands_partition():
    f = np.arange(1, 2001) * 0.05
    bands = third_octave_bands(f, min_bins=16)
    assert np.array_equal(np.concatenate(bands), np.arange(f.size))
    assert min(len(b) for b in bands) >= 16
    with pytest.raises(ParameterError, match="freqs"):
        third_octave_bands(np.array([1.0, 0.5]))


@pytest.mark.parametrize("mechanism", ["fused", "fused_posterior"])
def test_guarded_fused_chain(default_fleet_run, mechanism):
    """An honest average passes unchanged; a forged one (x 1e3) is refused and the chain restarts
    from the receiver's own inversion (count 1), finite, and its message encodes."""
    cfg, pipe, ys, Ys = default_fleet_run
    guards = fleet_guards(pipe.estimators, pipe.road_moment, cfg.sensor_noise_std)
    relay = Relay(pipe.estimators, mechanism, guard=guards)
    plain = Relay(pipe.estimators, mechanism).run(ys, spectra=Ys)
    steps = relay.run(ys, spectra=Ys)
    for s, p in zip(steps[1:], plain[1:]):
        if not s.guard.refused:
            np.testing.assert_array_equal(s.message.z, p.message.z)
    assert sum(s.guard.refused for s in steps[1:]) <= 1
    forged = dataclasses.replace(plain[3].message, z=1e3 * plain[3].message.z)
    out = relay.step(4, ys[4], forged, Y=Ys[4])
    assert out.guard.whole_message_refused and out.message.count == 1
    own = pipe.estimators[4].invert(Ys[4], posterior=mechanism == "fused_posterior")
    np.testing.assert_allclose(out.message.z, pipe.grid.irfft(own), atol=1e-15)
    assert decode(encode(out.message)).count == 1
