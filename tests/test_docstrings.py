"""Every public module, class and function is documented, and every argument of every public function
and method appears in its numpydoc ``Parameters`` section (python-control's docstrings test is the model)."""

import importlib
import inspect
import pkgutil
import warnings

import pytest
from numpydoc.docscrape import FunctionDoc

import roadcollab

MODULES = sorted(m.name for m in pkgutil.walk_packages(roadcollab.__path__, "roadcollab.")
                 if not any(part.startswith("_") for part in m.name.split(".")[1:]))


def _public_members(mod):
    names = getattr(mod, "__all__", None)
    if names is None:
        names = [n for n in vars(mod) if not n.startswith("_")]
    for n in names:
        obj = getattr(mod, n)
        if (inspect.isfunction(obj) or inspect.isclass(obj)) and obj.__module__ == mod.__name__:
            yield n, obj


def _callables(mod):
    for name, obj in _public_members(mod):
        if inspect.isfunction(obj):
            yield name, obj
        else:
            for meth_name, meth in vars(obj).items():
                if meth_name.startswith("_") and meth_name != "__call__":
                    continue
                if isinstance(meth, (staticmethod, classmethod)):
                    meth = meth.__func__
                if inspect.isfunction(meth):
                    yield f"{name}.{meth_name}", meth


def _documented_params(func) -> set[str]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        doc = FunctionDoc(func)
    out = set()
    for p in doc["Parameters"] + doc["Other Parameters"]:
        for n in p.name.split(","):
            out.add(n.strip().lstrip("*"))
    return out


@pytest.mark.parametrize("name", MODULES)
def test_public_names_are_documented(name):
    mod = importlib.import_module(name)
    assert (mod.__doc__ or "").strip(), f"module {name} has no docstring"
    missing = [n for n, obj in _public_members(mod) if not (obj.__doc__ or "").strip()]
    assert not missing, f"{name}: undocumented public names {missing}"


@pytest.mark.parametrize("name", MODULES)
def test_every_argument_is_documented(name):
    mod = importlib.import_module(name)
    bad = []
    for qual, func in _callables(mod):
        params = [p.name for p in inspect.signature(func).parameters.values()
                  if p.name not in ("self", "cls")]
        if not params or not (func.__doc__ or "").strip():
            continue
        missing = [p for p in params if p not in _documented_params(func)]
        if missing:
            bad.append(f"{qual}: {missing}")
    assert not bad, f"{name}: arguments missing from the Parameters section:\n  " + "\n  ".join(bad)
