"""Every numeric option of every command has a stated range, checked while parsing (issue 18, section 4).

The options are found by walking the parser, so an option added without a range fails
``test_every_valued_option_is_range_checked_or_listed``; each ranged option is then given values too
small, too large, NaN, infinite and not a number, through the real ``main`` in a subprocess-free
call: exit status 2, one line on stderr naming the option, no traceback, nothing computed.
"""

import argparse
import re
import subprocess
import sys
import time

import numpy as np
import pytest

from roadcollab.cli._arguments import Range, plural, ranged
from roadcollab.cli._table import fit_widths, print_table, split_columns, table_width
import roadcollab.cli.main as cli_main
from roadcollab.cli.main import build_parser, main

#: Options that take a value that is not a number (checked elsewhere: files, folders, addresses, names).
NOT_NUMERIC = {"--out", "--roads", "--map", "--kernels", "--fleet-id", "--drive", "--road-profile", "--road", "--network", "--store", "--tiles", "--fleet", "--id",
               "--broker", "--listen", "--scheduler", "--mechanism", "--iso-class", "--seeds", "--aggregation", "--tls-host"}
#: Options whose type checks a set that is not an interval (tested on their own below).
SPECIAL = {"--paillier-bits"}
NOT_NUMERIC |= {"--road-id"}   # enroll: a road of --network
NOT_NUMERIC |= {"--folder"}    # helper: the helper folder enroll writes
NOT_NUMERIC |= {"--guard-road"}   # estimate, vehicle: a choice of road prior
NOT_NUMERIC |= {"--reference-vehicle"}   # map: a vehicle_id (its pattern is checked by its type)


def _commands():
    """``(argv prefix, parser)`` of every leaf command (``message example`` included)."""
    top = build_parser()
    out = []
    for action in top._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, parser in action.choices.items():
                subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
                if subs:
                    out += [((name, sub), p) for a in subs for sub, p in a.choices.items()]
                else:
                    out.append(((name,), parser))
    return out


def _valued_options():
    """``(command, option, type)`` for every option that takes a value."""
    for prefix, parser in _commands():
        for action in parser._actions:
            if action.option_strings and action.nargs != 0 and not isinstance(action, argparse._HelpAction):
                yield prefix, action.option_strings[-1], action.type


def _bad_values(rng: Range):
    """Values just outside the range, far outside it, NaN, infinities and words."""
    step = 1 if rng.integer else max(abs(rng.low) * 0.5, 1e-3)
    yield "too small", repr(int(rng.low) - 1 if rng.integer else rng.low - step)
    yield "too large", repr(int(rng.high) + 1 if rng.integer else rng.high * 1.5 + 1)
    yield "far too large", "1e9" if rng.high < 1e9 else "1e30"
    yield "NaN", "nan"
    yield "inf", "inf"
    yield "-inf", "-inf"
    yield "not a number", "fast"
    if rng.integer:
        yield "fraction", f"{rng.low + 0.5}"


def _required(prefix, tmp_path):
    """The other arguments a command needs to reach the option under test."""
    extra = []
    if prefix[0] != "bench":
        extra += ["--out", str(tmp_path / "out.bin" if prefix[0] == "message" else tmp_path / "out")]
    if prefix[0] == "estimate":
        drive = tmp_path / "d.csv"
        drive.write_text("time_s,accel_left,accel_right\n")
        extra += ["--drive", str(drive)]
    return extra


CASES = [(prefix, option, label, value)
         for prefix, option, typ in _valued_options() if getattr(typ, "range", None) is not None
         for label, value in _bad_values(typ.range)]


@pytest.fixture
def no_run(monkeypatch):
    """A refused command line must never reach a command's ``run`` (nothing imported or computed)."""
    def run(args, command_line):
        raise AssertionError(f"{args.command} ran")
    monkeypatch.setattr(cli_main, "_RUN", {name: run for name in cli_main._RUN})


def _refused(capsys, argv):
    """Run ``main(argv)``: (exit status, stderr, seconds)."""
    t0 = time.perf_counter()
    with pytest.raises(SystemExit) as exc:
        main(argv)
    return exc.value.code, capsys.readouterr().err, time.perf_counter() - t0


def test_every_valued_option_is_range_checked_or_listed():
    unchecked = [(" ".join(prefix), option) for prefix, option, typ in _valued_options()
                 if getattr(typ, "range", None) is None and option not in NOT_NUMERIC | SPECIAL]
    assert unchecked == []
    assert len(CASES) > 200  # about 40 ranged options x 7-8 values: the walk found them


def test_every_range_is_in_the_help(capsys):
    for prefix, parser in _commands():
        text = " ".join(parser.format_help().split())
        for action in parser._actions:
            rng = getattr(action.type, "range", None)
            if rng is not None:
                assert rng.text() in text, (prefix, action.option_strings)


@pytest.mark.parametrize("prefix, option, label, value", CASES,
                         ids=[f"{' '.join(c[0])} {c[1]} {c[2]}" for c in CASES])
def test_out_of_range_values_are_one_line_naming_the_option(tmp_path, capsys, no_run, prefix, option, label, value):
    code, err, seconds = _refused(capsys, [*prefix, f"{option}={value}", *_required(prefix, tmp_path)])
    assert code == 2
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert f"argument {option}: expected " in err and "Traceback" not in err
    assert seconds < 5  # a guard against computing, not a speed target: run() is never called (fixture)
    assert not (tmp_path / "out").exists()  # nothing was started


def test_the_ranges_the_issue_found(tmp_path, capsys, no_run):
    out = str(tmp_path / "o")
    for argv, expected in [
        (["reproduce", "--speed", "0.01"], "argument --speed: expected a speed from 1 to 60 m/s, got 0.01"),
        (["reproduce", "--speed", "1000"], "argument --speed: expected a speed from 1 to 60 m/s, got 1000"),
        (["reproduce", "--speed", "1e9"], "argument --speed: expected a speed from 1 to 60 m/s, got 1e9"),
        (["attack", "--vehicles", "2"], "argument --vehicles: expected a fleet size from 3 to 1,000, got 2"),
        (["iri", "--segment-length", "0.01"], "argument --segment-length: expected a segment length from 1 to"),
    ]:
        code, err, _ = _refused(capsys, argv + ["--out", out])
        assert code == 2 and expected in err, err


def test_the_edges_of_a_range_are_accepted():
    speed = ranged("speed", 1, 60, "m/s")
    assert speed("1") == 1.0 and speed("60") == 60.0 and speed(" 15 ") == 15.0
    runs = ranged("number of runs", 1, 10, integer=True)
    assert runs("10") == 10 and isinstance(runs("3"), int)
    parsed = build_parser().parse_args(["reproduce", "--speed", "60", "--runs", "10000", "--noise", "0",
                                        "--uncertainty", "0.3", "--out", "o"])
    assert (parsed.speed, parsed.runs, parsed.noise, parsed.uncertainty) == (60.0, 10000, 0.0, 0.3)


def test_paillier_bits_and_iso_class(tmp_path, capsys, no_run):
    for value in ("100", "1000", "16384", "nan", "x"):
        code, err, _ = _refused(capsys, ["attack", "--paillier-bits", value, "--out", str(tmp_path)])
        assert code == 2 and "argument --paillier-bits: expected" in err and err.count("\n") == 1
    code, err, _ = _refused(capsys, ["reproduce", "--iso-class", "Z", "--out", str(tmp_path)])
    assert "argument --iso-class: expected an ISO 8608 roughness class A to H, got 'Z'" in err
    assert build_parser().parse_args(["reproduce", "--iso-class", "d", "--out", "o"]).iso_class == "D"


@pytest.mark.parametrize("argv, expected", [
    (["estimate", "--segment-length", "5", "--grid-step", "1"],
     "argument --segment-length: expected at least 10 times --grid-step (10 m), got 5 m"),
    (["estimate", "--max-offset", "0.15", "--grid-step", "0.1"],
     "argument --max-offset: expected at least 2 --grid-step (0.2 m) to search, got 0.15 m"),
    (["bench", "--scale", "5,10", "--check-segments", "6"],
     "argument --check-segments: expected at most the smallest --scale run (5), got 6"),
    (["sweep", "--gammas", "1,2,3,4,5,6,7,8", "--runs", "100"],
     "8 x 2 x 2 grid points x 100 runs = 3,200 runs, more than the 2,000 accepted"),
    (["calibrate-anomalies", "--seeds", "1-600", "601-1200"], "argument --seeds: expected at most 1000 seeds in all"),
    (["calibrate-anomalies", "--seeds", "1000-99999999999999"], "argument --seeds: expected at most 1000 seeds"),
    (["calibrate-anomalies", "--seeds", "5-3"], "argument --seeds: expected an ascending range a-b, got '5-3'"),
])
def test_options_that_depend_on_each_other_are_checked_after_parsing(tmp_path, capsys, no_run, argv, expected):
    code, err, seconds = _refused(capsys, argv + _required(argv[:1], tmp_path))
    assert code == 2 and expected in err and err.count("\n") == 1, err
    assert seconds < 5


def test_dependent_options_that_fit_pass():
    args = build_parser().parse_args(["estimate", "--drive", __file__, "--segment-length", "1", "--grid-step",
                                      "0.1", "--max-offset", "0.2", "--out", "o"])
    assert (args.segment_length, args.grid_step, args.max_offset) == (1.0, 0.1, 0.2)


def test_iri_segment_length_against_the_profiles_spacing(tmp_path, capsys):
    # The packaged profile is spaced 0.25 m: 2 m holds 8 samples, 2.5 m the 10 required.
    code = main(["iri", "--segment-length", "2", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and ("--segment-length: expected at least 10 times the profile's spacing of 0.25 m (2.5 m), "
                          "got 2 m") in err
    assert not (tmp_path / "o").exists()


def test_an_argument_error_is_one_line_from_the_installed_command(tmp_path):
    # The console script, not main(): what a user sees, with argparse's usage replaced by a pointer to --help.
    res = subprocess.run([sys.executable, "-m", "roadcollab.cli.main", "reproduce", "--speed", "0.01", "--out",
                          str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr == ("roadcollab reproduce: error: argument --speed: expected a speed from 1 to 60 m/s, got 0.01 "
                          "(see 'roadcollab reproduce --help')\n")


# --- plurals and tables --------------------------------------------------------------------------

def test_plural():
    assert [plural(n, "run") for n in (0, 1, 2, 1000)] == ["0 runs", "1 run", "2 runs", "1000 runs"]
    assert plural(1, "Dask worker") == "1 Dask worker" and plural(3, "vehicle") == "3 vehicles"


ATTACK_COLUMNS = ("mechanism", "attack", "road", "segments", "median rel. pole error", "success rate")
ATTACK_ROWS = [("hardened_secure_agg", "physical-fit replica", "measured", "20", "1.234e-05", "0.95"),
               ("paper", "structural", "synthetic", "2", "0.5", "1.00")]


def _lines(capsys, width, columns, rows):
    print_table("a title that is long enough to wrap on a narrow terminal, 1 run, 12.3 s", columns, rows,
                width=width)
    return capsys.readouterr().out.splitlines()


@pytest.mark.parametrize("width", [40, 60, 80, 100, 200])
def test_tables_fit_the_terminal_and_never_cut_a_number(capsys, width):
    rng = np.random.default_rng(0)
    columns = ("estimator",) + tuple(f"MSE vehicle {k} ((m/s)^2)" for k in range(1, 9))
    rows = [(name, *(f"{v:.3g}" for v in rng.lognormal(-12, 3, 8))) for name in ("observer", "Algorithm 1 (paper)",
                                                                              "fused", "centralized")]
    lines = _lines(capsys, width, columns, rows)
    assert max(len(line) for line in lines) <= width
    text = "\n".join(lines)
    for row in rows:
        for cell in row[1:]:
            assert re.search(rf"(?<![\w.+-]){re.escape(cell)}(?![\w.+-])", text), cell  # whole, on one line
    assert "…" not in text


def test_a_table_that_fits_is_one_part_and_a_wide_one_is_split(capsys):
    lines = _lines(capsys, 200, ATTACK_COLUMNS, ATTACK_ROWS)
    assert not any("part" in line for line in lines) and any("median rel. pole error" in line for line in lines)
    lines = _lines(capsys, 80, ATTACK_COLUMNS, ATTACK_ROWS)
    assert max(map(len, lines)) <= 80
    assert sum("(part" in line for line in lines) == 2
    # The first column is repeated in every part; every label appears whole.
    assert sum("hardened_secure_agg" in line for line in lines) == 2


def test_split_and_fit_widths():
    assert table_width([5, 5]) == 5 + 5 + 3 * 2 + 1
    assert split_columns([10, 10, 10], 80) == [[0, 1, 2]]
    assert split_columns([10, 30, 30, 30], 80) == [[0, 1, 2], [0, 3]]
    assert split_columns([10, 100], 80) == [[0, 1]]  # a column that cannot fit still prints, alone
    assert fit_widths([5, 5], [20, 8], 100) == [20, 8]
    w = fit_widths([5, 5], [40, 40], 40)
    assert table_width(w) == 40 and all(5 <= x <= 40 for x in w)


def test_piped_table_of_a_real_command_fits_80_columns(tmp_path):
    # rich takes 80 columns when stdout is a pipe; the MSE table of reproduce has 11 columns.
    res = subprocess.run([sys.executable, "-c", "from roadcollab.cli._table import print_table; "
                          "print_table('MSE per vehicle, 1 run, 0.1 s', ['estimator'] + [f'vehicle {k}' for k in "
                          "range(1, 11)], [['Algorithm 1 (paper)'] + ['1.23e-05'] * 10])"],
                         capture_output=True, text=True, timeout=60, env={"PATH": "/usr/bin:/bin", "TERM": "dumb"})
    assert res.returncode == 0, res.stderr
    assert max(map(len, res.stdout.splitlines())) <= 80 and res.stdout.count("1.23e-05") == 10


def test_range_messages_for_nan_and_words():
    speed = Range("speed", 1, 60, "m/s")
    with pytest.raises(argparse.ArgumentTypeError, match=r"expected a speed from 1 to 60 m/s, got nan$"):
        speed.parse("nan")
    with pytest.raises(argparse.ArgumentTypeError, match=r"got 'fast' \(not a number\)$"):
        speed.parse("fast")
    with pytest.raises(argparse.ArgumentTypeError, match=r"got '1.5' \(not a whole number\)$"):
        Range("number of runs", 1, 10, integer=True).parse("1.5")


def test_the_sweeps_default_grid_sizes_are_the_studys():
    from roadcollab.cli.sweep import DEFAULT_GRID_SIZES
    from roadcollab.experiments.sweep.config import SweepConfig

    cfg = SweepConfig()
    assert DEFAULT_GRID_SIZES == (len(cfg.gammas), len(cfg.sensor_noise_stds), len(cfg.parameter_uncertainties))
