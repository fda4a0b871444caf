"""Bounded influence alone against one malicious vehicle in secure aggregation (issue 20, section 2)."""

from __future__ import annotations

import pytest

from roadcollab.experiments.anomalies.config import AnomalyStudyConfig
from roadcollab.experiments.security.secagg_bounds import bounded_influence_ceiling


@pytest.mark.slow
def test_an_ideal_l2_bound_alone_misses_the_2x_target():
    """The finding documented in docs/security-secagg.md: even the tightest bound that admits every honest
    input lets one vehicle cost the guarded fused estimate well over 2x; a looser bound costs more."""
    rows = bounded_influence_ceiling(AnomalyStudyConfig(), 0, n_runs=1, margins=(1.0, 1.5))
    assert all(r.ratio > 2.0 for r in rows)
    assert rows[1].ratio > rows[0].ratio
