"""ccdcore's public API: the entry points importable from the package and each subpackage's
``__all__``, each with a numpydoc docstring whose example runs here (doctest)."""
from __future__ import annotations

import doctest
import importlib
import inspect
import re

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


#: a numpydoc section header: its name on one line, dashes of the same length on the next
_SECTION = re.compile(r"^(\w[\w ]*)\n(-+)$", re.MULTILINE)
#: a parameter's first line in a Parameters section: ``name : type`` or ``name`` (``**name``)
_PARAMETER = re.compile(r"^\*{0,2}(\w+)(?: : \S.*)?$")


def _sections(doc: str) -> dict[str, tuple[int, str]]:
    """Section name -> (where its header starts, its body) of a numpydoc docstring."""
    found = [m for m in _SECTION.finditer(doc) if len(m.group(1)) == len(m.group(2))]
    ends = [m.start() for m in found[1:]] + [len(doc)]
    return {m.group(1): (m.start(), doc[m.end():end]) for m, end in zip(found, ends)}


def _numpydoc_problems(obj) -> list[str]:
    """What keeps ``obj``'s docstring from being the numpydoc the entry points have: the
    sections Parameters (when it takes any), Returns (a function, not a class) and Examples, in
    that order, and in Parameters a line ``name : type`` or ``name`` at the start of a line for
    every parameter of the signature (``**options`` or ``options`` for ``**options``) and for
    no other name."""
    doc = inspect.getdoc(obj) or ""
    signature = list(inspect.signature(obj).parameters)
    wanted = (["Parameters"] if signature else []) + (
        [] if inspect.isclass(obj) else ["Returns"]) + ["Examples"]
    sections = _sections(doc)
    problems = [f"no {s} section" for s in wanted
                if f"{s}\n{'-' * len(s)}" not in doc or s not in sections]
    if problems:
        return problems
    starts = [sections[s][0] for s in wanted]
    if starts != sorted(starts):
        problems.append(f"sections not in the order {wanted}")
    if signature:
        documented = []
        for line in sections["Parameters"][1].splitlines():
            if line and not line[0].isspace():
                m = _PARAMETER.match(line)
                if m:
                    documented.append(m.group(1))
                else:
                    problems.append(f"not a parameter line ('name : type' or 'name'): {line!r}")
        problems += [f"parameter {p!r} not in Parameters" for p in signature
                     if p not in documented]
        problems += [f"{p!r} in Parameters is no parameter" for p in documented
                     if p not in signature]
    return problems


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_each_entry_point_has_numpydoc_sections_naming_every_parameter(name):
    """Every entry point's docstring has the numpydoc sections Parameters, Returns (not the
    class) and Examples, in that order, and documents every parameter of its signature."""
    assert _numpydoc_problems(getattr(ccdcore, name)) == []


def test_the_numpydoc_check_finds_what_is_missing():
    def complete(session, stack=None, *, align="auto", **options):
        """Summary.

        Parameters
        ----------
        session : Session
            The session.
        stack : str or None, optional
            The stack.
        align : str, optional
            Alignment.
        **options
            More.

        Returns
        -------
        int
            A number.

        Examples
        --------
        >>> 1
        1
        """

    assert _numpydoc_problems(complete) == []

    def lacking(session, stack=None, *, align="auto", **options):
        pass

    lacking.__doc__ = complete.__doc__.replace(
        "        stack : str or None, optional\n            The stack.\n", "")
    assert _numpydoc_problems(lacking) == ["parameter 'stack' not in Parameters"]
    lacking.__doc__ = complete.__doc__.replace("        **options\n            More.\n", "")
    assert _numpydoc_problems(lacking) == ["parameter 'options' not in Parameters"]
    lacking.__doc__ = complete.__doc__.replace("Returns\n        -------", "Returns\n        ---")
    assert _numpydoc_problems(lacking) == ["no Returns section"]
    lacking.__doc__ = ("Summary.\n\nReturns\n-------\nint\n    A number.\n\nParameters\n"
                       "----------\nsession\nstack\nalign\n**options\n\nExamples\n--------\n")
    assert _numpydoc_problems(lacking) == [
        "sections not in the order ['Parameters', 'Returns', 'Examples']"]
