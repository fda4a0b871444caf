"""Helpers of the networked-fleet tests: drive files, free loopback ports, brokers and CLI processes.

Every process started here listens on 127.0.0.1 only and is stopped by the fixture that started it
(by its own pid); every wait is bounded. On Linux a process started here also gets SIGTERM when the test
process that started it dies (``PR_SET_PDEATHSIG``), so a test run killed by hand leaves no server behind
(Mosquitto drops its privileges, which clears that signal: its fixture's ``atexit`` still stops it on a
normal exit).
"""

from __future__ import annotations

import atexit
import csv
import ctypes
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from roadcollab.experiments.drives.mixed_fleet import MIXED_SPEEDS, simulate_drive
from roadcollab.io.drive_params import write_drive_params
from roadcollab.io.drives import write_drive_csv
from roadcollab.io.profiles import measured_road
from roadcollab.models.vehicle import FleetSpec, sample_fleet

PY = sys.executable
HAVE_MOSQUITTO = shutil.which("mosquitto") is not None or Path("/usr/sbin/mosquitto").exists()
MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


def write_drives(folder: Path, speeds=MIXED_SPEEDS, *, seed: int = 0) -> tuple[list[str], float]:
    """Drives at ``speeds`` over the measured profile as CSV + TOML; their paths and slowest speed."""
    road = measured_road(rng=seed + 1)
    fleet = sample_fleet(len(speeds), FleetSpec(), rng=seed + 2)
    folder.mkdir(parents=True, exist_ok=True)
    paths, vmin = [], np.inf
    for j, sp in enumerate(speeds):
        d = simulate_drive(road, fleet[j], sp, start=5.0 + 2.0 * j, rng=seed + 10 + j)
        p = folder / f"d{j + 1}.csv"
        if isinstance(sp, tuple):
            write_drive_csv(p, d.time, d.accel, column="distance_m", values=d.positions)
            write_drive_params(p.with_suffix(".toml"), speed=None, params=d.params, start_m=float(d.positions[0]))
        else:
            write_drive_csv(p, d.time, d.accel)
            write_drive_params(p.with_suffix(".toml"), speed=d.speed, params=d.params, start_m=d.start_m)
        paths.append(str(p))
    return paths, vmin


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_port(port: int, timeout: float = 30.0, proc: subprocess.Popen | None = None) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"process exited with {proc.returncode} before listening on {port}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.1)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {timeout} s")


def rc(*args, timeout: float = 300.0, check: bool = True) -> subprocess.CompletedProcess:
    """Run ``roadcollab ARGS`` to completion."""
    p = subprocess.run([PY, "-m", "roadcollab.cli.main", *map(str, args)], capture_output=True, text=True,
                       timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f"roadcollab {' '.join(map(str, args))} -> {p.returncode}\n{p.stdout}\n{p.stderr}")
    return p


try:    # looked up here, not in the forked child (no loading or locks between fork and exec)
    _PRCTL = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None
except (OSError, AttributeError):
    _PRCTL = None
_PR_SET_PDEATHSIG = 1


def _die_with(parent: int):
    """``preexec_fn``: SIGTERM to the child when ``parent`` dies; exit at once if it already has."""
    def preexec() -> None:
        if _PRCTL is not None:
            _PRCTL(_PR_SET_PDEATHSIG, int(signal.SIGTERM))
        if os.getppid() != parent:
            os._exit(1)
    return preexec


def start(*cmd, log: Path) -> subprocess.Popen:
    with open(log, "ab") as fh:   # the child keeps its own copy of the descriptor
        return subprocess.Popen(list(map(str, cmd)), stdout=fh, stderr=subprocess.STDOUT, start_new_session=True,
                                preexec_fn=_die_with(os.getpid()))


def start_serve(fleet: Path, store: Path, log: Path, *, listen: int | None = None, broker: str | None = None,
                shared: bool = False, extra=()) -> subprocess.Popen:
    where = ["--listen", f"127.0.0.1:{listen}"] if broker is None else ["--broker", broker]
    p = start(PY, "-m", "roadcollab.cli.main", "serve", "--fleet", fleet, "--store", store, *where,
              *(["--shared"] if shared else []), *extra, log=log)
    end = time.monotonic() + 60
    while time.monotonic() < end:                        # ready when it printed its "serving" line
        if p.poll() is not None:
            raise RuntimeError(f"serve exited with {p.returncode}: {log.read_text()}")
        if "serving fleet" in log.read_text():
            return p
        time.sleep(0.1)
    raise TimeoutError(f"serve did not start: {log.read_text()}")


def start_amqtt(fleet: Path, port: int, log: Path) -> subprocess.Popen:
    p = start(PY, "-m", "roadcollab.network.brokers", "--fleet", fleet, "--listen", f"127.0.0.1:{port}", log=log)
    wait_port(port, proc=p)
    return p


_MOSQ_DIRS: dict = {}


def _mosquitto_dir(data: Path) -> Path:
    """A data folder Mosquitto can reach: as root it drops to the ``mosquitto`` user, which cannot enter
    pytest's 0700 temporary folders, so it gets a folder of its own directly under /tmp (one per
    ``data``, kept across a restart, removed at exit)."""
    if os.geteuid() != 0:
        return data
    if data not in _MOSQ_DIRS:
        _MOSQ_DIRS[data] = Path(tempfile.mkdtemp(prefix="rc-mosq-"))
        atexit.register(shutil.rmtree, _MOSQ_DIRS[data], True)
    return _MOSQ_DIRS[data]


def start_mosquitto(fleet: Path, port: int, data: Path, log: Path) -> subprocess.Popen:
    from roadcollab.network.brokers import mosquitto_config

    conf = mosquitto_config(fleet, "127.0.0.1", port, _mosquitto_dir(data))
    p = start(MOSQUITTO, "-c", conf, log=log)
    wait_port(port, proc=p)
    return p


def stop(p: subprocess.Popen, sig=signal.SIGTERM, timeout: float = 20.0) -> int:
    """Stop a process this module started (by its pid) and return its exit code."""
    if p.poll() is None:
        os.kill(p.pid, sig)
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            os.kill(p.pid, signal.SIGKILL)
            p.wait(timeout)
    return p.returncode


def read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    """Header and values (blank = NaN) of a numeric CSV."""
    with open(path) as fh:
        rows = list(csv.reader(fh))
    return rows[0], np.array([[float(v) if v != "" else np.nan for v in r] for r in rows[1:]])


def assert_same_table(a: Path, b: Path, rtol: float = 1e-9, skip: tuple = ()) -> float:
    """Same header, same blanks, and every number within ``rtol`` of its column's largest magnitude
    (columns whose name starts with one of ``skip`` left out)."""
    ha, va = read_csv(a)
    hb, vb = read_csv(b)
    keep_a = [i for i, h in enumerate(ha) if not h.startswith(tuple(skip))]
    keep_b = [i for i, h in enumerate(hb) if not h.startswith(tuple(skip))]
    ha, va, hb, vb = [ha[i] for i in keep_a], va[:, keep_a], [hb[i] for i in keep_b], vb[:, keep_b]
    assert ha == hb, f"{a.name}: columns differ: {ha} vs {hb}"
    assert va.shape == vb.shape, f"{a.name}: {va.shape} vs {vb.shape}"
    assert np.array_equal(np.isnan(va), np.isnan(vb)), f"{a.name}: blank cells differ"
    scale = np.nanmax(np.abs(va), axis=0)
    err = np.nanmax(np.abs(va - vb), axis=0) / np.where(scale > 0, scale, 1.0)
    assert np.all(err <= rtol), f"{a.name}: worst relative difference {np.max(err):.3g} in {ha[int(np.argmax(err))]}"
    return float(np.max(err))
