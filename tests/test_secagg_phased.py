"""Phased sessions with an l2-norm validity proof (issue 20, section 2: bounded influence)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from roadcollab.errors import ParameterError
from roadcollab.experiments.security.secagg_bounded import centred_clipping
from roadcollab.privacy.secagg_active_run import SecAggFleet
from roadcollab.privacy.secagg_flp import Field, Proof, ValidityEncoding, decide, prove, query
from roadcollab.privacy.secagg_messages import SecAggSpec, session_id
from roadcollab.privacy.secagg_phased import phase_session, public_schedule, radius_schedule, run_phased_session
from roadcollab.privacy.secagg_validity import submit

KEY = bytes(range(32))
SESSION = session_id(5, 0)
TINY = Field(97, 5)
L = 12


def _setup(n=5, R=0.6):
    fleet = SecAggFleet(n, SecAggSpec(min_inputs=3, threshold=3))
    wide = ValidityEncoding(np.full(L, 4.0), 2.0 ** -12)
    tight = ValidityEncoding(np.full(L, R), 2.0 ** -12, norm=R)
    gen = np.random.default_rng(0)
    road = gen.normal(0, 1.0, L)
    inputs = {i: road + gen.normal(0, 0.08, L) for i in range(1, n + 1)}
    return fleet, wide, tight, inputs


def test_honest_phased_session_is_the_mean_within_quantisation():
    fleet, wide, tight, inputs = _setup()
    out = run_phased_session(fleet, inputs, SESSION, wide, tight, phases=3, verify_key=KEY, rng=0)
    assert out.refused == {} and out.accepted == (1, 2, 3, 4, 5) and out.phases == 3 and out.clipped == 0
    assert np.max(np.abs(out.result - np.mean(list(inputs.values()), axis=0))) < 3 * 2.0 ** -12


def test_a_deviation_outside_the_norm_is_refused_and_named():
    fleet, wide, tight, inputs = _setup()
    q = np.full(L, 2 ** int(tight.bits[0]) - 1)            # every coordinate at +R: inside the box, norm R sqrt(L)

    def cheat(phase, i, sub):
        if phase == 2 and i == 3:
            return submit(tight, None, phase_session(SESSION, 2), 3, np.random.default_rng(1),
                          x=tight.encode_raw(q), identity=fleet.vehicles[3].identity)
        return sub
    out = run_phased_session(fleet, inputs, SESSION, wide, tight, phases=3, verify_key=KEY, rng=0, tamper=cheat)
    assert out.result is None and out.phases == 1
    assert "vehicle 3" in out.refused[3] and "circuit output" in out.refused[3]
    assert set(out.refused) == {3}
    with pytest.raises(ParameterError, match="norm"):
        tight.encode(np.full(L, tight.norm))


def test_a_later_phase_over_another_set_gets_nothing_and_a_second_session_neither():
    fleet, wide, tight, inputs = _setup()
    out = run_phased_session(fleet, inputs, SESSION, wide, tight, phases=3, verify_key=KEY, rng=0,
                             announce=lambda k, acc: acc[:-1])            # phase 2 without vehicle 5
    assert out.result is None and out.phases == 1
    assert "another survivor set" in out.refused[1] and "another survivor set" in out.refused[4]
    again = run_phased_session(fleet, inputs, SESSION, wide, tight, phases=3, verify_key=KEY, rng=1)
    assert again.result is None and "already contributed" in again.refused[2]


def test_one_vehicle_moves_the_phased_result_by_about_r_over_n_minus_1():
    fleet, wide, tight, inputs = _setup(n=5)
    honest = np.mean(list(inputs.values()), axis=0)
    lie = dict(inputs)
    lie[5] = inputs[5] + 50.0                               # clipped into the wide box in phase 1, then its d
    out = run_phased_session(fleet, lie, session_id(6, 0), wide, tight, phases=10, verify_key=KEY, rng=0)
    shift = float(np.linalg.norm(out.result - honest))
    one_phase = float(np.linalg.norm(np.mean([wide.clip(u)[0] for u in lie.values()], axis=0) - honest))
    # fixed point: m - mean u = (d_5 + mean u - u_5) / (n - 1), ||d_5|| <= R
    bound = (tight.norm + float(np.linalg.norm(honest - inputs[5]))) / 4
    assert shift <= 1.02 * bound and one_phase > 5 * shift


def _norm_cheat_rate(enc, q, attempts=400, seed=0):
    """How often a fixed input is accepted with the honest proof of it, over random joint and query randomness."""
    P, p = enc.domain, enc.field.p
    gen = np.random.default_rng(seed)
    x = enc.encode_raw(q)
    wins = 0
    for _ in range(attempts):
        rho = np.array([int(v) for v in gen.integers(0, p, enc.n_rho)], dtype=object)
        r = next(int(t) for t in gen.integers(0, p, 64) if pow(int(t), P, p) != 1)
        s = np.array([int(v) for v in gen.integers(0, p, enc.length)], dtype=object)
        pi = prove(enc, x, rho, np.array([int(v) for v in gen.integers(0, p, 2 * enc.chunk)], dtype=object))
        x_b = np.array([int(v) for v in gen.integers(0, p, x.size)], dtype=object)
        pi_b = np.array([int(v) for v in gen.integers(0, p, pi.elements.size)], dtype=object)
        va = query(enc, (x - x_b) % p, Proof((pi.elements - pi_b) % p), rho, r, s, True)
        vb = query(enc, x_b, Proof(pi_b), rho, r, s, False)
        wins += decide(enc, (va + vb) % p) == ""
    return wins / attempts


def test_norm_soundness_on_a_small_field():
    enc = ValidityEncoding(np.array([1.0, 1.0]), 2 / 3, field=TINY, norm=0.5)     # 2 bits, N = 2, 2 slack bits
    assert enc.norm_q == 2 and enc.slack_bits == 2
    assert _norm_cheat_rate(enc, [1, 2]) == 1.0                # d = (-1, 1): sum d^2 = 2 <= N, accepted
    rate = _norm_cheat_rate(enc, [3, 3])                       # d = (3, 3): 18 > N
    assert rate <= 3 / 97                                      # only rho_0 = 0 (1/p) lets it through
    plain = dataclasses.replace(enc, norm=0.0)
    assert _norm_cheat_rate(plain, [3, 3]) == 1.0              # without the norm check it is valid


def test_the_study_node_computes_what_the_phased_protocol_reveals():
    fleet, wide, tight, inputs = _setup(n=5, R=0.25)
    lie = dict(inputs)
    lie[2] = inputs[2] * 3.0
    out = run_phased_session(fleet, lie, session_id(7, 0), wide, tight, phases=6, verify_key=KEY, rng=0)
    us = [wide.clip(u)[0] for _, u in sorted(lie.items())]
    ideal, clipped = centred_clipping(us, us, tight.honest_radius, 6)
    assert out.clipped == clipped > 0
    assert np.max(np.abs(out.result - ideal)) < 6 * 2.0 ** -12


def test_the_radius_schedule_and_one_encoding_per_phase():
    assert radius_schedule(1.0, 5, grow=4.0) == [4.0, 2.0, 1.0, 1.0] and radius_schedule(1.0, 3) == [1.0, 1.0]
    fleet, wide, _, inputs = _setup()
    encs = [ValidityEncoding(np.full(L, r), r * 2.0 ** -12, norm=r) for r in radius_schedule(0.6, 4, grow=4.0)]
    out = run_phased_session(fleet, inputs, session_id(8, 0), wide, encs, phases=4, verify_key=KEY, rng=0)
    assert out.phases == 4 and np.max(np.abs(out.result - np.mean(list(inputs.values()), axis=0))) < 2.0 ** -10
    with pytest.raises(ParameterError, match="one encoding per phase"):
        run_phased_session(fleet, inputs, session_id(9, 0), wide, encs, phases=3, verify_key=KEY, rng=0)


def test_the_public_schedule_works_off_the_largest_offset():
    assert public_schedule(7.1, 1.0) == (6, 8.0)          # radii 8, 4, 2, 1, 1
    assert public_schedule(0.5, 1.0, final=1) == (2, 1.0)
    assert radius_schedule(1.0, *public_schedule(29.7, 1.0)) == [32.0, 16.0, 8.0, 4.0, 2.0, 1.0, 1.0]
