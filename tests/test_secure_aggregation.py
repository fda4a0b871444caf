"""Tests of roadcollab.privacy secure aggregation: exactness, dropouts, k enforced, masking, collusion, costs."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import kstest

from roadcollab.errors import MessageError, ParameterError
from roadcollab.privacy._secagg_kernels import (decode_sum, derive, encode_fixed, prg_ring, shamir_combine,
                                                shamir_split)
from roadcollab.privacy.secagg_run import (aggregator_view, collusion_view, run_secure_aggregation,
                                           secure_aggregation_cost)
from roadcollab.privacy.secure_aggregation import (_pair_mask, AggregationRefused, MaskedInput, Reveal, SecAggSpec,
                                                   advertise_keys, mask_input, reveal_shares, session_id, share_keys,
                                                   unmask)

SPEC = SecAggSpec(min_inputs=5, threshold=5)
N = 10


def _inputs(n=N, length=64, seed=0):
    gen = np.random.default_rng(seed)
    return [0.05 * gen.standard_normal((length, 2)) for _ in range(n)]


def _rel_err(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def test_sum_is_exact_without_dropouts():
    zs = _inputs()
    run = run_secure_aggregation(zs, SPEC, rng=0)
    plain = np.mean(zs, axis=0)
    assert run.result.survivors == tuple(range(1, N + 1)) and run.result.dropped == ()
    assert _rel_err(run.average, plain) <= 1e-9
    # Rounding to nearest: each input is off by at most half the resolution, so is the average.
    assert np.max(np.abs(run.average - plain)) <= 0.5 * SPEC.resolution * (1 + 1e-9)


@pytest.mark.parametrize("gone, silent", [((2, 7), ()), ((2, 7), (4,)), ((), (1, 3, 5)), ((1, 2, 3, 4, 5), ())])
def test_dropouts_are_recovered_exactly(gone, silent):
    zs = _inputs(seed=1)
    run = run_secure_aggregation(zs, SPEC, dropped_before_masking=gone, silent_in_unmasking=silent, rng=1)
    survivors = [i for i in range(1, N + 1) if i not in gone]
    assert run.result.survivors == tuple(survivors) and run.result.dropped == tuple(gone)
    assert _rel_err(run.average, np.mean([zs[i - 1] for i in survivors], axis=0)) <= 1e-9


def test_fewer_than_k_survivors_are_refused():
    zs = _inputs()
    with pytest.raises(AggregationRefused, match="at least k = 5"):
        run_secure_aggregation(zs, SPEC, dropped_before_masking=(1, 2, 3, 4, 5, 6), rng=0)


def test_aggregator_refuses_fewer_than_k_masked_inputs_and_fewer_than_t_answers():
    run = run_secure_aggregation(_inputs(), SPEC, rng=0)
    v = aggregator_view(run)
    four = [MaskedInput(i, v.masked[i]) for i in (1, 2, 3, 4)]
    with pytest.raises(AggregationRefused, match="4 masked inputs"):
        unmask(v.roster, four, v.reveals, SPEC, run.session)
    all_in = [MaskedInput(i, y) for i, y in v.masked.items()]
    with pytest.raises(AggregationRefused, match="threshold t = 5"):
        unmask(v.roster, all_in, v.reveals[:4], SPEC, run.session)
    with pytest.raises(AggregationRefused, match="silent|threshold"):
        run_secure_aggregation(_inputs(), SPEC, silent_in_unmasking=(1, 2, 3, 4, 5, 6), rng=0)


def _session(n=N, spec=SPEC, seed=3, length=64):
    session = session_id(7, 1)
    gen = np.random.default_rng(seed)
    pairs = [advertise_keys(i, session, root=gen.bytes(32)) for i in range(1, n + 1)]
    secrets = {s.vehicle: s for s, _ in pairs}
    roster = {a.vehicle: a for _, a in pairs}
    sealed = {i: share_keys(secrets[i], roster, spec) for i in roster}
    return session, secrets, roster, sealed


def test_honest_vehicle_refuses_to_reveal_for_fewer_than_k_survivors():
    session, secrets, roster, sealed = _session()
    mine = {i: sealed[i][1] for i in roster if i != 1}
    with pytest.raises(AggregationRefused, match="4 survivors"):
        reveal_shares(secrets[1], mine, roster, [1, 2, 3, 4], SPEC)
    rev = reveal_shares(secrets[1], mine, roster, [1, 2, 3, 4, 5, 6], SPEC)
    # Never both secrets of one vehicle: b for the survivors, s_sk for the others.
    assert set(rev.self_mask_shares) == {1, 2, 3, 4, 5, 6} and set(rev.key_shares) == {7, 8, 9, 10}


def test_a_masked_vector_is_uniform_on_the_ring_and_uncorrelated_with_its_input():
    zs = _inputs(length=6750, seed=4)
    run = run_secure_aggregation(zs, SPEC, rng=4)
    v = aggregator_view(run)
    for i in (1, 5, 10):
        u = v.masked[i].ravel().astype(float) / 2.0 ** 64
        assert kstest(u, "uniform").pvalue > 1e-3
        read = v.masked_as_float(i).ravel()
        assert abs(np.corrcoef(read, zs[i - 1].ravel())[0, 1]) < 4 / np.sqrt(read.size)
    # The same input masked in another session looks unrelated to the first masking.
    other = aggregator_view(run_secure_aggregation(zs, SPEC, session=session_id(0, 1), rng=4))
    a, b = (w.masked_as_float(1).ravel() for w in (v, other))
    assert abs(np.corrcoef(a, b)[0, 1]) < 4 / np.sqrt(a.size)


@pytest.mark.parametrize("colluders", [(1,), (2, 3), (1, 2, 3, 4)])
def test_collusion_below_t_reveals_exactly_the_sum_of_the_rest(colluders):
    zs = _inputs(seed=5)
    run = run_secure_aggregation(zs, SPEC, dropped_before_masking=(9,), rng=5)
    cv = collusion_view(run, colluders)
    honest = [i for i in range(1, N + 1) if i not in colluders and i != 9]
    assert cv.honest == tuple(honest) and cv.recovered == {}
    truth = np.sum([zs[i - 1] for i in honest], axis=0)
    assert np.max(np.abs(cv.honest_sum - truth)) <= N * SPEC.resolution


def test_collusion_of_t_vehicles_unmasks_individuals_the_bound_is_tight():
    zs = _inputs(seed=6)
    run = run_secure_aggregation(zs, SPEC, rng=6)
    cv = collusion_view(run, (1, 2, 3, 4, 5))
    assert sorted(cv.recovered) == [6, 7, 8, 9, 10]
    for h, x in cv.recovered.items():
        assert np.max(np.abs(x - zs[h - 1])) <= SPEC.resolution


def test_a_late_input_stays_masked_by_its_self_mask():
    """Vehicle 3 is declared dropped (its s_sk is rebuilt); its y_3 then arrives: b_3 still hides x_3."""
    zs = _inputs(length=2000, seed=7)
    run = run_secure_aggregation(zs, SPEC, dropped_before_masking=(3,), rng=7)
    v = aggregator_view(run)
    shares = {r.vehicle: r.key_shares[3] for r in v.reveals}
    s_sk = shamir_combine(shares, SPEC.threshold, "s_sk")
    assert not any(3 in r.self_mask_shares for r in v.reveals)   # b_3 was never revealed
    y3 = mask_input(run.secrets[2], zs[2], v.roster, SPEC).y
    for j in v.roster:
        if j != 3:
            y3 = y3 - _pair_mask(s_sk, 3, j, v.roster[j].s_pk, run.session, y3.shape)
    read = decode_sum(y3, SPEC.frac_bits).ravel()
    assert abs(np.corrcoef(read, zs[2].ravel())[0, 1]) < 4 / np.sqrt(read.size)
    # With b_3 it would be exact: the self mask is all that is left.
    b3 = derive(run.secrets[2].b_seed, b"self", run.session, 3)
    assert np.max(np.abs(decode_sum(y3 - prg_ring(b3, y3.shape), SPEC.frac_bits) - zs[2])) <= SPEC.resolution


def test_contributions_are_clipped_at_the_source():
    zs = _inputs(seed=8)
    zs[0] = zs[0] + 1e6          # a wild (or malicious) contribution
    run = run_secure_aggregation(zs, SPEC, rng=8)
    plain = np.mean([np.clip(z, -SPEC.clip, SPEC.clip) for z in zs], axis=0)
    assert _rel_err(run.average, plain) <= 1e-9
    assert np.max(run.average) <= SPEC.clip / N + 0.1


def test_shamir_threshold():
    secret = bytes(range(32))
    shares = shamir_split(secret, list(range(1, 8)), 4, b"\x01" * 32)
    assert shamir_combine({x: shares[x] for x in (2, 5, 6, 7)}, 4, "s") == secret
    assert shamir_combine(shares, 4, "s") == secret           # extra shares checked and consistent
    with pytest.raises(MessageError, match="3 shares received, threshold 4"):
        shamir_combine({x: shares[x] for x in (1, 2, 3)}, 4, "s")
    bad = {**shares, 7: shares[7] + 1}
    with pytest.raises(MessageError, match="holder 7 is inconsistent"):
        shamir_combine(bad, 4, "s")


def test_fixed_point_round_trip():
    x = np.array([[0.0, -1.0], [3.25e-3, 15.999], [-16.0, 1e-12]])
    q = encode_fixed(x, 16.0, 40)
    assert q.dtype == np.uint64
    assert np.max(np.abs(decode_sum(q, 40) - x)) <= 2.0 ** -41


def test_untrusted_inputs_raise_message_error():
    session, secrets, roster, sealed = _session()
    mine = {i: sealed[i][1] for i in roster if i != 1}
    tampered = {**mine, 2: bytes([mine[2][0] ^ 1]) + mine[2][1:]}
    with pytest.raises(MessageError, match="vehicle 2 failed authentication"):
        reveal_shares(secrets[1], tampered, roster, list(roster), SPEC)
    with pytest.raises(MessageError, match="expected 156 bytes"):
        reveal_shares(secrets[1], {**mine, 2: b"short"}, roster, list(roster), SPEC)
    with pytest.raises(MessageError, match="not in the roster"):
        reveal_shares(secrets[1], mine, roster, [1, 2, 3, 4, 5, 99], SPEC)
    with pytest.raises(MessageError, match="uint64"):
        MaskedInput(1, np.zeros((4, 2)))
    with pytest.raises(MessageError, match="positive int"):
        MaskedInput(0, np.zeros((4, 2), dtype=np.uint64))
    bad_key = {**roster, 2: dataclasses.replace(roster[2], c_pk=bytes(32))}
    with pytest.raises(MessageError, match="invalid X25519"):
        share_keys(secrets[1], bad_key, SPEC)


def test_aggregator_rejects_bad_shares_and_shapes():
    run = run_secure_aggregation(_inputs(), SPEC, dropped_before_masking=(10,), rng=9)
    v = aggregator_view(run)
    masked = [MaskedInput(i, y) for i, y in v.masked.items()]
    r0 = v.reveals[0]
    forged = Reveal(r0.vehicle, r0.self_mask_shares, {10: r0.key_shares[10] + 1})
    with pytest.raises(MessageError, match="s_sk of vehicle 10"):
        unmask(v.roster, masked, (forged,) + v.reveals[1:], SPEC, run.session)
    short = masked[:-1] + [MaskedInput(masked[-1].vehicle, masked[-1].y[:10])]
    with pytest.raises(MessageError, match="different shapes"):
        unmask(v.roster, short, v.reveals, SPEC, run.session)


def test_spec_and_arguments_are_validated():
    with pytest.raises(ParameterError, match="threshold must be <= 5"):
        SecAggSpec(min_inputs=5, threshold=6)
    with pytest.raises(ParameterError, match="clip must be <="):
        SecAggSpec(clip=1e6, frac_bits=40)
    with pytest.raises(ParameterError, match="2\\^63"):
        SecAggSpec(min_inputs=2, threshold=2, clip=4096.0, frac_bits=40).check_fleet(2 ** 20)
    with pytest.raises(ParameterError, match="n_vehicles must be >= 5"):
        run_secure_aggregation(_inputs(n=4), SPEC)
    with pytest.raises(ParameterError, match="inputs must be"):
        run_secure_aggregation([np.zeros((4, 2))] * 5 + [np.zeros((5, 2))], SPEC)
    with pytest.raises(ParameterError, match="dropped_before_masking"):
        run_secure_aggregation(_inputs(), SPEC, dropped_before_masking=(11,))
    with pytest.raises(ParameterError, match="root must be 32 bytes"):
        advertise_keys(1, session_id(0, 0), root=b"x")
    assert "secret" in repr(_session()[1][1]) and "b_seed" not in repr(_session()[1][1])


def test_cost_per_vehicle():
    length = 100
    cost = secure_aggregation_cost(_inputs(length=length)[0], n_vehicles=N, spec=SPEC, dropped=1, repeats=1, rng=0)
    assert cost["rounds"] == 4 and cost["max_rel_error"] <= 1e-9
    # Sent: keys 68; 9 sealed shares of 156 + 4 routing bytes; y (4 + 8 * 200); 10 shares of 4 + 66 (+ 4).
    assert cost["bytes_per_message"] == 68 + 9 * 160 + 4 + 8 * 2 * length + 4 + 10 * 70
    assert cost["ms_per_message"] > 0 and cost["aggregator_ms"] > 0 and cost["n_values"] == 2 * length
    assert set(cost["ms_by_round"]) == {"advertise_keys", "share_keys", "masked_input", "unmasking"}
