"""Replicated validated aggregation (three aggregators, one may deviate): the core, in-process (issue 20).

Oracles: the plain sum of the quantised inputs (honest sessions equal it exactly); a share is the difference
of the input and uniform expansions, so an aggregator's two components are independent of the input (the
third one, which it lacks, masks it; chi-square on a small field); a component's two holders compute the same
verifier share and the same sum from what they received (by the parts' hashes), so a change by one of them is
a conflict; a cheater's proof fails whoever holds what.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from roadcollab.errors import MessageError, ParameterError
from roadcollab.privacy.secagg_flp import ValidityEncoding
from roadcollab.privacy.secagg_replicated import ReplicatedAggregator, holdings, submit
from roadcollab.privacy.secagg_replicated_run import combine_sums, combine_verifications, run_replicated_aggregation
from roadcollab.wire.identity import FleetAuthority, VehicleIdentity

L = 10
ENC = ValidityEncoding(np.full(L, 4.0), 2.0 ** -12)
BALL = ValidityEncoding(np.full(L, 0.6), 2.0 ** -12, norm=0.6)


def _inputs(n=5, seed=0, scale=1.0):
    g = np.random.default_rng(seed)
    return {i: np.clip(g.normal(0, scale, L), -3.9, 3.9) for i in range(1, n + 1)}


def test_holdings_give_every_component_two_holders_and_every_aggregator_one_gap():
    three = holdings(3)
    assert [sorted(a for a in range(3) if j in three[a]) for j in range(3)] == [[0, 2], [0, 1], [1, 2]]
    assert all(len(set(range(3)) - set(c)) == 1 for c in three)
    assert holdings(2) == ((0,), (1,))
    with pytest.raises(ParameterError, match="2 or 3"):
        holdings(4)


@pytest.mark.parametrize("aggregators", [2, 3])
def test_honest_sessions_give_the_sum_of_the_quantised_inputs(aggregators):
    us = _inputs()
    ups = {i: submit(ENC, u, b"s", i, np.random.default_rng(i), aggregators=aggregators) for i, u in us.items()}
    out = run_replicated_aggregation(ENC, ups, b"s", aggregators=aggregators, min_inputs=3, rng=1)
    assert out.accepted == (1, 2, 3, 4, 5) and out.refused == {}
    assert np.allclose(out.total, sum(ENC.quantize(u) for u in us.values()), atol=1e-12)
    few = run_replicated_aggregation(ENC, {i: ups[i] for i in (1, 2)}, b"s", aggregators=aggregators, min_inputs=3)
    assert few.total is None and few.accepted == (1, 2)


@pytest.mark.parametrize("aggregators", [2, 3])
def test_cheaters_are_refused_whoever_holds_what(aggregators):
    us = _inputs(scale=0.05)
    g = np.random.default_rng(7)
    ups = {i: submit(BALL, u, b"t", i, g, aggregators=aggregators) for i, u in us.items()}
    ups[2] = submit(BALL, None, b"t", 2, g, aggregators=aggregators,
                    x=BALL.encode_raw(np.full(L, 2 ** int(BALL.bits[0]) - 1)))          # outside the ball
    ups[4] = submit(BALL, None, b"t", 4, g, aggregators=aggregators, x=BALL.encode_raw(np.full(L, 2 ** 40)))
    out = run_replicated_aggregation(BALL, ups, b"t", aggregators=aggregators, min_inputs=3, rng=2)
    assert out.accepted == (1, 3, 5)
    assert "circuit output" in out.refused[2] and "sums of its bits" in out.refused[4]


def test_a_share_that_does_not_open_its_part_or_a_bad_signature_is_refused_by_its_holder():
    auth = FleetAuthority.generate("t")
    ident = VehicleIdentity.enroll(auth, "v1")
    up = submit(ENC, _inputs()[1], b"s", 1, np.random.default_rng(0), identity=ident)
    for a in range(3):
        ReplicatedAggregator(ENC, a).receive(up.commitments, up.shares[a], b"s", auth.trust(), ident.certificate)
    b = up.shares[1]
    bad_seed = dataclasses.replace(b, seeds={**b.seeds, 1: bytes(16)})
    with pytest.raises(MessageError, match="component 1 does not match"):
        ReplicatedAggregator(ENC, 1).receive(up.commitments, bad_seed, b"s")
    a0 = up.shares[0]
    x = a0.x0.copy()
    x[0] = (x[0] + 1) % ENC.field.p
    with pytest.raises(MessageError, match="component 0 does not match"):
        ReplicatedAggregator(ENC, 0).receive(up.commitments, dataclasses.replace(a0, x0=x), b"s")
    proof = a0.proof0.copy()
    proof[0] = (proof[0] + 1) % ENC.field.p
    with pytest.raises(MessageError, match="proof share does not match"):
        ReplicatedAggregator(ENC, 2).receive(up.commitments, dataclasses.replace(up.shares[2], proof0=proof), b"s")
    with pytest.raises(MessageError, match="component 0 does not match"):      # the session is in every part
        ReplicatedAggregator(ENC, 0).receive(up.commitments, a0, b"other session")
    forged = dataclasses.replace(up.commitments, signature=bytes(64))
    with pytest.raises(MessageError, match="bad signature"):
        ReplicatedAggregator(ENC, 0).receive(forged, a0, b"s", auth.trust(), ident.certificate)
    with pytest.raises(MessageError, match="not components"):
        ReplicatedAggregator(ENC, 0).receive(up.commitments, up.shares[1], b"s")


def test_one_aggregator_changing_a_verifier_share_or_a_sum_is_a_conflict():
    us = _inputs()
    ups = {i: submit(ENC, u, b"s", i, np.random.default_rng(i)) for i, u in us.items()}
    aggs = [ReplicatedAggregator(ENC, a) for a in range(3)]
    reports = [{} for _ in aggs]
    for i, up in ups.items():
        for a, agg in enumerate(aggs):
            agg.receive(up.commitments, up.shares[a], b"s")
            reports[a][i] = agg.verify(i, b"s", b"key")
    acc, refused, conflicts = combine_verifications(ENC, 3, ups, reports)
    assert acc == (1, 2, 3, 4, 5) and not refused and not conflicts
    for a in range(3):                      # each aggregator's first component, changed in its report only
        changed = [dict(r) for r in reports]
        v = changed[a][3]
        j = holdings(3)[a][0]
        vals = {**v.values, j: (v.values[j] + 1) % ENC.field.p}
        changed[a][3] = dataclasses.replace(v, values=vals)
        _, _, conflicts = combine_verifications(ENC, 3, ups, changed)
        assert conflicts == [f"vehicle 3: the holders of component {j} report different verifier shares"]
    sums = [agg.component_sums(acc, 3) for agg in aggs]
    total = combine_sums(ENC, 3, sums)
    assert np.allclose(ENC.decode_sum(total, 5), sum(ENC.quantize(u) for u in us.values()), atol=1e-12)
    for a in range(3):
        bad = [dict(s) for s in sums]
        j = holdings(3)[a][1]
        bad[a][j] = (bad[a][j] + 5) % ENC.field.p
        with pytest.raises(MessageError, match=f"component {j} report different sums"):
            combine_sums(ENC, 3, bad)
    with pytest.raises(Exception, match="already released"):
        aggs[0].component_sums(acc, 3)


def test_what_one_aggregator_holds_is_independent_of_the_input():
    """Chi-square on F_17: the pair of components aggregator 0 holds (first coordinate of x) for inputs 0 and 3
    is uniform on F^2; with the third component it would give the input (the test of the test)."""
    from roadcollab.privacy.secagg_flp import Field

    f = Field(17, 3)
    enc = ValidityEncoding(np.full(1, 3.0), 1.0, field=f)
    g = np.random.default_rng(5)
    for u in (-3.0, 3.0):
        counts = np.zeros((17, 17))
        whole = set()
        for _ in range(4000):
            up = submit(enc, [u], b"s", 1, g)
            a0 = up.shares[0]
            x0 = int(a0.x0[0])
            x1 = int(f.elements(a0.seeds[1], b"x", enc.length + enc.n_bits)[0])
            counts[x0, x1] += 1
            x2 = int(f.elements(up.shares[1].seeds[2], b"x", enc.length + enc.n_bits)[0])
            whole.add((x0 + x1 + x2) % 17)
        expected = 4000 / 289
        chi2 = float(((counts - expected) ** 2 / expected).sum())
        assert chi2 < 288 + 5 * np.sqrt(2 * 288), chi2      # 288 degrees of freedom
        assert len(whole) == 1                               # all three components give the input
