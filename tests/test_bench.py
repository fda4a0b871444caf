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


def test_machine_load_is_the_three_load_averages_or_none(monkeypatch):
    import os

    from roadcollab.experiments.bench.study import machine_load

    monkeypatch.setattr(os, "getloadavg", lambda: (0.5, 0.75, 1.25))
    assert machine_load() == [0.5, 0.75, 1.25]

    def fails():
        raise OSError("no load average")

    monkeypatch.setattr(os, "getloadavg", fails)
    assert machine_load() is None
    monkeypatch.delattr(os, "getloadavg")            # as on Windows
    assert machine_load() is None


def _record(load_start, load_end):
    """A benchmark record as ``run_bench`` returns it, with made-up figures (for the table's format)."""
    mech = {"ms_min": 1.5, "ms_median": 1.7, "ms_receive_median": 1.0, "ms_send_median": 0.7,
            "floor_multiple_min": 19.0, "floor_multiple_median": 21.0}
    return {"floor": {"floor_ms": 0.08}, "samples_per_segment": 4000, "repeats": 60,
            "by_mechanism": {m: dict(mech) for m in ("none", "paper", "paper_vehicle", "hardened")},
            "naive_paper": {"ms_min": 30.0, "ms_median": 40.0, "library_ms_min": 1.5, "library_ms_median": 2.0},
            "speedup_paper_vs_naive": {"min": 20.0, "median": 20.0, "per_segment_median": 21.0},
            "exactness": {"privacy_vs_clear": 2.8e-13}, "max_rel_privacy_vs_clear": 1.7e-12,
            "kernels": "compiled", "kernel_paths": {"compiled": {"ms_min": 1.5, "ms_median": 1.7},
                                                    "reference": {"ms_min": 5.0, "ms_median": 6.0},
                                                    "speedup_median": 3.5},
            "scaling": [{"n_samples": 4000, "ms_paper": 1.7, "paper_per_nlogn_rel": 1.0, "ms_hardened": 0.3,
                         "hardened_per_nlogn_rel": 1.0}],
            "ms_per_vehicle_setup": 3.0, "load_average": {"start": load_start, "end": load_end}, "seed": 7,
            "roadcollab_version": "9.9.9"}


@pytest.mark.parametrize("load_start, load_end, expected", [
    ([0.5, 0.75, 1.25], [1.4, 0.9, 1.3], "load 0.50 -> 1.40 (1 min), 0.75 -> 0.90 (5 min)"),
    (None, None, "load average not available")])
def test_the_bench_table_states_the_load_seed_and_version(monkeypatch, capsys, load_start, load_end, expected):
    import roadcollab.experiments.bench.study as study
    from roadcollab.cli import bench
    from roadcollab.cli.main import build_parser

    monkeypatch.setattr(study, "run_bench", lambda **kwargs: _record(load_start, load_end))
    args = build_parser().parse_args(["bench", "--quick"])
    assert bench.run(args, "roadcollab bench --quick") == 0
    out = " ".join(capsys.readouterr().out.split())      # the table's title may wrap
    assert expected in out
    assert "seed 7, roadcollab 9.9.9" in out


@pytest.mark.slow  # runs every part of the benchmark once (compiles every kernel on a fresh install)
def test_the_bench_record_carries_the_load_seed_and_version():
    import roadcollab
    from roadcollab.experiments.bench.study import run_bench

    rec = run_bench(sizes=(1000,), repeats=3, seed=3, exactness_segments=1)
    for when in ("start", "end"):
        load = rec["load_average"][when]
        assert len(load) == 3 and all(x >= 0 for x in load)
    assert rec["seed"] == 3 and rec["roadcollab_version"] == roadcollab.__version__
