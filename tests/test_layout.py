"""The layout shows the architecture (docs/architecture.md, "Layout"): the app in app/, the
report in report/, each family of modules a subpackage, at most 25 modules at ccdcore's top
level, every package installed, and no module or function too long to read."""
from __future__ import annotations

import ast
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: folder -> the package it is installed as
FOLDERS = {"ccdcore": "ccdcore", "app": "ccdcore_app", "report": "ccdcore_report"}
MAX_TOP_MODULES = 25
MAX_MODULE_LINES = 900
MAX_FUNCTION_LINES = 120


def _packages() -> set[str]:
    found = set()
    for folder, package in FOLDERS.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            found.add(".".join((package, *init.parent.relative_to(ROOT / folder).parts)))
    return found


def test_the_top_level_is_the_design_cards():
    for name in ("pyproject.toml", "app", "ccdcore", "tests", "assets", "README.md", "report"):
        assert (ROOT / name).exists(), name
    assert not (ROOT / "ccdcore_app").exists() and not (ROOT / "ccdcore_report").exists()


def test_ccdcore_has_at_most_25_top_level_modules():
    top = sorted(p.name for p in (ROOT / "ccdcore").glob("*.py"))
    assert len(top) <= MAX_TOP_MODULES, f"{len(top)} modules at ccdcore/'s top: {top}"


def test_every_package_is_installed_under_its_name():
    """pyproject.toml lists every package (a wheel without one would lack its modules) and maps
    the app's and the report's folders to their package names."""
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]
    setup = tool["setuptools"]
    assert set(setup["packages"]) == _packages()
    assert setup["package-dir"] == {"ccdcore_app": "app", "ccdcore_report": "report"}


def test_every_package_says_what_it_holds():
    for folder in FOLDERS:
        for init in (ROOT / folder).rglob("__init__.py"):
            doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8")))
            assert doc and len(doc) > 20, f"{init.relative_to(ROOT)} has no docstring"


def test_no_module_or_function_is_too_long():
    long_modules, long_functions = [], []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            rel = path.relative_to(ROOT)
            if text.count("\n") > MAX_MODULE_LINES:
                long_modules.append(f"{rel}: {text.count(chr(10))} lines")
            for node in ast.walk(ast.parse(text)):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    n = node.end_lineno - node.lineno + 1
                    if n > MAX_FUNCTION_LINES:
                        long_functions.append(f"{rel}:{node.lineno} {node.name}: {n} lines")
    assert long_modules == [] and long_functions == [], long_modules + long_functions
