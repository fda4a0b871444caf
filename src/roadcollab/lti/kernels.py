"""The choice between the compiled (numba) kernels and the numpy reference path, and what the kernel
modules share (compile options, read-only views, the tile of bins).

Two paths compute the same quantities:

- ``"reference"``: numpy/scipy only (:func:`~roadcollab.lti.blockdiag.block_response`, the
  pole-residue product of :func:`~roadcollab.lti.response.ss_response`, the ``Psi`` draw's loop in
  :func:`~roadcollab.privacy.obfuscator_design.draw_obfuscator`);
- ``"compiled"``: the same evaluations as loops compiled by numba, tiles of bins with real and
  imaginary parts apart (:mod:`roadcollab.lti._eval_kernel`, :mod:`roadcollab.lti._pole_kernel`), the
  ``Psi`` draw's rejection loop and realisation
  (:mod:`roadcollab.privacy._draw_kernel`, from the same random generator, leaving the same state) and
  ``Psi``'s responses from its poles and residues, a receiver's complex Schur form (real Schur form and
  compiled rotations) and the triangular Stein solve of its Lyapunov certificate
  (:mod:`roadcollab.lti._cert_kernel`), and the per-bin 2x2 products and inverses
  (:mod:`roadcollab.lti._bin_kernel`). They differ from the reference by round-off only (the Schur form
  is another valid one; the certificate's residual is checked either way).

The block diagonalisation of a received system (reordering, Sylvester splits, eigenvalue clustering:
:mod:`roadcollab.lti._blockdiag_kernel`), ``Psi``'s pole residues and the hiding similarity of ``T~``, ``S~``
(:mod:`roadcollab.lti._hide_kernel`) are compiled too.

The library's default is ``"reference"`` (numpy). The compiled path passes the 300-segment exactness test and
makes ``paper`` about 3.5x faster per segment than the reference path (3.45-3.58x in the bench's alternating
line, docs/speed.md, "Eleventh pass"), but every process that uses it pays numba's start-up (import, cache
load) and about 145 MiB, and a fresh installation's first run compiles the kernels, about 16-17 s of CPU in
all (at LLVM -O1, :data:`KERNEL_OPT_LEVEL`), shared between the command and a second process the command line
starts (docs/speed.md, "Twelfth pass", "Fifteenth pass"). So the commands that run Algorithm 2 many times
(``roadcollab reproduce``, ``attack``, ``sweep``, ``bench``) use it unless told otherwise (``--kernels``),
and a vehicle process or a library call keeps the numpy path. The
environment variable ``ROADCOLLAB_KERNELS=compiled`` (or ``reference``) sets the default of both, and
:func:`use_kernels` selects a path for a block of code (``roadcollab bench --kernels``).

numba is compiled with ``error_model="numpy"``: its default ``"python"`` model checks every float
division for zero (to raise ``ZeroDivisionError``) and that branch blocks vectorisation (measured
3.9x slower on the same loop). ``cache=True`` keeps the machine code on disk, beside the kernel modules in
``__pycache__`` (or under ``NUMBA_CACHE_DIR`` when set), so only the first run after installation
compiles.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
from collections.abc import Iterator
from typing import Any

import numpy as np

from .._validation import is_frozen
from ..errors import ParameterError

__all__ = ["KERNELS", "kernel_path", "environment_kernels", "use_kernels", "compiled_available", "jit_options", "read_only",
           "complex_parts", "keep_parts",
           "TILE"]

KERNELS = ("compiled", "reference")

_CHOICE: contextvars.ContextVar[str | None] = contextvars.ContextVar("roadcollab_kernels", default=None)
#: Bins per pass of the block kernel: its per-bin arrays (2 x (n + 4 + 2 k_max m) x TILE doubles) stay in cache.
TILE = 256
#: The compiled functions once built (``{}`` before the first use; ``None`` values if numba is missing).
_COMPILED: dict[str, Any] = {}


def jit_options(internal: bool = False) -> dict[str, Any]:
    """The options every compiled kernel of the package is built with (``numba.njit(**jit_options())``).

    Parameters
    ----------
    internal : bool
        For a function only compiled kernels call: without the wrappers that let Python (and C) call it
        (``no_cpython_wrapper``, ``no_cfunc_wrapper``), which numba otherwise compiles for every function
        (0.03-0.1 s each of a fresh installation's first run, docs/speed.md, "Twelfth pass").

    Returns
    -------
    dict
        ``cache=True`` (machine code kept on disk), ``error_model="numpy"`` (no zero-division branch
        in float divisions, module docstring), ``nogil=True``; with ``internal``, the two options above.
    """
    options: dict[str, Any] = {"cache": True, "error_model": "numpy", "nogil": True}
    if internal:
        options.update(no_cpython_wrapper=True, no_cfunc_wrapper=True)
    return options


def read_only(x: np.ndarray) -> np.ndarray:
    """``x`` itself if it is read-only, else a read-only view of it (no copy).

    numba compiles one specialisation per argument type, and a read-only array is another type than a
    writable one. The checked messages' arrays are read-only and a vehicle's own are not, so a kernel fed
    both compiled twice (about 5.5 s of a fresh installation's first run, docs/speed.md, "Seventh pass").
    Its wrappers pass arrays the kernel only reads through this.

    Parameters
    ----------
    x : ndarray

    Returns
    -------
    ndarray
        The same data, ``flags.writeable`` False.
    """
    if x.flags.writeable:
        x = x.view()
        x.flags.writeable = False
    return x


#: Parts of the unit-circle vectors :func:`keep_parts` was given (the last four): (vector, real, imaginary).
_PARTS: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []


def keep_parts(z: np.ndarray) -> None:
    """Split a frozen complex vector that :func:`~roadcollab.lti.response.unit_circle` keeps (``exp(j omega)``
    of a grid), so that :func:`complex_parts` finds its parts by identity while it stays frozen: the memo
    rests on what unit_circle's own does, for the same vectors.

    Parameters
    ----------
    z : (M,) complex ndarray
        Read-only.
    """
    if is_frozen(z):
        re, im = _split(z)
        _PARTS.insert(0, (z, re, im))         # the list holds z, so its id cannot be reused
        del _PARTS[4:]


def _split(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    re, im = np.array(z.real, dtype=float), np.array(z.imag, dtype=float)     # own copies, C order
    re.flags.writeable = False
    im.flags.writeable = False
    return re, im


def complex_parts(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The real and imaginary parts of a complex vector as contiguous read-only arrays, as the kernels over
    bins take them. For a grid's ``exp(j omega)`` (:func:`keep_parts`) they are split once: a ``paper``
    vehicle-segment split the same 3000 bins four times, 2.3 us each (docs/speed.md, "Eleventh pass").

    Parameters
    ----------
    z : (M,) complex ndarray

    Returns
    -------
    real, imag : (M,) float ndarray
        Read-only.
    """
    for source, re, im in tuple(_PARTS):
        if source is z and is_frozen(source):
            return re, im
    return _split(z)


def _build() -> dict[str, Any]:
    """Import numba, once (lazily: importing it costs about 0.3 s); ``{"numba": None}`` when it does not
    import. The kernels themselves are module-level functions of the ``_*_kernel`` modules, compiled there:
    a kernel that calls a jitted closure cannot be loaded from numba's on-disk cache (its key holds the
    closure's cell, new in every process), and the pole-residue kernels defined here before were compiled
    again by every process (1-2 s of every run, one more cache file each time)."""
    if _COMPILED:
        return _COMPILED
    try:
        import numba
    except ImportError:
        _COMPILED.update(numba=None)
        return _COMPILED
    _COMPILED.update(numba=numba)
    _lower_kernels_opt_level()
    return _COMPILED


#: LLVM's optimisation level for the package's kernels (numba's own default, ``NUMBA_OPT``, is 3). At 1
#: a fresh installation's first run compiled for 0.7 s less (four pairs of cold ``bench --quick``), and
#: neither ``paper`` per segment nor ``reproduce`` was slower (same medians within noise; 0.99 of the time
#: in five pairs), with every CSV and figure of ``reproduce`` byte-identical: without fast-math LLVM may not
#: reorder or fuse floating-point operations at any level (docs/speed.md, "Fifteenth pass").
KERNEL_OPT_LEVEL = 1
#: The active compile scope: [depth of the package's kernels being compiled, numba's level before].
_OPT_SCOPE: list[Any] = [0, None]


def _lower_kernels_opt_level() -> None:
    """Compile the package's kernels at :data:`KERNEL_OPT_LEVEL`, and nothing else: a listener on numba's
    ``numba:compile`` event (numba's event API) lowers ``numba.config.OPT`` while a function of this
    package compiles (with everything it compiles inside: its callees, numba's own overloads) and restores
    it after. numba reads the level whenever it builds its optimisation passes, and fires the event under
    its global compiler lock, so no other compilation sees the lowered level. A user's ``NUMBA_OPT`` is
    left in force.
    """
    if "NUMBA_OPT" in os.environ:
        return
    from numba.core import config as numba_config, event

    config: Any = numba_config                  # untyped module; OPT is set by numba at import

    def is_ours(ev: Any) -> bool:
        func = getattr(ev.data.get("dispatcher"), "py_func", None)
        return (getattr(func, "__module__", None) or "").startswith("roadcollab.")    # None: made by exec

    class _Scope(event.Listener):
        def on_start(self, ev: Any) -> None:
            if _OPT_SCOPE[0] == 0 and is_ours(ev):
                _OPT_SCOPE[1] = config.OPT
                config.OPT = type(config.OPT)(KERNEL_OPT_LEVEL)
            if _OPT_SCOPE[0] or is_ours(ev):
                _OPT_SCOPE[0] += 1

        def on_end(self, ev: Any) -> None:
            if _OPT_SCOPE[0]:
                _OPT_SCOPE[0] -= 1
                if _OPT_SCOPE[0] == 0:
                    config.OPT = _OPT_SCOPE[1]

    register: Any = event.register              # untyped in numba
    register("numba:compile", _Scope())


def compiled_available() -> bool:
    """Whether numba imports (the compiled kernels can be used).

    Returns
    -------
    bool
    """
    return _build()["numba"] is not None


def kernel_path() -> str:
    """The path in effect: :func:`use_kernels`' choice, else ``ROADCOLLAB_KERNELS``, else ``"reference"``;
    always ``"reference"`` when numba does not import.

    Returns
    -------
    {"compiled", "reference"}

    Raises
    ------
    ParameterError
        If ``ROADCOLLAB_KERNELS`` is set to anything else.
    """
    choice = _CHOICE.get() or environment_kernels() or "reference"
    return "compiled" if choice == "compiled" and compiled_available() else "reference"


def environment_kernels() -> str | None:
    """The path ``ROADCOLLAB_KERNELS`` asks for, or None when it is unset or empty.

    Returns
    -------
    {"compiled", "reference"} or None

    Raises
    ------
    ParameterError
        If ``ROADCOLLAB_KERNELS`` is set to anything else.
    """
    choice = os.environ.get("ROADCOLLAB_KERNELS") or None
    if choice is not None and choice not in KERNELS:
        raise ParameterError(f"environment variable ROADCOLLAB_KERNELS must be 'compiled' or 'reference', "
                             f"got {choice!r}")
    return choice


@contextlib.contextmanager
def use_kernels(name: str) -> Iterator[None]:
    """Evaluate with the ``"compiled"`` or ``"reference"`` kernels inside a ``with`` block.

    Parameters
    ----------
    name : {"compiled", "reference"}
        ``"compiled"`` falls back to the reference path when numba is not importable.

    Raises
    ------
    ParameterError
        For another name.
    """
    if name not in KERNELS:
        raise ParameterError(f"kernels must be one of {KERNELS}, got {name!r}")
    token = _CHOICE.set(name)
    try:
        yield
    finally:
        _CHOICE.reset(token)
