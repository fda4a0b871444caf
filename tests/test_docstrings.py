"""Every public name has a docstring, and functions document their parameters (numpydoc)."""

import importlib
import inspect
import pkgutil

import pytest

import roadcollab

MODULES = [m.name for m in pkgutil.iter_modules(roadcollab.__path__) if not m.name.startswith("_")]


@pytest.mark.parametrize("name", MODULES)
def test_public_names_are_documented(name):
    mod = importlib.import_module(f"roadcollab.{name}")
    assert mod.__doc__ and mod.__doc__.strip(), f"module {name} has no docstring"
    missing = []
    for attr in getattr(mod, "__all__", []):
        obj = getattr(mod, attr)
        if (inspect.isfunction(obj) or inspect.isclass(obj)) and not (obj.__doc__ or "").strip():
            missing.append(attr)
    assert not missing, f"{name}: undocumented public names {missing}"


@pytest.mark.parametrize("name", MODULES)
def test_functions_with_several_arguments_have_a_parameters_section(name):
    mod = importlib.import_module(f"roadcollab.{name}")
    bad = []
    for attr in getattr(mod, "__all__", []):
        obj = getattr(mod, attr)
        if inspect.isfunction(obj):
            params = [p for p in inspect.signature(obj).parameters if p not in ("self",)]
            if len(params) >= 3 and "Parameters" not in (obj.__doc__ or ""):
                bad.append(attr)
    assert not bad, f"{name}: functions of 3+ arguments without a Parameters section: {bad}"
