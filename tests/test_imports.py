"""ccdcore must not pull in a UI package (dependencies point app -> ccdcore only)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

UI_PACKAGES = ("panel", "holoviews", "bokeh", "app")


def test_importing_ccdcore_imports_no_ui_package():
    code = (
        "import sys, importlib, pkgutil, ccdcore\n"
        "for m in pkgutil.walk_packages(ccdcore.__path__, 'ccdcore.'):\n"
        "    importlib.import_module(m.name)\n"
        f"bad = sorted(n for n in sys.modules if n.split('.')[0] in {UI_PACKAGES!r})\n"
        "print(','.join(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == "", f"ccdcore imported UI packages: {out.stdout.strip()}"
