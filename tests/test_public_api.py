"""ccdcore's public API: the entry points importable from the package and each subpackage's
``__all__``, each with a numpydoc docstring whose example runs here (doctest)."""
from __future__ import annotations

import doctest
import importlib
import inspect

import pytest

import ccdcore

#: the subpackages that list their public names
SUBPACKAGES = ("ccdcore.io", "ccdcore.session", "ccdcore.dark", "ccdcore.flatfield",
               "ccdcore.response", "ccdcore.response.tsin", "ccdcore.change", "ccdcore.emva",
               "ccdcore.product", "ccdcore.distributed", "ccdcore.cli", "ccdcore.simulate")

ENTRY_POINTS = [n for n in ccdcore.__all__ if n != "__version__"]


def test_the_package_lists_its_entry_points():
    assert len(ENTRY_POINTS) >= 15
    for name in ENTRY_POINTS:
        obj = getattr(ccdcore, name)
        assert callable(obj), name
        # the same object as in its home module: one definition, re-exported
        assert getattr(importlib.import_module(obj.__module__), name) is obj
    assert set(ENTRY_POINTS) <= set(dir(ccdcore)) and "__version__" in ccdcore.__all__
    with pytest.raises(AttributeError):
        ccdcore.no_such_name  # noqa: B018


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_each_entry_point_has_an_example_that_runs(name):
    """Every entry point's docstring has an Examples section (numpydoc) with at least one
    checked output, and doctest runs it without a failure."""
    obj = getattr(ccdcore, name)
    doc = inspect.getdoc(obj) or ""
    assert "Examples\n--------" in doc, f"{name} has no Examples section"
    module = importlib.import_module(obj.__module__)
    tests = doctest.DocTestFinder(recurse=False).find(obj, name, module=module,
                                                       globs=dict(vars(module)))
    examples = [e for t in tests for e in t.examples]
    assert any(e.want.strip() for e in examples), f"{name}'s example checks no output"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    for t in tests:
        runner.run(t)
    assert runner.failures == 0 and runner.tries == len(examples)


def test_the_package_docstring_example_runs():
    tests = doctest.DocTestFinder(recurse=False).find(ccdcore, "ccdcore")
    runner = doctest.DocTestRunner()
    for t in tests:
        runner.run(t)
    assert runner.tries >= 5 and runner.failures == 0


@pytest.mark.parametrize("package", SUBPACKAGES)
def test_each_subpackage_lists_public_names_that_resolve(package):
    """``__all__`` of each subpackage names objects that import; no public name is shadowed by
    a submodule of the same name (importing the submodule would replace the attribute)."""
    mod = importlib.import_module(package)
    names = list(mod.__all__)
    assert names, f"{package} lists no public name"
    for name in names:
        obj = getattr(mod, name)
        assert obj is not None, f"{package}.{name}"
        if not inspect.ismodule(obj):
            assert importlib.util.find_spec(f"{package}.{name}") is None, (
                f"{package}.{name} is both a public name and a submodule")
    assert (mod.__doc__ or "").strip(), f"{package} has no docstring"
