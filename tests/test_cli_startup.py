"""The command line starts light: building its parser (``--version``, ``--help``, every verb's
``--help``) loads no heavy package and no estimator; a verb loads them when it runs.

Each check runs in a fresh interpreter, since this test session has long loaded everything.
There is no timing assertion here (docs/architecture.md, "Start-up of the command line", has
the figures); what is asserted is what the time depends on: the modules loaded.
"""
from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: what building the parser must not load: compiled kernels, SciPy, the image and FITS readers,
#: Dask, the UI packages, and the estimators
HEAVY = ("numba", "scipy", "threadpoolctl", "OpenImageIO", "astropy", "dask", "distributed",
         "panel", "bokeh", "holoviews", "matplotlib", "ccdcore_app", "ccdcore_report")
ESTIMATORS = ("ccdcore.response.tsin.estimator", "ccdcore.response.methods",
              "ccdcore.response.brackets", "ccdcore.response.classic", "ccdcore.response.hdr",
              "ccdcore.reduce", "ccdcore.kmap_kernels", "ccdcore.noise", "ccdcore.dark.frame",
              "ccdcore.fixedpattern", "ccdcore.flatfield.fit", "ccdcore.flatfield.uniformity",
              "ccdcore.product.make", "ccdcore.change.detector", "ccdcore.session",
              "ccdcore.io.frames")

VERBS = ("simulate", "session", "ptc", "calibrate", "datasheet", "apply", "snup", "response",
         "hdr", "change", "report", "app")


def _python(code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=120)


#: prints the heavy packages and estimators loaded after building the parser and asking it
#: for the help of each verb named on the command line (``-`` for ``ccdcore --help``)
_LOADED = f"""
import contextlib, io, sys
import ccdcore.cli.command
parser = ccdcore.cli.command.build_parser()
for verb in sys.argv[1:]:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):
        parser.parse_args(["--help"] if verb == "-" else [verb, "--help"])
heavy = {HEAVY!r}
estimators = {ESTIMATORS!r}
print(",".join(sorted(n for n in sys.modules if n.split(".")[0] in heavy
                      or any(n == e or n.startswith(e + ".") for e in estimators))))
"""


def test_building_the_parser_loads_no_heavy_package_nor_estimator():
    out = _python(_LOADED)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"building the parser loaded: {out.stdout.strip()}"


def test_every_help_loads_no_heavy_package_nor_estimator():
    out = _python(_LOADED, "-", *VERBS)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"--help loaded: {out.stdout.strip()}"


def test_version_is_the_package_version():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    out = subprocess.run([sys.executable, "-m", "ccdcore.cli", "--version"],
                         capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout == f"ccdcore {project['version']}\n"


def test_the_light_names_agree_with_the_modules_that_use_them():
    """The parser's facts (:mod:`ccdcore.response.names`, :mod:`ccdcore.reduce_names`) are
    those of the estimators."""
    from ccdcore import reduce, reduce_names
    from ccdcore.response import brackets, methods, names

    assert tuple(methods.METHODS) == names.METHOD_NAMES
    assert names.DEFAULT_METHOD == methods.AUTO
    assert names.METHOD_CHOICES == (methods.AUTO,) + tuple(methods.METHODS)
    assert names.DEFAULT_BLOOM_RADIUS == brackets.DEFAULT_BLOOM_RADIUS
    assert names.MAX_BLOOM_RADIUS == brackets.MAX_BLOOM_RADIUS
    assert reduce_names.STREAMED_NAME == reduce.STREAMED_NAME


def test_response_package_loads_its_names_on_first_use():
    """``ccdcore.response`` loads no submodule until a name is used; then every public name
    (``__all__``) and submodule is there, as when the package loaded them all at once."""
    code = """
import sys
import ccdcore.response as r
before = sorted(m for m in sys.modules if m.startswith("ccdcore.response."))
from ccdcore.response import response_of, METHODS, merge
from ccdcore.response import *
missing = [n for n in r.__all__ if n not in globals()]
import ccdcore.response.methods as m
print(before, missing, response_of is m.response_of, r.methods is m,
      r.tsin.estimate is r.estimate, set(r.__all__) <= set(dir(r)), hasattr(r, "no_such_name"))
"""
    out = _python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["[]", "[]", "True", "True", "True", "True", "False"]


@pytest.mark.parametrize("method", ["tsin", "debevec"])
def test_response_runs_end_to_end_in_a_fresh_process(tmp_path, method):
    """The verbs load what they need when they run: simulate a small bracket, estimate its
    response, each in its own interpreter (``python -m ccdcore.cli.command``)."""
    session = tmp_path / "tsin01"
    cli = [sys.executable, "-m", "ccdcore.cli"]
    out = subprocess.run(cli + ["simulate", "tsin01", str(session), "--size", "48x32"],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    out = subprocess.run(cli + ["response", str(session), "--method", method, "--bloom-radius",
                                "2", "--json"], capture_output=True, text=True, cwd=ROOT,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert res["method"] == method and res["channels"] == ["L"] and res["levels"] == 256
