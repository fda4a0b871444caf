"""A fresh installation's first compiled run, on both cores: the sender's kernels compile in a second process.

numba compiles a kernel on its first call and keeps the machine code on disk (``cache=True``,
:mod:`~roadcollab.lti.kernels`); before it compiles, a process looks on disk, so a kernel another
process has compiled in the meantime is loaded instead (0.01-0.02 s). A ``paper`` run compiles about
21 s of kernels one after the other: the receiver's (certificate, Schur form, decoupling, clustering, block
evaluation) during the fleet's setup, then the sender's (the ``Psi`` draw loop and realisation, the pole
residues and responses, the hiding similarity). :func:`start_background_compile` starts a process that
compiles the sender's kernels at once, while the command itself compiles the receiver's: each half is
about 10 s (docs/speed.md, "Seventh pass").

The second process runs the library's own sender path on a small segment (512 samples), so it compiles
exactly the specialisations the command will ask for, and nothing else: it builds no output, reads no
file and stops by itself when the draw is done. If it fails, or is slower, the command compiles what is
missing itself, as without it.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np

from ...collaboration.algorithm1 import CollaborativeEstimator
from ...lti.kernels import compiled_available, use_kernels
from ...models.vehicle import sample_fleet
from ...privacy import _draw_kernel
from ...lti._cert_kernel import hidden_parts
from ...privacy.obfuscation import ObfuscationChannel, _apply_fresh
from ..config import ExperimentConfig

__all__ = ["sender_kernels_cached", "compile_sender_kernels", "start_background_compile"]

#: The processes started by :func:`start_background_compile` in this process.
_STARTED: list[subprocess.Popen] = []


def sender_kernels_cached() -> bool:
    """Whether the ``Psi`` draw loop (the largest of the sender's kernels, 5-6 s to compile) is on disk.

    Returns
    -------
    bool
        True if its cache index file exists (or numba is missing, or its cache cannot be located: then
        there is nothing to start).
    """
    if not compiled_available():
        return True
    _draw_kernel._build()
    loop = _draw_kernel._KERNEL["loop_pair"]           # the two draws of a paper send, in one call
    try:
        index = loop._cache._cache_file._index_path     # numba's FunctionCache (private, 0.60-0.68)
    except AttributeError:
        return True
    return os.path.exists(index)


def compile_sender_kernels(n_samples: int = 512, seed: int = 0) -> None:
    """Compile (or load) the sender's kernels by drawing one ``paper`` channel on the compiled path.

    Parameters
    ----------
    n_samples : int
        Samples of the segment grid (the kernels' types do not depend on it).
    seed : int
        Seed of the fleet and the draw (nothing is kept).
    """
    base = ExperimentConfig(n_vehicles=1, n_runs=1, margin=0.0)
    cfg = dataclasses.replace(base, segment_length=n_samples * base.speed / base.sample_rate)
    rng = np.random.default_rng(seed)
    vehicle = sample_fleet(1, cfg.fleet, rng=rng)[0]
    # The vehicle's own systems come from the numpy path: the command compiles the receiver's kernels.
    with use_kernels("reference"):
        est = CollaborativeEstimator(vehicle, cfg.noise_model(), cfg.grid(), gamma=cfg.gamma)
    with use_kernels("compiled"):
        ch = ObfuscationChannel.draw(est.T_ss, est.S_ss, est.grid, cfg.obfuscation, rng=rng)
        # What a paper send runs after the draw, up to the certificate (the command compiles that one first,
        # for its receiver): Psi's residues and its product with a spectrum, the hidden form's W and H. The
        # command compiled these itself, about 1.1 s after everything else (docs/speed.md, "Eleventh pass").
        _apply_fresh(ch.psi1, est.grid, np.zeros((est.grid.n_bins, 2), complex))
        form = ch.T.__dict__.get("_cert_form")      # random_similarity's memo: (digest, (R, U, scale, Q))
        if form is not None:
            hidden_parts(form[1][1], form[1][2], form[1][3])


def start_background_compile() -> subprocess.Popen | None:
    """Start a process compiling the sender's kernels if their disk cache is empty.

    Returns
    -------
    subprocess.Popen or None
        The process (its output discarded; it ends by itself in about 10-15 s), or None when the
        kernels are cached, numba is missing, or the process cannot be started.
    """
    if sender_kernels_cached():
        return None
    try:
        proc = subprocess.Popen([sys.executable, "-m", __name__], stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        return None
    _STARTED.append(proc)     # kept: a Popen collected while running warns (ResourceWarning) and is not reaped
    return proc


if __name__ == "__main__":    # pragma: no cover - run in the second process
    compile_sender_kernels()
