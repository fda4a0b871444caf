"""The second process that compiles the sender's kernels (``experiments.bench.warm``)."""

import os
import subprocess
import sys

import pytest

from roadcollab.lti import kernels

_SLOW = [pytest.mark.slow, pytest.mark.skipif(not kernels.compiled_available(), reason="numba not importable")]

#: In a fresh process: is the draw loop cached; then a bench segment on the compiled path, and which of the
#: sender's kernels and of the receiver's (those the second process compiles by signature) it loaded from disk
#: and which it compiled.
_PROBE = """
import json
from roadcollab.experiments.bench import warm
from roadcollab.experiments.bench.study import bench_segment
from roadcollab.privacy import _draw_kernel
from roadcollab.lti import _cert_kernel, _hide_kernel, _pole_kernel
cached = warm.sender_kernels_cached()
bench_segment(512, mechanism="paper", repeats=1, kernels="compiled")
stats = {name: (sum(d.stats.cache_hits.values()), sum(d.stats.cache_misses.values()))
         for name, d in (("loop", _draw_kernel._KERNEL["loop"]), ("realise", _draw_kernel._KERNEL["realise"]),
                         ("hide", _hide_kernel._KERNEL["hide"]), ("residues", _draw_kernel._KERNEL["residues"]),
                         ("pole_apply", _pole_kernel._KERNEL["pole_apply"]), ("hidden", _cert_kernel._KERNEL["hidden"]))}
stats.update({kernel.py_func.__name__: (sum(kernel.stats.cache_hits.values()), sum(kernel.stats.cache_misses.values()))
              for kernel, _ in warm.receiver_kernels()})
print(json.dumps({"cached": cached, "stats": stats}))
"""


def _probe(env):
    import json
    out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=600, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@_SLOW[0]
@_SLOW[1]
def test_the_second_process_compiles_the_specialisations_the_command_then_loads(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    cold = _probe(dict(env, NUMBA_CACHE_DIR=str(tmp_path / "cold")))
    assert cold["cached"] is False
    assert all(hits == 0 and misses == 1 for hits, misses in cold["stats"].values())   # compiled itself
    subprocess.run([sys.executable, "-m", "roadcollab.experiments.bench.warm"], env=env, timeout=600, check=True)
    warm = _probe(env)
    assert warm["cached"] is True
    assert all(hits == 1 and misses == 0 for hits, misses in warm["stats"].values())   # loaded, not compiled


class _Kernel:
    """A stand-in for a dispatcher: what compile_receiver_tail reads and calls."""

    def __init__(self, name, log):
        self.name, self.log, self.overloads = name, log, {}

    def compile(self, sig):
        self.log.append(self.name)
        self.overloads[sig] = True


@pytest.mark.parametrize("on_disk, own, compiled", [
    ((), (), ["h", "g", "f", "e", "d", "c", "b", "a"]),           # nothing on disk: all of them, last first
    (("a", "b", "c"), (), ["h", "g", "f", "e"]),                  # the command has compiled a-c, is at d
    (("a", "b", "c", "d", "e", "f", "g"), (), []),                # the command is at the last one
    (("a", "b", "c", "d", "e", "f", "g", "h"), (), []),
    (("a", "b", "f"), ("f",), ["h", "g", "f", "e", "d"]),          # f its own (the sender's path): not a sign
])
def test_the_receiver_tail_stops_where_the_command_has_been(monkeypatch, on_disk, own, compiled):
    """The second process compiles the receiver's kernels from the last one backwards and leaves a kernel to
    the command once the one before it is on disk, not counting those it compiled or loaded itself."""
    from roadcollab.experiments.bench import warm

    log = []
    kernels = [_Kernel(name, log) for name in "abcdefgh"]
    for k in kernels:
        if k.name in own:
            k.overloads["sig"] = True
    monkeypatch.setattr(warm, "receiver_kernels", lambda: [(k, "sig") for k in kernels])
    monkeypatch.setattr(warm, "_on_disk", lambda k: k.name in on_disk)
    assert warm.compile_receiver_tail() == len(compiled)
    assert log == compiled


@pytest.mark.parametrize("command, option, env, kernels, started, scale", [
    ("bench", None, None, "compiled", True, None), ("bench", None, "reference", "reference", True, None),
    ("bench", None, None, "compiled", True, [100]),
    ("reproduce", None, None, "compiled", True, None), ("reproduce", None, "reference", "reference", False, None),
    ("reproduce", "reference", "compiled", "reference", False, None),
    ("attack", "compiled", "reference", "compiled", True, None), ("sweep", None, "compiled", "compiled", True, None),
    ("status", "-", "compiled", None, False, None), ("estimate", "-", None, None, False, None)])
def test_the_batch_commands_default_to_the_compiled_path_and_compile_alongside(monkeypatch, command, option, env,
                                                                              kernels, started, scale):
    """--kernels, else ROADCOLLAB_KERNELS, else compiled for the commands with the option ("-": the command has none,
    and keeps the library's default); the second compile process starts on the compiled path (bench: always)."""
    import argparse

    from roadcollab.cli import main
    from roadcollab.experiments.bench import warm

    calls = []
    monkeypatch.setattr(warm, "start_background_compile", lambda: calls.append(1))
    if env is None:
        monkeypatch.delenv("ROADCOLLAB_KERNELS", raising=False)
    else:
        monkeypatch.setenv("ROADCOLLAB_KERNELS", env)
    args = argparse.Namespace(command=command, scale=scale, **({} if option == "-" else {"kernels": option}))
    assert main._kernels(args) == kernels
    main._compile_alongside(args, main._kernels(args))
    assert bool(calls) is started


def test_a_bad_kernels_environment_variable_is_one_clear_line(monkeypatch, capsys, tmp_path):
    from roadcollab.cli.main import main

    monkeypatch.setenv("ROADCOLLAB_KERNELS", "turbo")
    assert main(["reproduce", "--runs", "1", "--vehicles", "2", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["roadcollab reproduce: error: environment variable ROADCOLLAB_KERNELS must be 'compiled' or "
                   "'reference', got 'turbo'"]
    assert not (tmp_path / "r").exists()


_SEGMENT = """
from roadcollab.experiments.bench.study import bench_segment
for mechanism in ("paper", "none"):
    bench_segment(512, mechanism=mechanism, repeats=1, kernels="compiled")
"""


@_SLOW[0]
@_SLOW[1]
def test_a_second_process_compiles_no_kernel_again(tmp_path):
    """Every kernel a bench segment uses is loaded from the on-disk cache by the next process: a kernel that
    calls a jitted closure is not (its cache key holds the closure's cell), and before they moved to module
    level the pole-residue kernels were compiled again, and saved once more, by every process."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    subprocess.run([sys.executable, "-c", _SEGMENT], env=env, timeout=600, check=True)
    first = sorted(p.name for p in (tmp_path / "cache").rglob("*.nbc"))
    subprocess.run([sys.executable, "-c", _SEGMENT], env=env, timeout=600, check=True)
    second = sorted(p.name for p in (tmp_path / "cache").rglob("*.nbc"))
    assert first and second == first, sorted(set(second) - set(first))
