"""Hostile input files: every class gets one clear error naming the file, and nothing else escapes.

The corpus is generated in tmp_path (no committed binaries); the 2.5 GB file is a sparse file.
"""

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from roadcollab import FileFormatError, ParameterError
from roadcollab.cli.main import build_parser, main
from roadcollab.reporting.output_folder import MANIFEST
from roadcollab.io.drive_params import write_drive_params
from roadcollab.io.drives import load_drive, read_drive_csv
from roadcollab.io.limits import FileLimits
from roadcollab.io.profiles import load_profile
from roadcollab.models.vehicle import HalfCarParameters

PARAMS = HalfCarParameters(700.0, 500.0, 0.7, 0.8, 20000.0, 1500.0)
HEADER = "time_s,accel_left,accel_right"


def _rows(n=100, fs=200.0):
    rng = np.random.default_rng(0)
    return [f"{k / fs!r},{float(a)!r},{float(b)!r}" for k, (a, b) in enumerate(rng.standard_normal((n, 2)))]


def _drive(d: Path, rows=None, params=None, suffix=".toml") -> Path:
    csv_path = d / "drive.csv"
    csv_path.write_text("\n".join([HEADER] + (_rows() if rows is None else rows)) + "\n")
    if params is None:
        write_drive_params(d / "drive.toml", speed=15.0, params=PARAMS)
    else:
        (d / f"drive{suffix}").write_text(params)
    return csv_path


def _with_row(k, text):
    rows = _rows()
    rows[k] = text
    return rows


def _toml(top="speed_mps = 15.0", **veh):
    vals = {**PARAMS.as_dict(), **veh}
    return top + "\n\n[vehicle]\n" + "\n".join(f"{k} = {v}" for k, v in vals.items()) + "\n"


def _json(**top):
    return json.dumps({"speed_mps": 15.0, "vehicle": PARAMS.as_dict(), **top})


VEH_JSON = json.dumps(PARAMS.as_dict())[1:-1]

# (rows, params text, params suffix, the file the error must start with, pattern after it)
CSV_CLASSES = {
    "glitch sample": (_with_row(20, "0.1,1e150,0.2"), "csv", r" line 22: column 2 \(accel_left\): expected an "
                                                            r"acceleration within \+-200 m/s\^2"),
    "just above the glitch bound": (_with_row(20, "0.1,0.2,-200.5"), "csv", r" line 22: column 3"),
    "NaN": (_with_row(5, "0.025,nan,0.2"), "csv", r" line 7: .*expected a finite number, got 'nan'"),
    "inf": (_with_row(5, "0.025,0.1,inf"), "csv", r" line 7: .*expected a finite number, got 'inf'"),
    "overflow": (_with_row(5, "0.025,1e400,0.2"), "csv", r" line 7: .*expected a finite number, got '1e400'"),
    "Arabic-Indic digits": (_with_row(5, "0.025,\u0660.\u0661,0.2"), "csv", r" line 7: column 2 .*ASCII digits"),
    "full-width digits": (_with_row(5, "0.025,\uff11,0.2"), "csv", r" line 7: column 2 .*ASCII digits"),
    "underscore digits": (_with_row(5, "0.025,1_0,0.2"), "csv", r" line 7: column 2 .*ASCII digits"),
    "1e-9 s time step": ([f"{k * 1e-9!r},0.1,0.2" for k in range(100)], "csv",
                         r": expected a sample rate of at most 10000 Hz .* got 1e\+09 Hz"),
    "huge field": (_with_row(5, "0.025," + "9" * 100000 + ",0.2"), "csv", r" line 7: column 2 .*\(100002 characters\)"),
}
PARAM_CLASSES = {
    "deeply nested JSON": ('{"speed_mps": ' + "[" * 100000 + "]" * 100000 + "}", ".json",
                           r": expected a flat JSON object, got arrays or objects nested too deeply"),
    "deeply nested TOML": ("speed_mps = " + "[" * 100000 + "]" * 100000 + "\n", ".toml",
                           r": expected a flat TOML file"),
    "moderately nested JSON": ('{"speed_mps": ' + "[" * 500 + "]" * 500 + ', "vehicle": {}}', ".json",
                               r": key 'speed_mps' must be a number \(m/s\), got \[\[\[.*characters\)"),
    "400-digit integer JSON": ('{"speed_mps": 1' + "0" * 400 + ', "vehicle": {' + VEH_JSON + "}}", ".json",
                               r": key 'speed_mps' must lie in \[0.5, 70\] m/s, got an integer of 401 digits"),
    "400-digit integer TOML": (_toml(top="speed_mps = 1" + "0" * 400), ".toml", r": key 'speed_mps' .* 401 digits"),
    "5000-digit integer JSON": ('{"speed_mps": 1' + "0" * 5000 + "}", ".json", r": expected numbers of at most"),
    "sensor_noise_std 1e300": (_toml(top="speed_mps = 15.0\nsensor_noise_std = 1e300"), ".toml",
                               r": key 'sensor_noise_std' must lie in \[0, 20\] m/s\^2 .*got 1e\+300"),
    "duplicate JSON key": ('{"speed_mps": 15.0, "speed_mps": 1e9, "vehicle": {' + VEH_JSON + "}}", ".json",
                           r": duplicate key 'speed_mps'"),
    "duplicate JSON vehicle key": ('{"speed_mps": 15.0, "vehicle": {' + VEH_JSON + ', "damping": 1.0}}', ".json",
                                   r": duplicate key 'damping'"),
    "duplicate TOML key": (_toml(top="speed_mps = 15.0\nspeed_mps = 16.0"), ".toml", r": expected valid TOML"),
    "speed 1e9": (_toml(top="speed_mps = 1e9"), ".toml", r": key 'speed_mps' must lie in \[0.5, 70\] m/s"),
    "speed 1e-300": (_toml(top="speed_mps = 1e-300"), ".toml", r": key 'speed_mps' must lie in \[0.5, 70\]"),
    "speed 0.4": (_toml(top="speed_mps = 0.4"), ".toml", r": key 'speed_mps' must lie in \[0.5, 70\]"),
    "TOML nan": (_toml(top="speed_mps = nan"), ".toml", r": key 'speed_mps' must be a finite number"),
    "JSON Infinity": (_json(sensor_noise_std=float("inf")), ".json", r": key 'sensor_noise_std' must be a finite"),
    "Arabic-Indic digits JSON": ('{"speed_mps": \u0661\u0665}', ".json", r" line 1: expected valid JSON"),
    "full-width digits TOML": ("speed_mps = \uff11\uff15\n", ".toml", r": expected valid TOML"),
    "sprung mass 1e-6 (singular model)": (_toml(sprung_mass=1e-6), ".toml",
                                          r": key 'vehicle.sprung_mass' must lie in \[100, 20000\] kg"),
    "roll inertia 1e-9": (_toml(roll_inertia=1e-9), ".toml", r": key 'vehicle.roll_inertia' must lie in \[10, "),
    "damping 1e12": (_toml(damping=1e12), ".toml", r": key 'vehicle.damping' must lie in \[50, 100000\] N s/m"),
    "arm 1e-9": (_toml(left_arm=1e-9), ".toml", r": key 'vehicle.left_arm' must lie in \[0.2, 2\] m"),
    "parameters file of 2 MB": ("# " + "x" * 2_000_000 + "\n" + _toml(), ".toml", r": parameters file is 2 MB, larger"),
}


@pytest.mark.parametrize("case", list(CSV_CLASSES))
def test_hostile_csv_names_the_file_and_line(tmp_path, case):
    rows, _, pattern = CSV_CLASSES[case]
    path = _drive(tmp_path, rows=rows)
    with pytest.raises(FileFormatError, match="^" + re.escape(str(path)) + pattern):
        load_drive(path)


@pytest.mark.parametrize("case", list(PARAM_CLASSES))
def test_hostile_parameters_name_the_file_and_key(tmp_path, case):
    text, suffix, pattern = PARAM_CLASSES[case]
    path = _drive(tmp_path, params=text, suffix=suffix)
    with pytest.raises(FileFormatError, match="^" + re.escape(str(path.with_suffix(suffix))) + pattern) as info:
        load_drive(path)
    assert "\n" not in str(info.value) and len(str(info.value)) < 600


def test_huge_file_is_refused_by_size_before_reading(tmp_path):
    path = _drive(tmp_path)
    os.truncate(path, 2_500_000_000)  # sparse: no disk space, no reading
    t0 = time.perf_counter()
    with pytest.raises(FileFormatError, match="^" + re.escape(f"{path}: drive CSV is 2500 MB, larger than the limit "
                                                               "of 200 MB; raise the limit with --max-file-mb")):
        read_drive_csv(path)
    assert time.perf_counter() - t0 < 0.5
    prof = tmp_path / "profile.txt"
    prof.write_text("0 0\n")
    os.truncate(prof, 2_500_000_000)
    with pytest.raises(FileFormatError, match=re.escape(f"{prof}: profile file is 2500 MB")):
        load_profile(prof)


def test_row_limit_stops_reading_and_can_be_raised(tmp_path):
    path = _drive(tmp_path, rows=_rows(n=120))
    with pytest.raises(FileFormatError, match=re.escape(f"{path} line 102: more than 100 data rows; raise the limit "
                                                        "with --max-rows")):
        read_drive_csv(path, limits=FileLimits(max_rows=100))
    assert read_drive_csv(path, limits=FileLimits(max_rows=120))[0].shape == (120,)
    assert FileLimits().max_rows == 2_000_000  # 10 M rows are refused by default
    with pytest.raises(ParameterError, match="max_rows must be >= 1"):
        FileLimits(max_rows=0)


PROFILE_CLASSES = {
    "Arabic-Indic digits": ("1.0 \u0660.\u0661", r"line 2: expected 2 numbers .* written with ASCII digits"),
    "glitch elevation": ("1.0 1e150", r"line 2: expected an elevation within \+-10000 m"),
    "far distance": ("1e300 0.0", r"line 2: expected a distance within \+-1e\+07 m"),
    "overflow": ("1.0 1e999", r"line 2: expected finite numbers"),
}


@pytest.mark.parametrize("case", list(PROFILE_CLASSES))
def test_hostile_profiles_name_the_file_and_line(tmp_path, case):
    line, pattern = PROFILE_CLASSES[case]
    path = tmp_path / "p.txt"
    path.write_text("0.0 0.0\n" + line + "\n" + "".join(f"{k}.0 0.0\n" for k in range(2, 12)))
    with pytest.raises(FileFormatError, match="^" + re.escape(str(path)) + ": " + pattern):
        load_profile(path)


def test_profile_spacing_must_be_physical(tmp_path):
    path = tmp_path / "p.txt"
    path.write_text("".join(f"{k * 1e-9!r} 0.0\n" for k in range(10)))
    with pytest.raises(FileFormatError, match=re.escape(f"{path}: expected a distance step between 0.0001 and 1 m")):
        load_profile(path)


def _cli(capsys, argv):
    code = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.count("\n") <= 1, err
    return code, err.strip()


def test_cli_prints_one_line_naming_the_file(tmp_path, capsys):
    path = _drive(tmp_path, params=_toml(top="speed_mps = 1e9"))
    code, err = _cli(capsys, ["estimate", "--drive", str(path), "--out", str(tmp_path / "out")])
    assert code == 2 and err.startswith(f"roadcollab estimate: error: {path.with_suffix('.toml')}: key 'speed_mps'")
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.*"))


def test_short_profile_says_its_length_and_the_minimum(tmp_path, capsys):
    path = tmp_path / "short.txt"
    path.write_text("".join(f"{0.01 * k:.2f} 0.0\n" for k in range(1001)))  # 10 m, like the Belgian block
    code, err = _cli(capsys, ["reproduce", "--runs", "1", "--road-profile", str(path), "--out", str(tmp_path / "o")])
    assert code == 2 and f"{path}: the profile covers 10 m; a simulated run needs at least 51 m" in err
    path.write_text("".join(f"{k}.0 0.0\n" for k in range(3)))
    code, err = _cli(capsys, ["anomalies", "--runs", "1", "--road-profile", str(path), "--max-rows", "2",
                              "--out", str(tmp_path / "o")])
    assert code == 2 and f"{path}: line 3: more than 2 data rows" in err


def test_bad_out_fails_fast_without_a_traceback(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for argv in (["reproduce", "--runs", "100", "--out", str(blocker)],
                 ["reproduce", "--runs", "100", "--out", str(blocker / "sub")],
                 ["message", "example", "--out", str(blocker / "msg.bin")],
                 ["message", "example", "--out", str(tmp_path)]):
        t0 = time.perf_counter()
        code, err = _cli(capsys, argv)
        assert code == 2 and f"error: --out {argv[-1]}" in err and time.perf_counter() - t0 < 1.0, err


def test_failed_or_interrupted_run_leaves_previous_results(tmp_path, capsys, monkeypatch):
    good = tmp_path / "good"
    good.mkdir()
    path = _drive(good)
    out = tmp_path / "out"
    out.mkdir()
    (out / "report.md").write_text("previous")
    (out / MANIFEST).write_text(json.dumps({"command": "estimate", "files": ["report.md"]}))  # an earlier result
    bad = _drive(tmp_path, rows=_with_row(3, "0.015,nan,0"))
    assert _cli(capsys, ["estimate", "--drive", str(bad), "--out", str(out)])[0] == 2
    import roadcollab.reporting.drives_report as report   # the command imports it when it runs

    def killed(*args, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "write_estimates", killed)
    assert main(["estimate", "--drive", str(path), "--out", str(out)]) == 130  # Ctrl-C: one line, status 130
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "report.md"]
    assert (out / "report.md").read_text() == "previous"
    assert not list(tmp_path.glob(".out.*"))


def test_options_are_checked_before_compute(tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["attack", "--paillier-bits", "100", "--out", str(tmp_path / "a")])
    assert "expected a key size from 512 to 8192 bits" in capsys.readouterr().err
    code, err = _cli(capsys, ["attack", "--scheduler", "not an address", "--out", str(tmp_path / "a")])
    assert code == 2 and "--scheduler must be an address such as tcp://host:8786" in err


@pytest.mark.parametrize("command", ["reproduce", "attack", "anomalies", "calibrate-anomalies", "sweep", "bench",
                                     "estimate"])
def test_help_says_what_it_does_writes_and_an_example(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = capsys.readouterr().out
    assert "Writes:" in text and f"example:\n  roadcollab {command}" in text


# --- files that are not regular files (issue 18, section 4) ---------------------------------------

def _not_regular(tmp_path: Path, kind: str) -> tuple[Path, str]:
    """A path of ``kind`` and the message the readers must give for it."""
    path = tmp_path / f"{kind.replace(' ', '_')}.csv"
    if kind == "folder":
        path.mkdir()
        return path, "to be a regular file, got a folder"
    if kind == "FIFO":
        os.mkfifo(path)
        return path, "to be a regular file, got a named pipe (FIFO)"
    if kind == "device":
        return Path("/dev/zero"), "to be a regular file, got a device"
    if kind == "symlink loop":
        path.symlink_to(tmp_path / "loop_b")
        (tmp_path / "loop_b").symlink_to(path)
        return path, "is a symlink loop"
    if kind == "dangling symlink":
        path.symlink_to(tmp_path / "gone.csv")
        return path, f"is a dangling symlink (its target {tmp_path / 'gone.csv'} does not exist)"
    if kind == "missing":
        return path, "not found (expected an existing file)"
    raise AssertionError(kind)


NOT_REGULAR = ["folder", "FIFO", "device", "symlink loop", "dangling symlink", "missing"]
#: Every file option of the command line, with what it calls the file.
FILE_OPTIONS = [
    (["estimate", "--out", "{out}", "--drive"], "--drive", "drive CSV"),
    (["reproduce", "--runs", "1", "--out", "{out}", "--road-profile"], "--road-profile", "profile file"),
    (["anomalies", "--runs", "1", "--out", "{out}", "--road-profile"], "--road-profile", "profile file"),
    (["iri", "--out", "{out}", "--road-profile"], "--road-profile", "profile file"),
]


@pytest.mark.parametrize("kind", NOT_REGULAR)
@pytest.mark.parametrize("argv, option, what", FILE_OPTIONS, ids=[" ".join(f[0][:1]) + " " + f[1] for f in FILE_OPTIONS])
def test_file_options_name_the_kind_of_non_regular_file(tmp_path, kind, argv, option, what):
    # A subprocess with a timeout: a reader that opened the FIFO would block forever (no writer comes).
    path, message = _not_regular(tmp_path, kind)
    args = [a.format(out=tmp_path / "out") for a in argv] + [str(path)]
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "roadcollab.cli.main", *args], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 2 and "Traceback" not in res.stderr and res.stderr.count("\n") == 1, res.stderr
    assert f"error: argument {option}: {path}: " in res.stderr and message in res.stderr
    assert (what in res.stderr) and time.perf_counter() - t0 < 30
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kind", NOT_REGULAR)
def test_readers_name_the_kind_of_non_regular_file(tmp_path, kind):
    path, message = _not_regular(tmp_path, kind)
    for read, what in ((read_drive_csv, "drive CSV"), (load_profile, "profile file")):
        with pytest.raises(FileFormatError, match="^" + re.escape(f"{path}: ") + ".*" + re.escape(message)) as info:
            read(path)
        assert what in str(info.value) and "\n" not in str(info.value)


def test_unreadable_file_says_permission_denied(tmp_path, monkeypatch):
    path = tmp_path / "p.txt"
    path.write_text("".join(f"{k}.0 0.0\n" for k in range(12)))
    if os.geteuid() != 0:  # root reads anything: then the check is exercised through os.access below
        path.chmod(0)
        with pytest.raises(FileFormatError, match=re.escape(f"{path}: cannot read profile file: permission denied")):
            load_profile(path)
        path.chmod(0o644)
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False)
    with pytest.raises(FileFormatError, match=re.escape(f"{path}: cannot read profile file: permission denied")):
        load_profile(path)


def test_a_file_below_a_file_is_not_found_with_the_reason(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(FileFormatError, match=re.escape("not found (a folder in its path is a file)")):
        load_profile(tmp_path / "f" / "p.txt")


# --- what iri reads: what the other commands read (issue 18, section 4) -----------------------------

def _packaged_rows():
    from roadcollab.io.profiles import packaged_profile_path

    prof = load_profile(packaged_profile_path())
    return prof.distance.tolist(), prof.elevation.tolist()


def _iri_csv(path: Path) -> np.ndarray:
    return np.loadtxt(path / "iri.csv", delimiter=",", skiprows=1, ndmin=2)


def test_iri_reads_a_profile_with_a_bom_and_a_header(tmp_path, capsys):
    d, z = _packaged_rows()
    plain = tmp_path / "plain.txt"
    plain.write_text("".join(f"{a!r} {b!r}\n" for a, b in zip(d, z)))
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + ("distance_m,elevation_m\n" + "".join(f"{a!r},{b!r}\n" for a, b in zip(d, z))
                                       ).encode())
    assert main(["iri", "--road-profile", str(plain), "--out", str(tmp_path / "a")]) == 0
    assert main(["iri", "--road-profile", str(bom), "--out", str(tmp_path / "b")]) == 0
    capsys.readouterr()
    np.testing.assert_array_equal(_iri_csv(tmp_path / "a"), _iri_csv(tmp_path / "b"))


def test_iri_of_a_two_track_profile_is_per_track(tmp_path, capsys):
    # Oracles: each track's IRI is the one-track IRI of that track alone, and the IRI is homogeneous
    # (the Golden Car is linear and the rectified slope is |.|): a right track of 2 x left has twice its IRI.
    d, z = _packaged_rows()
    two = tmp_path / "two.txt"
    two.write_text("# distance_m left_m right_m\n" + "".join(f"{a!r} {b!r} {2 * b!r}\n" for a, b in zip(d, z)))
    one = tmp_path / "one.txt"
    one.write_text("".join(f"{a!r} {b!r}\n" for a, b in zip(d, z)))
    assert main(["iri", "--road-profile", str(two), "--out", str(tmp_path / "two")]) == 0
    assert main(["iri", "--road-profile", str(one), "--out", str(tmp_path / "one")]) == 0
    assert "IRI over 5 segments of 100 m" in capsys.readouterr().out
    two_iri, one_iri = _iri_csv(tmp_path / "two"), _iri_csv(tmp_path / "one")
    np.testing.assert_array_equal(two_iri[:, 2], one_iri[:, 2])
    np.testing.assert_allclose(two_iri[:, 3], 2 * one_iri[:, 2], rtol=1e-12)
    assert "two tracks (left, right)" in (tmp_path / "two" / "report.md").read_text()


def test_two_track_profile_drives_its_own_right_track(tmp_path):
    from roadcollab.io.profiles import measured_road

    d, z = _packaged_rows()
    right = z[::-1]
    path = tmp_path / "two.csv"
    path.write_text("distance_m, left_m, right_m\n" + "".join(f"{a!r}, {b!r}, {c!r}\n" for a, b, c in zip(d, z, right)))
    prof = load_profile(path)
    assert prof.tracks == 2 and prof.elevation.shape == (len(d), 2)
    road = measured_road(path, detrend=False, enveloping_length=0.0, rng=0)
    np.testing.assert_array_equal(road.elevation[:, 0], z)
    np.testing.assert_array_equal(road.elevation[:, 1], right)
    with pytest.raises(ParameterError, match="second_track 'measured' needs a two-track profile"):
        measured_road(None, second_track="measured", rng=0)


@pytest.mark.parametrize("text, pattern", [
    ("0 0 0\n1 0\n", r"line 2: expected 3 numbers 'distance_m left_m right_m', got '1 0' \(every row has the 3 "),
    ("distance_m,left_m,right_m\n0,0\n", r"line 2: expected 3 numbers 'distance_m left_m right_m'"),
    ("0 0\n1 0 0\n", r"line 2: expected 2 numbers 'distance_m elevation_m', got '1 0 0'"),
    ("0 0\ndistance_m elevation_m\n", r"line 2: expected 2 numbers"),   # a header only before the data
    ("0 0 0 0\n", r"line 1: expected 2 numbers 'distance_m elevation_m' or 3 'distance_m left_m right_m'"),
])
def test_profile_columns_are_consistent(tmp_path, text, pattern):
    path = tmp_path / "p.txt"
    path.write_text(text)
    with pytest.raises(FileFormatError, match="^" + re.escape(str(path)) + ": " + pattern):
        load_profile(path)


def test_iri_advice_names_its_own_flags(tmp_path, capsys):
    d, z = _packaged_rows()
    path = tmp_path / "p.txt"
    path.write_text("".join(f"{a!r} {b!r}\n" for a, b in zip(d, z)))
    code, err = _cli(capsys, ["iri", "--road-profile", str(path), "--max-rows", "100", "--out", str(tmp_path / "o")])
    assert code == 2 and "raise the limit with --max-rows" in err
    code, err = _cli(capsys, ["iri", "--road-profile", str(path), "--max-file-mb", "0.01", "--out", str(tmp_path / "o")])
    assert code == 2 and "raise the limit with --max-file-mb" in err
    parser_help = " ".join(build_parser()._subparsers._group_actions[0].choices["iri"].format_help().split())
    for flag in re.findall(r"raise the limit with (--[a-z-]+)", err + " --max-rows"):
        assert flag in parser_help
    # And the raised limit works.
    assert main(["iri", "--road-profile", str(path), "--max-rows", str(len(d)), "--out", str(tmp_path / "o")]) == 0
