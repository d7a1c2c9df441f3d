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


def _module_imports(root: Path, package: str | None = None
                    ) -> dict[str, list[tuple[str, str | None]]]:
    """Module name -> (imported module, imported name) of every import of a module of the
    package in folder ``root`` (named ``package``, else the folder's name) it makes: at module
    level and inside functions, methods and ``if`` blocks alike (the whole AST is walked, since a
    lazy import inside a function still runs and still makes an arrow). ``from m import n`` gives
    (m, n), relative imports resolved against the module's package;
    ``import m`` gives (m, None)."""
    import ast

    top = package or root.name
    out: dict[str, list[tuple[str, str | None]]] = {}
    for path in sorted(root.rglob("*.py")):
        parts = (top, *path.relative_to(root).with_suffix("").parts)
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        package = name if parts[-1] == "__init__" else name.rsplit(".", 1)[0]
        found: list[tuple[str, str | None]] = []
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = package
                for _ in range(node.level - 1):
                    base = base.rsplit(".", 1)[0]
                mod = (f"{base}.{node.module}" if node.module else base) if node.level else (
                    node.module or "")
                found += [(mod, a.name) for a in node.names]
            elif isinstance(node, ast.Import):
                found += [(a.name, None) for a in node.names]
        out[name] = [(mod, n) for mod, n in found if mod.split(".")[0] == top]
    return out


ROOT = Path(__file__).resolve().parents[1] / "ccdcore"


def _private_imports(modules: dict[str, list[tuple[str, str | None]]]) -> list[str]:
    """``<module> imports <name> from <source>`` for every name starting with ``_`` that one
    ccdcore module imports from another, wherever the import is (module level or inside a
    function); allowed: a private module of a package (``from . import _det``), the names of a
    private module (``from ._common import round_sig``) and ``__version__``."""
    bad = []
    for mod, imports in modules.items():
        for src, name in imports:
            if name is None:                     # ``import a.b.c`` names modules only
                continue
            if (name.startswith("_") and name != "__version__"
                    and f"{src}.{name}" not in modules      # a package's private module is fine
                    and not src.rsplit(".", 1)[-1].startswith("_")   # so are its own names
                    and src != mod):
                bad.append(f"{mod} imports {name} from {src}")
    return bad


def test_no_private_name_is_imported_across_modules():
    modules = _module_imports(ROOT)
    bad = _private_imports(modules)
    assert bad == [], "private names imported across modules:\n" + "\n".join(bad)


def _import_graph(imports: dict[str, list[tuple[str, str | None]]]) -> dict[str, set[str]]:
    """Module -> the ccdcore modules it imports: ``from p import m`` of a submodule ``m`` is an
    arrow to ``p.m``, any other name an arrow to ``p``; a package importing its own submodules
    is how packages work, not an arrow."""
    graph = {}
    for m, deps in imports.items():
        targets = {src if name is None or f"{src}.{name}" not in imports else f"{src}.{name}"
                   for src, name in deps}
        graph[m] = {n for n in targets & set(imports) - {m} if not n.startswith(m + ".")}
    return graph


def _find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as ``[a, b, ..., a]``, or None."""
    state: dict[str, int] = {}            # 1: on the current path, 2: done

    def visit(m: str, path: list[str]) -> list[str] | None:
        state[m] = 1
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return path[path.index(n):] + [n]
            if n not in state:
                found = visit(n, path + [n])
                if found:
                    return found
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            found = visit(m, [m])
            if found:
                return found
    return None


def test_ccdcore_has_no_import_cycle():
    cycle = _find_cycle(_import_graph(_module_imports(ROOT)))
    assert cycle is None, "import cycle (imports inside functions count): " + " -> ".join(cycle)


def test_the_app_and_the_report_have_no_import_cycle():
    """The same check on the browser app (``app/``, package ``ccdcore_app``) and the report
    (``report/``, package ``ccdcore_report``)."""
    for folder, package in (("app", "ccdcore_app"), ("report", "ccdcore_report")):
        imports = _module_imports(ROOT.parent / folder, package)
        assert len(imports) > 5, f"no modules found in {folder}/"
        cycle = _find_cycle(_import_graph(imports))
        assert cycle is None, f"import cycle in {folder}/: " + " -> ".join(cycle)


def test_the_checks_see_imports_inside_functions(tmp_path):
    """The two checks read function bodies and ``import`` statements: a lazy import closing a
    cycle and a private name imported inside a method are both found."""
    pkg = tmp_path / "ccdcore"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from . import a\n")
    (pkg / "a.py").write_text("def f():\n    from .b import g\n    return g\n")
    (pkg / "b.py").write_text("import ccdcore.sub.c\n\ndef g():\n    pass\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "c.py").write_text("class C:\n    def m(self):\n"
                                      "        from ..a import _hidden, f\n")
    imports = _module_imports(pkg)
    assert _find_cycle(_import_graph(imports)) == ["ccdcore.a", "ccdcore.b", "ccdcore.sub.c",
                                                   "ccdcore.a"]
    assert _private_imports(imports) == ["ccdcore.sub.c imports _hidden from ccdcore.a"]


#: the modules that run reductions over frames: they take a ``reducer`` (ccdcore.reduce)
ESTIMATORS = ("ccdcore.dark.frame", "ccdcore.noise", "ccdcore.fixedpattern",
              "ccdcore.flatfield.fit", "ccdcore.response.hdr", "ccdcore.change.detector",
              "ccdcore.product.make", "ccdcore.reduce")


def _all_imports(path: Path) -> set[str]:
    """Every module an import statement of ``path`` names, anywhere in the file."""
    import ast

    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            found.add(("." * node.level) + (node.module or ""))
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return found


def test_estimators_take_a_reducer_and_never_see_dask():
    """No estimator imports Dask or ccdcore.distributed, even inside a function, and none has a
    parameter named ``client``: where the reductions run is the reducer's business."""
    import ast

    for name in ESTIMATORS:
        path = ROOT.parent / (name.replace(".", "/") + ".py")
        mods = _all_imports(path)
        bad = sorted(m for m in mods if m.lstrip(".").split(".")[0] in ("dask", "distributed")
                     or "distributed" in m.lstrip(".").split("."))
        assert bad == [], f"{name} imports {bad}"
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                params = [a.arg for a in node.args.args + node.args.kwonlyargs]
                assert "client" not in params, f"{name}.{node.name} takes a client"


def test_an_estimator_runs_on_the_reducer_it_is_given():
    """A reducer of one's own (here one that counts and then streams) is the one the dark
    reference, the photon transfer and K̂ use, for every frame."""
    from ccdcore.dark.frame import dark_reference
    from ccdcore.fixedpattern import fixed_pattern_map
    from ccdcore.noise import photon_transfer
    from ccdcore.reduce import STREAMED, Reducer

    calls: list[str] = []

    class Counting(Reducer):
        def moments(self, frames, **kw):
            calls.append("moments")
            return super().moments(frames, **kw)

        def pair_stats(self, session, paired, **kw):
            calls.append("pairs")
            return super().pair_stats(session, paired, **kw)

        def frame_sums(self, session, records, **kw):
            calls.append("sums")
            return super().frame_sums(session, records, **kw)

        def fixed_pattern(self, source, **kw):
            calls.append("kmap")
            return super().fixed_pattern(source, **kw)

    healey = ROOT.parent / "assets" / "healey94"
    counting = Counting()
    a, b = dark_reference(healey_session(healey)), dark_reference(healey_session(healey),
                                                                  reducer=counting)
    assert a.mean_map.tobytes() == b.mean_map.tobytes() and calls == ["moments"]
    pt = photon_transfer(healey, reducer=counting)
    # (the manifest gives the black level: no dark sums)
    assert pt.A == photon_transfer(healey, reducer=STREAMED).A and calls[1:] == ["pairs"]
    k = fixed_pattern_map(healey_session(healey), reducer=counting)
    # K̂ asks its reducer for the dark reference too
    assert calls[2:] == ["kmap", "moments"] and k.K.shape == a.mean_map.shape


def healey_session(path):
    from ccdcore.session import open_session

    return open_session(path)
