"""FigureQueue: figures drawn at once serially, or on a process pool at the end, to the same files."""

import hashlib

import pytest

from roadcollab.reporting import plotting
from roadcollab.reporting.figure_queue import FigureQueue


def _rows():
    """Rows of a small fusion figure: two estimators, two vehicles."""
    import dataclasses

    from roadcollab.experiments.reproduction.rows import FusionRow

    values = {"mse_mean": 1e-3, "mse_std": 1e-4, "mse_ci95": 2e-4}
    return [FusionRow(**{f.name: values.get(f.name, 3) for f in dataclasses.fields(FusionRow)
                         if f.name not in ("estimator", "vehicle")}, estimator=e, vehicle=v)
            for e in ("fused", "centralized") for v in (1, 2)]


def _fails(path):
    raise ValueError(f"cannot draw {path}")


def test_serial_draws_at_once_and_a_pool_draws_the_same_files_at_the_end(tmp_path):
    rows = _rows()
    serial = FigureQueue()
    serial(plotting.plot_fusion, rows, tmp_path / "a.png")
    assert (tmp_path / "a.png").exists() and serial.seconds > 0
    pooled = FigureQueue(2)
    for name in ("b.png", "c.png", "d.png"):
        pooled(plotting.plot_fusion, rows, tmp_path / name)
    assert not (tmp_path / "b.png").exists() and pooled.seconds == 0   # queued, not drawn
    pooled.finish()
    digest = {hashlib.sha256((tmp_path / n).read_bytes()).hexdigest() for n in ("a.png", "b.png", "c.png", "d.png")}
    assert len(digest) == 1 and pooled.seconds > 0
    pooled.finish()     # nothing left: no pool started


def test_a_figure_that_fails_on_the_pool_raises_in_finish(tmp_path):
    q = FigureQueue(2)
    q(_fails, tmp_path / "x.png")
    q(plotting.plot_fusion, _rows(), tmp_path / "y.png")
    with pytest.raises(ValueError, match="cannot draw"):
        q.finish()
