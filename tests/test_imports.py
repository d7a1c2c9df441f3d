"""ccdcore must not pull in a UI package (dependencies point app -> ccdcore only)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

UI_PACKAGES = ("panel", "holoviews", "bokeh", "ccdcore_app")


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


def _module_imports(root: Path) -> dict[str, list[tuple[str, str]]]:
    """Module name -> (imported module, imported name) of its module-level ``from`` imports
    inside ccdcore (relative imports resolved)."""
    import ast

    out: dict[str, list[tuple[str, str]]] = {}
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        package = name if parts[-1] == "__init__" else name.rsplit(".", 1)[0]
        found = []
        for node in ast.parse(path.read_text()).body:   # module level only: lazy imports allowed
            if isinstance(node, ast.ImportFrom):
                base = package
                for _ in range(node.level - 1):
                    base = base.rsplit(".", 1)[0]
                mod = (f"{base}.{node.module}" if node.module else base) if node.level else (
                    node.module or "")
                found += [(mod, a.name) for a in node.names]
        out[name] = found
    return out


ROOT = Path(__file__).resolve().parents[1] / "ccdcore"


def test_no_private_name_is_imported_across_modules():
    modules = _module_imports(ROOT)
    bad = [f"{mod} imports {name} from {src}" for mod, imports in modules.items()
           for src, name in imports
           if src.startswith("ccdcore") and name.startswith("_") and name != "__version__"
           and f"{src}.{name}" not in modules      # a package's private module is fine
           and not src.rsplit(".", 1)[-1].startswith("_")]
    assert bad == []


def test_ccdcore_has_no_import_cycle():
    imports = _module_imports(ROOT)
    graph = {m: {src if src in imports else f"{src}.{name}" for src, name in deps}
             & set(imports) - {m} for m, deps in imports.items()}
    state: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for n in sorted(graph[m]):
            if n.startswith(m + "."):
                continue   # a package importing its own submodules is how packages work
            assert state.get(n) != 1, "import cycle: " + " -> ".join(path + [n])
            if n not in state:
                visit(n, path + [n])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])
