"""Ctrl-C, SIGTERM and SIGKILL: one line, exit 130/143, previous results untouched, no process left behind."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from roadcollab.reporting.output_folder import MANIFEST

#: Long enough that the signal arrives mid-run (the runs alone take minutes).
RUN = ["reproduce", "--runs", "400", "--vehicles", "3"]


def _as_from_a_terminal() -> None:
    """Give the child the SIGINT disposition of a command typed in a terminal: a test runner started in the
    background (as CI may be) has SIGINT ignored, and Python keeps an ignored SIGINT ignored."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _previous_result(out: Path) -> dict:
    """A previous reproduce result as a run leaves it (manifest + files)."""
    out.mkdir()
    (out / "mse.csv").write_text("vehicle,mse\n1,0.5\n")
    (out / MANIFEST).write_text(json.dumps({"roadcollab": "0", "command": "reproduce", "files": ["mse.csv"]}))
    return {p.name: p.read_bytes() for p in out.iterdir()}


def _start(out: Path, extra=(), timeout: float = 180.0) -> tuple[subprocess.Popen, list[int]]:
    """Start a run and wait until it computes (its staging folder exists and, with workers, they run)."""
    env = dict(os.environ, COLUMNS="100")
    proc = subprocess.Popen([sys.executable, "-m", "roadcollab.cli.main", *RUN, *extra, "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=_as_from_a_terminal)
    want = 2 if "--workers" in extra else 0
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        staging = list(out.parent.glob(f".{out.name}.partial-*"))
        kids = psutil.Process(proc.pid).children(recursive=True) if proc.poll() is None else []
        if staging and len(kids) >= want and proc.poll() is None:
            time.sleep(1.0)  # well inside the runs
            return proc, [k.pid for k in psutil.Process(proc.pid).children(recursive=True)]
        if proc.poll() is not None:
            raise AssertionError(f"the run ended early: {proc.communicate()}")
        time.sleep(0.1)
    proc.kill()
    raise AssertionError("the run did not start computing in time")


def _gone_within(pids, seconds: float) -> float:
    """Seconds until every pid is gone (AssertionError after ``seconds``)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        alive = [p for p in pids if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]
        if not alive:
            return time.monotonic() - t0
        time.sleep(0.05)
    raise AssertionError(f"processes alive {seconds} s later: {alive}")


def _check_interrupted(tmp_path, sig, status, extra):
    out = tmp_path / "res"
    before = _previous_result(out)
    proc, kids = _start(out, extra)
    t0 = time.monotonic()
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == status, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip() and "%" not in ln and "━" not in ln]
    assert lines[-1] == f"roadcollab reproduce: interrupted; the previous results in {out} are untouched", stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    _gone_within(kids, max(0.0, 2.0 - (time.monotonic() - t0)) + 0.5)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert not list(tmp_path.glob(".res.partial-*"))


@pytest.mark.slow  # a signal to a process under load: serially with the other interrupt tests
def test_ctrl_c_serial(tmp_path):
    _check_interrupted(tmp_path, signal.SIGINT, 130, ())


@pytest.mark.slow
@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_interrupt_with_workers(tmp_path, sig, status):
    _check_interrupted(tmp_path, sig, status, ("--workers", "2"))


@pytest.mark.slow
def test_sigterm_serial(tmp_path):
    _check_interrupted(tmp_path, signal.SIGTERM, 143, ())


@pytest.mark.slow
def test_sigkill_leaves_no_worker_and_the_next_run_cleans_up(tmp_path):
    out = tmp_path / "res"
    before = _previous_result(out)
    proc, kids = _start(out, ("--workers", "2"))
    assert len(kids) >= 2
    proc.kill()
    proc.communicate(timeout=30)
    _gone_within(kids, 2.0)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert list(tmp_path.glob(".res.partial-*"))  # SIGKILL cannot clean up ...
    done = subprocess.run([sys.executable, "-m", "roadcollab.cli.main", "reproduce", "--runs", "1", "--vehicles", "2",
                           "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert not list(tmp_path.glob(".res.partial-*"))  # ... the next run into the same place does
    assert "mse.csv" in json.loads((out / MANIFEST).read_text())["files"]


def _raised_in_a_callback(interrupt: BaseException):
    """What a kernel's caller sees when the signal's handler ran inside numba's boxing callback (measured
    with SIGTERM during ``reproduce``): SystemErrors raised from the interrupt."""
    def run(args, command_line):
        try:
            try:
                raise interrupt
            except BaseException as err:
                raise SystemError("<function _numba_unpickle> returned a result with an exception set") from err
        except SystemError as err:
            raise SystemError("CPUDispatcher(<function _block_form>) returned a result with an exception set") from err
    return run


@pytest.mark.parametrize("interrupt, status", [(KeyboardInterrupt(), 130), ("terminated", 143)])
def test_an_interrupt_inside_a_compiled_kernels_callback_is_still_an_interrupt(tmp_path, monkeypatch, capsys,
                                                                               interrupt, status):
    from roadcollab.cli import main as cli

    interrupt = cli.Terminated() if interrupt == "terminated" else interrupt
    monkeypatch.setitem(cli._RUN, "reproduce", _raised_in_a_callback(interrupt))
    out = tmp_path / "res"
    assert cli.main(["reproduce", "--kernels", "reference", "--out", str(out)]) == status
    assert capsys.readouterr().err.strip() == f"roadcollab reproduce: interrupted; nothing was written to {out}"


def test_a_system_error_without_an_interrupt_is_not_taken_for_one(tmp_path, monkeypatch):
    from roadcollab.cli import main as cli

    monkeypatch.setitem(cli._RUN, "reproduce", _raised_in_a_callback(RuntimeError("a kernel failed")))
    with pytest.raises(SystemError):
        cli.main(["reproduce", "--kernels", "reference", "--out", str(tmp_path / "res")])
