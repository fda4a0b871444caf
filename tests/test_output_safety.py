"""No command ever touches a file it did not write (README "Output folders")."""

import hashlib
import json
import os
import time
from pathlib import Path

import pytest

from roadcollab.cli.main import main
from roadcollab.reporting.output_folder import MANIFEST, STAGING_MARK

#: Every command that writes, with the smallest arguments that would run it (bench writes nothing).
COMMANDS = {
    "reproduce": ["reproduce", "--runs", "1", "--vehicles", "2"],
    "attack": ["attack", "--runs", "2"],
    "anomalies": ["anomalies", "--runs", "1", "--vehicles", "3", "--no-sweeps"],
    "calibrate-anomalies": ["calibrate-anomalies", "--seeds", "1000", "--runs-per-seed", "1"],
    "sweep": ["sweep", "--runs", "1"],
    "iri": ["iri"],
    "estimate": ["estimate", "--drive", "{drive}"],
    "simulate-drives": ["simulate-drives"],
    "map": ["map", "--drive", "{drive}", "--store", "{store}"],
    "export": ["export", "--store", "{store}"],
}


def _user_folder(root: Path) -> tuple[Path, Path]:
    """A folder as a user has it: a thesis, notes and the drives being read."""
    home = root / "myproject"
    (home / "drives").mkdir(parents=True)
    (home / "thesis.tex").write_text("\\documentclass{article} years of work\n")
    (home / "notes.md").write_text("notes\n")
    drive = home / "drives" / "d.csv"
    drive.write_text("time_s,accel_left,accel_right\n0,0,0\n0.005,0,0\n")
    (home / "drives" / "d.toml").write_text("speed_mps = 15\n")
    return home, drive


def _snapshot(folder: Path) -> dict:
    return {str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir")
            for p in sorted(folder.rglob("*"))}


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_no_command_touches_a_users_folder(name, tmp_path, monkeypatch, capsys):
    home, drive = _user_folder(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    before = _snapshot(tmp_path)
    args = [a.format(drive=drive, store=tmp_path / "elsewhere" / "road.sqlite") for a in COMMANDS[name]]
    cases = [(elsewhere, str(home)), (elsewhere, str(home / "drives")), (elsewhere, str(tmp_path)),
             (home / "drives", "."), (home / "drives", ".."), (home, "drives")]
    for cwd, out in cases:
        monkeypatch.chdir(cwd)
        t0 = time.perf_counter()
        code = main(args + ["--out", out])
        elapsed = time.perf_counter() - t0
        err = capsys.readouterr().err.strip()
        assert code == 2, (name, out, err)
        assert len(err.splitlines()) == 1 and "--out" in err and "Traceback" not in err, err
        assert elapsed < 1.0, (name, out, elapsed)  # refused before any compute (milliseconds in practice)
    with pytest.raises(SystemExit) as exc:
        main(args + ["--out", ""])
    assert exc.value.code == 2 and "--out" in capsys.readouterr().err.strip().splitlines()[-1]
    assert _snapshot(tmp_path) == before


def test_message_example_never_replaces_a_foreign_file(tmp_path, capsys):
    thesis = tmp_path / "thesis.tex"
    thesis.write_text("mine")
    assert main(["message", "example", "--out", str(thesis)]) == 2
    assert thesis.read_text() == "mine"
    assert "was not written by roadcollab" in capsys.readouterr().err
    msg = tmp_path / "m.bin"
    assert main(["message", "example", "--out", str(msg)]) == 0
    assert main(["message", "example", "--out", str(msg), "--seed", "4"]) == 0  # its own earlier output: fine


def test_previous_result_is_replaced_but_a_users_file_in_it_is_kept(tmp_path, capsys):
    out = tmp_path / "iri"
    assert main(["iri", "--out", str(out)]) == 0
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["command"] == "iri" and "iri.csv" in manifest["files"] and "config.json" in manifest["files"]
    (out / "my_comments.txt").write_text("keep me")
    (out / "iri.csv").write_text("stale")
    assert main(["iri", "--out", str(out), "--segment-length", "50"]) == 0
    assert (out / "my_comments.txt").read_text() == "keep me"
    assert (out / "iri.csv").read_text() != "stale"
    # A result of another command is not this command's to replace.
    capsys.readouterr()
    assert main(["reproduce", "--runs", "1", "--out", str(out)]) == 2
    assert "holds the results of 'roadcollab iri'" in capsys.readouterr().err


def test_empty_folder_is_used_and_kept(tmp_path):
    out = tmp_path / "empty"
    out.mkdir()
    assert main(["iri", "--out", str(out)]) == 0
    assert (out / "iri.csv").is_file()


def test_leftover_staging_folders(tmp_path):
    """A killed run's staging folder (our mark, a dead pid) goes; anything else beside --out stays."""
    out = tmp_path / "res"
    dead = tmp_path / ".res.partial-killed"
    dead.mkdir()
    (dead / STAGING_MARK).write_text(json.dumps({"pid": 2 ** 22 + 12345}))  # above pid_max's default: not alive
    alive = tmp_path / ".res.partial-running"
    alive.mkdir()
    (alive / STAGING_MARK).write_text(json.dumps({"pid": os.getpid()}))
    foreign = tmp_path / ".res.partial-users"
    foreign.mkdir()
    (foreign / "x.txt").write_text("not ours")
    assert main(["iri", "--out", str(out)]) == 0
    assert not dead.exists() and alive.exists() and (foreign / "x.txt").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([".res.partial-running", ".res.partial-users", "res"])


def test_failed_run_leaves_previous_results_and_no_staging(tmp_path):
    out = tmp_path / "iri"
    assert main(["iri", "--out", str(out)]) == 0
    before = _snapshot(out)
    bad = tmp_path / "bad.txt"
    bad.write_text("not a profile\n")
    assert main(["iri", "--out", str(out), "--road-profile", str(bad)]) == 2
    assert _snapshot(out) == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_out_that_is_an_input_or_holds_one(tmp_path, capsys):
    prof = tmp_path / "p" / "profile.txt"
    prof.parent.mkdir()
    prof.write_text("0 0\n")
    for out in (prof.parent, tmp_path):
        assert main(["iri", "--road-profile", str(prof), "--out", str(out)]) == 2
        assert "holds the input" in capsys.readouterr().err
