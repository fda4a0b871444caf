"""A fresh installation's first compiled run, on both cores: the sender's kernels compile in a second process.

numba compiles a kernel on its first call and keeps the machine code on disk (``cache=True``,
:mod:`~roadcollab.lti.kernels`); before it compiles, a process looks on disk, so a kernel another
process has compiled in the meantime is loaded instead (0.01-0.02 s). A ``paper`` run compiles its kernels
one after the other: the receiver's (pole residues, block diagonalisation, block evaluation, Schur form,
certificate, per-bin solve) during the fleet's setup and its first decode and estimate, then the sender's
(the ``Psi`` draw loop and realisation, the pole residues and responses, the hiding similarity).
:func:`start_background_compile` starts a process that compiles the sender's kernels at once, while the
command itself compiles the receiver's (docs/speed.md, "Seventh pass"); then, as long as the command has
not reached them, the receiver's from the last one backwards (:func:`compile_receiver_tail`), so that the
two processes meet in the middle (docs/speed.md, "Twelfth pass").

The second process runs the library's own sender path on a small segment (512 samples), so it compiles
exactly the specialisations the command will ask for; the receiver's kernels it compiles by their
signatures (:func:`receiver_kernels`). It builds no output, reads no file and stops by itself. If it fails,
or is slower, the command compiles what is missing itself, as without it.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from typing import Any

import numpy as np

from ...collaboration.algorithm1 import CollaborativeEstimator
from ...lti import _bin_kernel, _blockdiag_kernel, _cert_kernel, _eval_kernel, _pole_kernel
from ...lti.kernels import compiled_available, use_kernels
from ...models.vehicle import sample_fleet
from ...privacy import _draw_kernel
from ...lti._cert_kernel import hidden_parts
from ...privacy.obfuscation import ObfuscationChannel, _apply_fresh
from ..config import ExperimentConfig

__all__ = ["sender_kernels_cached", "compile_sender_kernels", "receiver_kernels", "compile_receiver_tail",
           "start_background_compile"]

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
    loop = _draw_kernel._KERNEL["loop"]                # the draws of a send, in one call
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


def receiver_kernels() -> list[tuple[Any, tuple]]:
    """The receiver's kernels in the order a command's first ``paper`` run reaches them, each with the one
    specialisation it compiles (the wrappers hand every kernel C-ordered arrays, read-only where the kernel
    only reads them: :func:`~roadcollab.lti.kernels.read_only`): the pole-residue evaluation and the 2x2
    inverse (the fleet's setup), the block diagonalisation, the block evaluation, the 2x2 product, the
    Schur form's rotations, the certificate and the receiver's per-bin solve (decode and estimate).

    Returns
    -------
    list of (dispatcher, tuple of numba types)
        Empty without numba.
    """
    if not compiled_available():
        return []
    from numba import types

    def arr(dtype: Any, ndim: int, readonly: bool = False) -> Any:
        return types.Array(dtype, ndim, "C", readonly=readonly)

    f8, c16, i8 = types.float64, types.complex128, types.int64
    pole, bins, form = _pole_kernel._build(), _bin_kernel._build(), _blockdiag_kernel._build()
    block, cert = _eval_kernel._build(), _cert_kernel._build()
    return [
        (pole["pole"], (arr(f8, 1), arr(f8, 1), arr(f8, 2), arr(f8, 2), arr(f8, 1), arr(f8, 1), arr(f8, 1, True),
                        arr(f8, 1, True), arr(c16, 2))),
        (bins["inv"], (arr(c16, 3, True), arr(c16, 3))),
        (form["form"], (arr(c16, 2, True), arr(c16, 2, True), arr(f8, 2, True), arr(f8, 2, True), f8, f8, f8)),
        (block["block"], (arr(c16, 2), arr(c16, 2), arr(c16, 2), arr(f8, 2, True), arr(i8, 1), arr(i8, 1),
                          arr(f8, 1, True), arr(f8, 1, True), arr(c16, 2))),
        (bins["matvec"], (arr(c16, 3, True), arr(c16, 2), arr(c16, 2))),
        (cert["rsf2csf"], (arr(c16, 2), arr(c16, 2))),
        (cert["figures"], (arr(c16, 2), arr(c16, 2), arr(f8, 2, True), arr(c16, 2), types.boolean)),
        (bins["receiver_z"], (arr(c16, 3, True), arr(c16, 3, True), arr(c16, 2, True), arr(c16, 2, True),
                              arr(f8, 1, True), arr(c16, 2))),
    ]


def compile_receiver_tail() -> int:
    """Compile the receiver's kernels from the last one a command reaches backwards, while the command
    compiles them from the first on: the two processes meet in the middle.

    A kernel is left to the command once the one before it (in the command's order, of those this process
    has not compiled or loaded itself: the sender's path reaches the Schur form's rotations too) is on disk:
    the command is then compiling it, or past it. Compiling by signature (``dispatcher.compile``) gives the
    same cache entry as the command's call (the probe test checks that the command loads them).

    Returns
    -------
    int
        How many kernels this process compiled or loaded.
    """
    kernels = receiver_kernels()
    done = 0
    for i in range(len(kernels) - 1, -1, -1):
        before = [k for k, _ in kernels[:i] if not k.overloads]
        if before and _on_disk(before[-1]):
            break
        kernel, sig = kernels[i]
        kernel.compile(sig)
        done += 1
    return done


def _on_disk(kernel: Any) -> bool:
    """Whether a kernel's cache index file exists (numba's ``FunctionCache``, private; False if it cannot be
    located)."""
    try:
        return os.path.exists(kernel._cache._cache_file._index_path)
    except AttributeError:
        return False


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
    compile_receiver_tail()
