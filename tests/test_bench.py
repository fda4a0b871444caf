"""The benchmark measures what it says (smoke test; speed targets live in `roadcollab bench`)."""

import pytest

from roadcollab import ParameterError
from roadcollab.experiments.bench import bench_segment


@pytest.mark.parametrize("mechanism", ["none", "paper", "paper_vehicle", "hardened"])
def test_bench_segment_reports_its_fields(mechanism):
    rec = bench_segment(1000, mechanism=mechanism, repeats=2)
    assert rec["samples_per_segment"] == 1000 and rec["nfft"] >= 1500
    assert rec["ms_per_vehicle_segment"] > 0 and rec["ms_per_vehicle_setup"] > 0


def test_bench_rejects_unknown_mechanism():
    with pytest.raises(ParameterError, match="mechanism must be one of"):
        bench_segment(1000, mechanism="rot13")
