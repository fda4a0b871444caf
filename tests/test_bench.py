"""The benchmark measures what it says (smoke test; speed targets live in `roadcollab bench`)."""

import pytest

from roadcollab import ParameterError
from roadcollab.experiments.bench.study import bench_segment


@pytest.mark.parametrize("mechanism", ["none", "paper", "paper_vehicle", "hardened"])
def test_bench_segment_reports_its_fields(mechanism):
    rec = bench_segment(1000, mechanism=mechanism, repeats=2)
    assert rec["samples_per_segment"] == 1000 and rec["nfft"] >= 1500
    assert rec["ms_per_vehicle_segment"] > 0 and rec["ms_per_vehicle_setup"] > 0
    # The split covers the timed work: each part below the whole (medians of the same segments).
    assert 0 < rec["ms_receive_median"] < rec["ms_per_vehicle_segment"]
    assert 0 < rec["ms_send_median"] < rec["ms_per_vehicle_segment"]


def test_bench_rejects_unknown_mechanism():
    with pytest.raises(ParameterError, match="mechanism must be one of"):
        bench_segment(1000, mechanism="rot13")


def test_naive_chain_agrees_with_the_library_and_exactness_is_measured():
    from roadcollab.experiments.bench.study import bench_exactness, bench_naive

    naive = bench_naive(1000, repeats=2)
    assert naive["library_ms_min"] > 0 and naive["speedup_min"] == naive["ms_min"] / naive["library_ms_min"]
    assert naive["ms_min"] > 0 and naive["max_rel_vs_library"] < 1e-9
    ex = bench_exactness(segments=1, n_samples=1000)
    assert set(ex) == {"privacy_vs_clear", "privacy_vs_clear_direct_receiver", "receiver_algorithms",
                       "receiver_vs_sender"}
    assert ex["privacy_vs_clear"] < 1e-11 and ex["receiver_algorithms"] < 1e-9 and ex["receiver_vs_sender"] < 1e-9


def test_bench_checks_every_segment_on_the_reference_path():
    rec = bench_segment(1000, mechanism="paper", repeats=3, kernels="reference")
    assert rec["kernels"] == "reference"
    assert 0 < rec["max_rel_privacy_vs_clear"] < 1e-9        # measured on every segment, so never exactly 0
    assert bench_segment(1000, mechanism="none", repeats=1)["max_rel_privacy_vs_clear"] == 0.0
    with pytest.raises(ParameterError, match="kernels must be one of"):
        bench_segment(1000, repeats=1, kernels="fast")


@pytest.mark.slow  # 40 s on a fresh install: it compiles every kernel (2.5 s once cached)
def test_bench_times_both_kernel_paths():
    from roadcollab.experiments.bench.study import bench_kernel_paths
    from roadcollab.lti.kernels import compiled_available

    paths = bench_kernel_paths(1000, repeats=2, rounds=2)
    assert paths["reference"]["ms_min"] > 0
    if compiled_available():
        assert paths["compiled"]["ms_min"] > 0 and paths["speedup_median"] > 0
