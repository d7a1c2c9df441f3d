"""The report's package boundary: ``ccdcore_report`` is Bokeh only, so the CLI's ``report`` verb
loads neither Panel, HoloViews nor the app.

That ``ccdcore report SESSION -o out.html`` works through ``ccdcore.cli.command.main`` on the
bundled
healey94 is checked by tests/test_report.py (its ``h94`` fixture and the tests using it)."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FORBIDDEN = ("panel", "holoviews", "ccdcore_app")


def test_the_report_path_of_the_cli_loads_no_app_or_panel(tmp_path):
    """In a fresh interpreter: import the package and the CLI, run the report verb on the demo
    (its lazy imports included), then none of Panel, HoloViews or the app is loaded."""
    out = tmp_path / "r.html"
    code = (
        "import sys\n"
        "import ccdcore_report, ccdcore.cli.command\n"
        f"rc = ccdcore.cli.command.main(['report', {str(ROOT / 'assets' / 'healey94')!r}, '-o', "
        f"{str(out)!r}])\n"
        f"bad = sorted(n for n in sys.modules if n.split('.')[0] in {FORBIDDEN!r})\n"
        "print(rc, ','.join(bad))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, check=True)
    assert proc.stdout.splitlines()[-1] == "0 ", proc.stdout + proc.stderr
    assert out.stat().st_size > 0


def _imported_modules(path: Path) -> set[str]:
    """Top-level names of every module ``path`` imports, at module level or inside functions."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
    return found


def test_no_module_of_the_report_imports_the_app_or_panel():
    """Also the imports of code paths a demo report does not take (lazy imports included)."""
    modules = sorted((ROOT / "report").rglob("*.py"))
    assert modules
    bad = {p.name: sorted(_imported_modules(p) & set(FORBIDDEN)) for p in modules}
    assert {k: v for k, v in bad.items() if v} == {}
