"""The Examples sections of the main entry points run as written (doctest)."""

import doctest
import importlib

import pytest

MODULES = ["roadcollab.collaboration.relay", "roadcollab.wire.protocol", "roadcollab.experiments.reproduction.study",
           "roadcollab.collaboration.algorithm1", "roadcollab.collaboration.fusion", "roadcollab.detection.detector",
           "roadcollab.models.simulation", "roadcollab.models.vehicle", "roadcollab.estimation.grid",
           "roadcollab.experiments.pipeline"]


@pytest.mark.parametrize("name", MODULES)
def test_examples_run(name):
    mod = importlib.import_module(name)
    result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.IGNORE_EXCEPTION_DETAIL, verbose=False)
    assert result.attempted > 0, f"{name} has no examples"
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"
