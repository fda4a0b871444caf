"""Estimation from recorded drives: file formats, clear errors, and equality with the in-memory pipeline."""

import argparse
import csv
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from roadcollab import ParameterError
from roadcollab.cli.estimate import add_estimate_arguments, estimate_command
from roadcollab.experiments.drives.estimation import ESTIMATORS, estimate_drives, integrate_elevation
from roadcollab.io.drive_clean import clean_drive
from roadcollab.io.drives import common_time_grid, load_drive, load_drives, read_drive_csv, write_drive_csv
from roadcollab.io.drive_params import write_drive_params
from roadcollab.experiments.config import ExperimentConfig
from roadcollab.experiments.anomalies.estimates import run_estimates
from roadcollab.experiments.pipeline import FleetPipeline
from roadcollab.models.simulation import add_sensor_noise, simulate_response
from roadcollab.models.vehicle import HalfCarParameters, sample_fleet
from roadcollab.reporting.drive_tables import FINAL_COLUMNS

SEED = 7


def _read_columns(path: Path) -> dict[str, np.ndarray]:
    with path.open() as fh:
        rows = list(csv.DictReader(fh))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def _rel(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b)))


# --- a simulated fleet written to disk -----------------------------------------------------------

@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """3-vehicle fleet: in-memory estimates (run_estimates) and the same measurements as drive files."""
    cfg = ExperimentConfig(n_vehicles=3, n_runs=1)
    pipe = FleetPipeline(cfg, sample_fleet(3, cfg.fleet, rng=11))
    ref = run_estimates(pipe, np.random.SeedSequence(SEED))
    # Regenerate the measurements exactly as run_estimates draws them.
    road_ss, noise_ss = np.random.SeedSequence(SEED).spawn(2)
    road = pipe.road(np.random.default_rng(road_ss))
    assert np.array_equal(road.velocity, ref.road.velocity)
    noise_rng = np.random.default_rng(noise_ss)
    d = tmp_path_factory.mktemp("drives")
    paths = []
    for j, est in enumerate(pipe.estimators):
        y = add_sensor_noise(simulate_response(est.true_plant, road.velocity), cfg.sensor_noise_std, rng=noise_rng)
        # Logger clocks need not start at 0 (drive 2 starts at 12.5 s).
        t = road.time + (12.5 if j == 1 else 0.0)
        paths.append(write_drive_csv(d / f"drive{j + 1}.csv", t, y))
        # Only the *estimated* parameters are known for real cars; drive 2 uses JSON.
        write_drive_params(d / f"drive{j + 1}.{'json' if j == 1 else 'toml'}", speed=cfg.speed,
                           params=est.vehicle.estimated_params, sensor_noise_std=cfg.sensor_noise_std,
                           start_m=float(road.start))
    out = d / "out"
    summary = estimate_command([str(p) for p in paths], out, command="roadcollab estimate ...")
    return {"cfg": cfg, "pipe": pipe, "ref": ref, "paths": paths, "out": out, "summary": summary, "dir": d}


def test_command_reproduces_in_memory_estimates(simulated):
    """The library on the drive files, unguarded, reproduces the in-memory pipeline; the command is the
    (guarded) library on the cleaned drives (spike repair and offset removal, roadcollab.io.drive_clean) and writes it in full precision."""
    ref, out, summary = simulated["ref"], simulated["out"], simulated["summary"]
    assert summary["n_drives"] == 3 and summary["sample_rate_hz"] == 200.0 and summary["speed_mps"] == 15.0
    assert summary["n_samples"] == ref.collaborative.shape[1] and not summary["truncated"]
    assert summary["spikes_repaired"] == [0, 0, 0]
    raw = load_drives(simulated["paths"])
    lib = estimate_drives(raw, guard=None)      # the in-memory pipeline is the paper's unguarded Algorithm 1
    guarded = estimate_drives(raw)
    cleaned = estimate_drives([clean_drive(d)[0] for d in raw])     # the command: guarded by default
    cols = _read_columns(out / "road_estimates.csv")
    assert np.allclose(cols["position_m"], ref.positions, rtol=0, atol=1e-9)
    for name, arr in (("single", ref.observer_only), ("collaborative", ref.collaborative), ("fused", ref.fused)):
        for k in range(3):
            assert _rel(lib.velocity[name][k], arr[k]) < 1e-9, (name, k)
            for c, side in enumerate(("left", "right")):
                got = cols[f"w_{name}_v{k + 1}_{side}"]
                assert _rel(got, cleaned.velocity[name][k, :, c]) < 1e-12, (name, k, side)
                assert _rel(cols[f"elevation_{name}_v{k + 1}_{side}"],
                            integrate_elevation(cleaned.velocity[name][k], 200.0)[:, c]) < 1e-12
                # Removing the slow trend (below 0.05 Hz) changes the estimate far less than its own error.
                err = np.sqrt(np.mean((arr[k, :, c] - ref.truth[:, c]) ** 2))
                assert np.sqrt(np.mean((got - guarded.velocity[name][k, :, c]) ** 2)) < 0.1 * err, (name, k, side)
    final = _read_columns(out / "final_estimate.csv")
    assert list(final) == list(FINAL_COLUMNS)
    assert _rel(final["elevation_collaborative_left"], cleaned.elevation["collaborative"][-1, :, 0]) < 1e-12
    assert _rel(final["elevation_fused_right"], cleaned.elevation["fused"][-1, :, 1]) < 1e-12
    assert np.all(final["coverage"] == 3)


def test_command_writes_all_outputs(simulated):
    out = simulated["out"]
    for name in simulated["summary"]["files"]:
        assert (out / name).stat().st_size > 0, name
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["seed"] is None and cfg["command"] == "roadcollab estimate ..." and "roadcollab_version" in cfg
    drives = cfg["config"]["drives"]
    assert [Path(d["csv"]).name for d in drives] == ["drive1.csv", "drive2.csv", "drive3.csv"]
    assert drives[1]["params_file"].endswith("drive2.json")
    est_params = simulated["pipe"].fleet[2].estimated_params.as_dict()
    assert drives[2]["vehicle"] == est_params
    report = (out / "report.md").read_text()
    for text in ("![road velocity](road_velocity.png)", "![elevation](elevation.png)", "## Anomalies",
                 "drive1.csv", "30 m"):
        assert text in report, text


def test_anomalies_match_the_detector(simulated):
    anomaly = pytest.importorskip("roadcollab.detection.detector")
    scoring = pytest.importorskip("roadcollab.detection.scoring")
    ref, out, cfg = simulated["ref"], simulated["out"], simulated["cfg"]
    with (out / "anomalies.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == ["estimator", "vehicle", "position_m", "side", "kind", "depth_m", "confidence"]
    assert {r["estimator"] for r in rows} <= set(ESTIMATORS)
    cleaned = estimate_drives([clean_drive(d)[0] for d in load_drives(simulated["paths"])])   # what the command ran
    for name in ("collaborative", "fused"):
        arr = cleaned.velocity[name]
        dets = anomaly.detect_anomalies(arr[-1], positions=ref.positions, speed=cfg.speed, sample_rate=cfg.sample_rate)
        got = [r for r in rows if r["estimator"] == name and r["vehicle"] == "3"]
        assert len(got) == len(dets) and len(dets) > 0
        for r, d in zip(got, dets):
            assert (r["side"], r["kind"]) == (d.side, d.kind)
            assert abs(float(r["position_m"]) - d.position) < 1e-6
            assert abs(float(r["depth_m"]) - d.depth) < 1e-6 * d.depth
    assert simulated["summary"]["n_anomalies"]["fused"] == sum(1 for r in rows if r["estimator"] == "fused")
    # The simulated road's anomalies are found by the fused estimate of the last drive.
    dets = anomaly.detect_anomalies(cleaned.velocity["fused"][-1], positions=ref.positions, speed=cfg.speed,
                                    sample_rate=cfg.sample_rate)
    score = scoring.match_detections(dets, ref.road.anomalies, region=(15.0, 315.0))
    assert score.n_true == 0 or score.recall > 0.5


def test_drives_of_different_length_are_truncated(simulated, tmp_path):
    paths = simulated["paths"]
    t, y, _ = read_drive_csv(paths[2])
    short = write_drive_csv(tmp_path / "short.csv", t[:-100], y[:-100])
    (tmp_path / "short.toml").write_text(paths[2].with_suffix(".toml").read_text())
    drives = load_drives([paths[0], paths[1], short])
    est = estimate_drives(drives)
    n = drives[0].n_samples - 100
    assert est.n_samples == n and est.truncated and est.velocity["fused"].shape == (3, n, 2)
    summary = estimate_command([str(paths[0]), str(short)], tmp_path / "out", command="x")
    assert summary["truncated"] and summary["samples_per_drive"] == [n + 100, n]
    assert "truncated to the shortest" in (tmp_path / "out" / "report.md").read_text()


def test_add_estimate_arguments():
    p = argparse.ArgumentParser()
    add_estimate_arguments(p)
    args = p.parse_args(["--drive", "a.csv", "--drive", "b.csv", "--out", "o"])
    assert args.drive == ["a.csv", "b.csv"] and args.out == Path("o")
    with pytest.raises(SystemExit):
        p.parse_args(["--out", "o"])


# --- bad files -----------------------------------------------------------------------------------

PARAMS = HalfCarParameters(700.0, 500.0, 0.7, 0.8, 20000.0, 1500.0)
N_ROWS = 100


def _good_rows(n=N_ROWS, fs=200.0, t0=0.0):
    rng = np.random.default_rng(0)
    return [f"{t0 + k / fs!r},{float(a)!r},{float(b)!r}" for k, (a, b) in enumerate(rng.standard_normal((n, 2)))]


def _write_drive(d: Path, name="drive", *, lines=None, header="time_s,accel_left,accel_right", params=None,
                 suffix=".toml", fs=200.0, **param_kw):
    lines = _good_rows(fs=fs) if lines is None else lines
    csv_path = d / f"{name}.csv"
    csv_path.write_text("\n".join(([header] if header is not None else []) + lines) + "\n")
    if params is not None:
        (d / f"{name}{suffix}").write_text(params)
    else:
        kw = {"speed": 15.0, **param_kw}
        write_drive_params(d / f"{name}{suffix}", params=PARAMS, **kw)
    return csv_path


def _toml(top="speed_mps = 15.0", vehicle=None):
    veh = {k: v for k, v in PARAMS.as_dict().items()} if vehicle is None else vehicle
    return top + "\n\n[vehicle]\n" + "\n".join(f"{k} = {v!r}" for k, v in veh.items()) + "\n"


def test_good_drive_reads(tmp_path):
    path = _write_drive(tmp_path, header=" time_s , accel_left ,accel_right ")
    d = load_drive(path)
    assert d.n_samples == N_ROWS and d.sample_rate == 200.0 and d.speed == 15.0 and d.params == PARAMS
    assert d.start_m == 0.0 and d.sensor_noise_std == 0.05
    # BOM, CRLF line endings and blank lines are fine; JSON works too.
    rows = _good_rows()
    p2 = tmp_path / "win.csv"
    p2.write_bytes(("\ufefftime_s,accel_left,accel_right\r\n" + "\r\n".join(rows[:50] + [""] + rows[50:]) + "\r\n\r\n")
                   .encode("utf-8"))
    write_drive_params(tmp_path / "win.json", speed=15.0, params=PARAMS, start_m=12.0, sensor_noise_std=0.1)
    d2 = load_drive(p2)
    assert np.array_equal(d2.accel, d.accel) and d2.start_m == 12.0 and d2.sensor_noise_std == 0.1


def _bad_row(k, text):
    rows = _good_rows()
    rows[k] = text
    return rows


CSV_CASES = {
    "empty file": ([], None, r"line 1: expected the header 'time_s,accel_left,accel_right', got an empty file"),
    "missing header": (None, None, r"line 1: expected the header 'time_s,accel_left,accel_right', got a row of "
                                   r"numbers \(the header line is required\)"),
    "wrong header name": (None, "time,accel_left,accel_right",
                          r"line 1: expected the header 'time_s,accel_left,accel_right', got "
                          r"'time,accel_left,accel_right' \(column 1 is 'time', expected 'time_s'\)"),
    "extra column in header": (None, "time_s,accel_left,accel_right,speed",
                               r"line 1: expected the header .* got 4 column name\(s\)"),
    "row with 2 numbers": (_bad_row(15, "0.075,0.1"), "",
                           r"line 17: expected 3 numbers 'time_s, accel_left, accel_right', got 2"),
    "row with 4 numbers": (_bad_row(3, "0.015,0.1,0.2,0.3"), "", r"line 5: expected 3 numbers .*, got 4"),
    "non-numeric": (_bad_row(8, "0.04,abc,0.2"), "",
                    r"line 10: column 2 \(accel_left\): expected a number, got 'abc'"),
    "empty field": (_bad_row(8, "0.04,0.1,"), "",
                    r"line 10: column 3 \(accel_right\): expected a number, got an empty field"),
    "nan": (_bad_row(20, "0.1,nan,0.2"), "", r"line 22: column 2 \(accel_left\): expected a finite number, got 'nan'"),
    "inf": (_bad_row(20, "0.1,0.3,-inf"), "",
            r"line 22: column 3 \(accel_right\): expected a finite number, got '-inf'"),
    "gap": (_good_rows()[:40] + _good_rows(t0=0.5)[40:], "",
            r"line 42: a gap in the log: time_s jumps by 0.505 s \(101 median steps of 0.005 s; at most 3 are "
            r"bridged\) from 0.195 on line 41; 1 such gap\(s\) in total: split the log"),
    "time going back": (_bad_row(30, "0.1,0.1,0.2"), "", r"line 32: expected time_s to increase, got 0.1 after 0.145 "
                                                         r"on line 31 \(a clock step"),
    "clock standing still": (_bad_row(30, "0.145,0.1,0.2"), "", r"line 32: expected time_s to increase, got 0.145"),
    "speed out of range": ([r + ",80.0" for r in _good_rows()], "time_s,accel_left,accel_right,speed_mps",
                           r"line 2: column 4 \(speed_mps\): expected a speed in \[0.5, 70\] m/s, got 80.0"),
    "distance not increasing": ([r + f",{min(k, 50)}.0" for k, r in enumerate(_good_rows())],
                                "time_s,accel_left,accel_right,distance_m",
                                r": column 4 \(distance_m\) must increase .* got 50.0 after 50.0 at line 53"),
    "too few rows": (_good_rows(n=40), "", r": expected at least 64 data rows after the header, got 40"),
}


@pytest.mark.parametrize("case", list(CSV_CASES))
def test_bad_csv_is_a_clear_error(tmp_path, case):
    lines, header, pattern = CSV_CASES[case]
    header = "time_s,accel_left,accel_right" if header == "" else header
    if case == "missing header":
        lines, header = _good_rows(), None
    if case == "empty file":
        path = tmp_path / "drive.csv"
        path.write_text("\n\n")
        write_drive_params(tmp_path / "drive.toml", speed=15.0, params=PARAMS)
    else:
        path = _write_drive(tmp_path, lines=lines, header=header)
    with pytest.raises(ParameterError, match="^" + re.escape(str(path)) + " ?" + pattern):
        estimate_command([str(path)], tmp_path / "out", command="x")
    assert not (tmp_path / "out").exists()  # nothing is written for bad input


VEHICLE_WITHOUT_DAMPING = {k: v for k, v in PARAMS.as_dict().items() if k != "damping"}
PARAM_CASES = {
    "missing speed": (_toml(top="start_m = 0.0"), ".toml", r": missing required key\(s\) 'speed_mps'"),
    "missing vehicle key": (_toml(vehicle=VEHICLE_WITHOUT_DAMPING), ".toml",
                            r": missing required key\(s\) 'vehicle.damping'"),
    "missing vehicle table": ("speed_mps = 15.0\n", ".toml", r": missing required key\(s\) 'vehicle'"),
    "unknown key": (_toml(top="speed_mps = 15.0\nsensor_noise = 0.1"), ".toml",
                    r": unknown key\(s\) 'sensor_noise'; expected only speed_mps, vehicle, sensor_noise_std, start_m"),
    "unknown vehicle key": (_toml(vehicle={**PARAMS.as_dict(), "stifness": 1.0}), ".toml",
                            r": unknown key\(s\) 'vehicle.stifness'"),
    "negative speed": (_toml(top="speed_mps = -15.0"), ".toml",
                       r": key 'speed_mps' must lie in \[0.5, 70\] m/s \(the physical range\), got -15"),
    "zero stiffness": (_toml(vehicle={**PARAMS.as_dict(), "stiffness": 0.0}), ".toml",
                       r": key 'vehicle.stiffness' must lie in \[2000, 1.5e\+06\] N/m .*, got 0"),
    "negative noise": (_toml(top="speed_mps = 15.0\nsensor_noise_std = -1.0"), ".toml",
                       r": key 'sensor_noise_std' must lie in \[0, 20\] m/s\^2 .*, got -1"),
    "string value": (_toml(top='speed_mps = "15"'), ".toml", r": key 'speed_mps' must be a number \(m/s\), got '15'"),
    "bool value": (_toml(top="speed_mps = true"), ".toml", r": key 'speed_mps' must be a number \(m/s\), got True"),
    "vehicle not a table": ("speed_mps = 15.0\nvehicle = 3\n", ".toml", r": key 'vehicle' must be a table"),
    "toml syntax": ("speed_mps = = 15\n", ".toml", r": expected valid TOML, got a syntax error: .*line 1"),
    "json syntax": ('{\n  "speed_mps": 15.0,\n  "vehicle": {,}\n}\n', ".json",
                    r" line 3: expected valid JSON, got a syntax error"),
    "json not an object": ("[15.0]\n", ".json", r": expected a JSON object"),
    "json NaN": (json.dumps({"speed_mps": float("nan"), "vehicle": PARAMS.as_dict()}), ".json",
                 r": key 'speed_mps' must be a finite number \(m/s\), got nan"),
    "json unknown key": (json.dumps({"speed_mps": 15.0, "vehicle": PARAMS.as_dict(), "start": 3.0}), ".json",
                         r": unknown key\(s\) 'start'"),
}


@pytest.mark.parametrize("case", list(PARAM_CASES))
def test_bad_params_is_a_clear_error(tmp_path, case):
    text, suffix, pattern = PARAM_CASES[case]
    path = _write_drive(tmp_path, params=text, suffix=suffix)
    with pytest.raises(ParameterError, match="^" + re.escape(str(path.with_suffix(suffix))) + pattern):
        load_drive(path)


def test_missing_or_ambiguous_params_file(tmp_path):
    path = _write_drive(tmp_path)
    path.with_suffix(".toml").unlink()
    with pytest.raises(ParameterError, match="^" + re.escape(f"{path}: parameters file not found: expected "
                                                             f"{path.with_suffix('.toml')} or "
                                                             f"{path.with_suffix('.json')}")):
        load_drive(path)
    write_drive_params(path.with_suffix(".toml"), speed=15.0, params=PARAMS)
    write_drive_params(path.with_suffix(".json"), speed=15.0, params=PARAMS)
    with pytest.raises(ParameterError, match=re.escape(f"{path}: ambiguous parameters")):
        load_drive(path)


def test_missing_csv_and_wrong_file(tmp_path):
    with pytest.raises(ParameterError, match=re.escape(f"{tmp_path / 'nope.csv'}: drive CSV not found")):
        load_drive(tmp_path / "nope.csv")
    path = _write_drive(tmp_path)
    with pytest.raises(ParameterError, match="expected the drive's acceleration CSV"):
        load_drive(path.with_suffix(".toml"))
    with pytest.raises(ParameterError, match="expected at least one drive"):
        load_drives([])


def test_drives_on_different_grids_are_read(tmp_path):
    """Rate, speed and start may differ; common_time_grid tells the time-grid path from the distance path."""
    a = _write_drive(tmp_path, "drive1")
    b = _write_drive(tmp_path, "drive2", lines=_good_rows(fs=100.0))
    c = _write_drive(tmp_path, "drive3", speed=12.0)
    e = _write_drive(tmp_path, "drive4", start_m=5.0)
    drives = load_drives([a, b, c, e])
    assert [d.sample_rate for d in drives] == [200.0, 100.0, 200.0, 200.0]
    assert drives[2].speed == 12.0 and drives[3].start_m == 5.0 and drives[3].positions[0] == 5.0
    assert np.allclose(np.diff(drives[2].positions), 12.0 / 200.0)
    for other in (b, c, e):
        assert not common_time_grid(load_drives([a, other]))
    # A logger clock offset does not matter; a sample rate within 1e-6 relative is the same.
    f = _write_drive(tmp_path, "drive5", lines=_good_rows(t0=1234.5))
    g = _write_drive(tmp_path, "drive6", lines=_good_rows(fs=200.0 * (1 + 1e-8)))
    assert common_time_grid(load_drives([a, f, g]))


def test_small_drive_runs_end_to_end(tmp_path):
    """A short noise-only log: the command still writes everything (anomaly detection may be skipped)."""
    a = _write_drive(tmp_path, "drive1", lines=_good_rows(n=300))
    b = _write_drive(tmp_path, "drive2", lines=_good_rows(n=280), suffix=".json")
    summary = estimate_command([str(a), str(b)], tmp_path / "out", command="x")
    assert summary["n_samples"] == 280 and summary["truncated"]
    assert any("window-edge effects" in n for n in summary["notes"])
    for name in summary["files"]:
        assert (tmp_path / "out" / name).exists()


def test_command_writes_estimates_when_detection_cannot_run(tmp_path, monkeypatch):
    import roadcollab.experiments.drives.estimation as study   # the command imports it when it runs

    def refuse(est):
        raise ParameterError("window of 300 samples is shorter than the longest template")

    monkeypatch.setattr(study, "find_anomalies", refuse)
    a = _write_drive(tmp_path, "drive1", lines=_good_rows(n=300))
    summary = estimate_command([str(a)], tmp_path / "out", command="x")
    assert summary["n_anomalies"] is None
    assert any(n.startswith("Anomaly detection was not run") for n in summary["notes"])
    assert (tmp_path / "out" / "anomalies.csv").read_text().startswith("estimator,vehicle,position_m")


# --- elevation -----------------------------------------------------------------------------------

def test_elevation_is_exact_for_piecewise_constant_velocity():
    fs, A, f = 200.0, 0.02, 1.3
    w0 = 2 * np.pi * f
    t = np.arange(2001) / fs
    h = A * np.sin(w0 * t)                       # elevation at the sample instants
    v = np.diff(h)[:, None] * fs                 # piecewise-constant velocity between them
    got = integrate_elevation(np.hstack([v, -v]), fs)
    want = h[:-1] - h[:-1].mean()
    assert np.max(np.abs(got[:, 0] - want)) < 1e-15 * len(t)
    assert np.max(np.abs(got[:, 1] + want)) < 1e-15 * len(t)
    assert abs(got.mean()) < 1e-15


def test_elevation_of_a_cosine_is_a_sine():
    """v = A cos(w t) -> h = A / w sin(w t) (mean removed), to the rectangle rule's O(w dt)."""
    fs, A, f = 500.0, 0.3, 2.0
    w0 = 2 * np.pi * f
    t = np.arange(5000) / fs                     # 20 whole periods
    got = integrate_elevation((A * np.cos(w0 * t))[:, None], fs)[:, 0]
    want = A / w0 * np.sin(w0 * t)
    want -= want.mean()
    assert np.max(np.abs(got - want)) < (A / w0) * (w0 / fs)
    assert np.max(np.abs(got - want)) > 0  # (not trivially equal)


def test_elevation_of_constant_velocity_is_a_ramp():
    got = integrate_elevation(np.full((11, 2), 0.5), 10.0)
    ramp = 0.05 * np.arange(11)
    assert np.allclose(got, (ramp - ramp.mean())[:, None], atol=1e-15)


def test_bad_elevation_input():
    with pytest.raises(ParameterError):
        integrate_elevation(np.array([[np.nan, 0.0]]), 10.0)
    with pytest.raises(ParameterError):
        integrate_elevation(np.zeros((3, 2)), 0.0)


def test_toml_without_tomllib_is_a_clear_error(tmp_path, monkeypatch):
    """Python 3.10 has no tomllib: a TOML parameters file gets a clear error pointing to JSON."""
    path = _write_drive(tmp_path)
    monkeypatch.setitem(sys.modules, "tomllib", None)
    with pytest.raises(ParameterError, match="^" + re.escape(f"{path.with_suffix('.toml')}: reading TOML needs "
                                                             f"Python >= 3.11 (tomllib); write the parameters as "
                                                             f"JSON in {path.with_suffix('.json')}")):
        load_drive(path)
