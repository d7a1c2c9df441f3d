"""``pip install ccdcore`` is the library alone: the app, the report and a Dask cluster are
optional extras, and a verb whose extra is missing says which ``pip install`` brings it."""
from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXTRA_PACKAGES = ("panel", "holoviews", "bokeh", "pandas", "dask", "distributed", "matplotlib")


def _requirement_names(reqs: list[str]) -> set[str]:
    names = set()
    for r in reqs:
        name = r.split(";")[0].split("[")[0]
        for sep in "<>=!~ ":
            name = name.split(sep)[0]
        names.add(name.strip().lower())
    return names


def test_the_library_depends_on_no_extra_package():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = _requirement_names(project["dependencies"])
    assert core.isdisjoint(EXTRA_PACKAGES), core & set(EXTRA_PACKAGES)
    extras = project["optional-dependencies"]
    assert {"panel", "holoviews", "bokeh"} <= _requirement_names(extras["app"])
    assert "bokeh" in _requirement_names(extras["report"])
    assert "dask" in _requirement_names(extras["distributed"])


def test_importing_every_ccdcore_module_imports_no_extra_package():
    code = (
        "import sys, importlib, pkgutil, ccdcore\n"
        "for m in pkgutil.walk_packages(ccdcore.__path__, 'ccdcore.'):\n"
        "    importlib.import_module(m.name)\n"
        f"print(','.join(sorted(n for n in sys.modules if n.split('.')[0] in {EXTRA_PACKAGES!r})))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=ROOT)
    assert out.stdout.strip() == ""


@pytest.mark.parametrize("argv, missing, extra", [
    (["report", "assets/healey94", "-o", "{tmp}/r.html"], "bokeh", "report"),
    (["app", "assets/healey94", "--port", "5999"], "panel", "app"),
    (["ptc", "assets/healey94", "--workers", "1"], "distributed", "distributed"),
    (["datasheet", "assets/emva1288", "-o", "{tmp}/d"], "matplotlib", "datasheet"),
])
def test_a_verb_without_its_extra_says_what_to_install(tmp_path, argv, missing, extra):
    """The extra's package made unimportable (``sys.modules[name] = None``), as on a machine
    where only the library is installed."""
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    code = (
        f"import sys\nsys.modules[{missing!r}] = None\n"
        "from ccdcore.cli.command import main\n"
        f"sys.exit(main({argv!r}))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr
    assert f"needs {missing}" in lines[0] and f"pip install 'ccdcore[{extra}]'" in lines[0]
    assert not list(tmp_path.iterdir())                  # nothing written
