"""Plant small bugs in a module, one at a time, and see whether the tests catch each.

Run by hand from the project root (it edits a clone, never this tree)::

    python benchmarks/mutation.py ccdcore/ptc_fit.py ccdcore/emva/dark.py \
        --coverage /tmp/cov/.coverage --clone /tmp/mutclone --sample 40 --out mutants.json

Each mutant changes one expression, the way a plausible slip would: a comparison on the other side
of its bound (``<`` for ``<=``), an operator for its neighbour (``+``/``-``, ``*``/``/``), a power
dropped, a number moved (an integer by one, a float doubled), ``and``/``or``, a ``not`` dropped,
``all``/``any``, ``min``/``max``, ``mean``/``median`` or a square root dropped. The mutants are
drawn with a fixed seed *before* any test runs. For each one the script runs the tests that
execute its line (from a coverage database recorded with ``dynamic_context = test_function``;
lines run at import or by no recorded test, and numba kernels, which coverage cannot see, take
every test file importing their module), stops at the first failure, and counts the mutant caught
when a test fails or runs out of time.

``--patches DIR`` runs hand-planted bugs instead (one ``*.patch`` each, ``git diff`` format) with
every test file importing a changed module or running a changed line.

Why not mutmut: it rewrites every function into a trampoline, which breaks numba's compiled
kernels and our lazily loaded packages, and its stats pass runs the whole suite under its own
runner. This script is ~400 lines, edits only a throw-away clone, and uses the suite as it is.
"""
from __future__ import annotations

import argparse
import functools
import itertools
import ast
import json
import os
import random
import signal
import sqlite3
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SWAP_CMP = {ast.Lt: ast.LtE, ast.LtE: ast.Lt, ast.Gt: ast.GtE, ast.GtE: ast.Gt,
            ast.Eq: ast.NotEq, ast.NotEq: ast.Eq, ast.Is: ast.IsNot, ast.IsNot: ast.Is,
            ast.In: ast.NotIn, ast.NotIn: ast.In}
SWAP_BIN = {ast.Add: ast.Sub, ast.Sub: ast.Add, ast.Mult: ast.Div, ast.Div: ast.Mult,
            ast.FloorDiv: ast.Mult}
SWAP_NAME = {"all": "any", "any": "all", "min": "max", "max": "min", "mean": "median",
             "median": "mean", "nanmean": "nanmedian", "nanmedian": "nanmean", "nanmin": "nanmax",
             "nanmax": "nanmin", "minimum": "maximum", "maximum": "minimum", "sum": "mean"}
DROP_CALL = {"sqrt", "abs", "fabs", "square"}


@dataclass
class Mutant:
    module: str
    line: int
    kind: str
    before: str
    after: str
    start: tuple[int, int]
    end: tuple[int, int]
    status: str = "pending"
    tests: int = 0
    seconds: float = 0.0
    killer: str = ""


def _skip_lines(tree: ast.Module) -> set[int]:
    """Lines not worth mutating: docstrings, ``__all__``, logging and messages of raised errors."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        first = body[0] if isinstance(body, list) and body else None
        if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                and isinstance(first.value.value, str):
            skip.update(range(body[0].lineno, body[0].end_lineno + 1))
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__"
                                                for t in node.targets):
            skip.update(range(node.lineno, node.end_lineno + 1))
        if isinstance(node, ast.Raise) and node.exc is not None:
            skip.update(range(node.lineno, node.end_lineno + 1))
    return skip


def _in_fstring(tree: ast.Module) -> set[int]:
    ids: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.JoinedStr):
            ids.update(id(n) for n in ast.walk(node))
    return ids


def _variant(node: ast.AST) -> list[tuple[str, ast.AST]]:
    """The mutated copies of one expression node, each with its kind."""
    out: list[tuple[str, ast.AST]] = []
    if isinstance(node, ast.Compare):
        for i, op in enumerate(node.ops):
            if type(op) in SWAP_CMP:
                new = ast.Compare(node.left, list(node.ops), node.comparators)
                new.ops[i] = SWAP_CMP[type(op)]()
                out.append(("compare", new))
    elif isinstance(node, ast.BinOp):
        if type(node.op) in SWAP_BIN:
            out.append(("operator", ast.BinOp(node.left, SWAP_BIN[type(node.op)](), node.right)))
        elif isinstance(node.op, ast.Pow):
            out.append(("power", node.left))
    elif isinstance(node, ast.BoolOp):
        out.append(("boolean", ast.BoolOp(ast.Or() if isinstance(node.op, ast.And) else ast.And(),
                                          node.values)))
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
        out.append(("not", node.operand))
    elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub) \
            and isinstance(node.operand, ast.Constant):
        out.append(("sign", node.operand))
    elif isinstance(node, ast.Constant) and type(node.value) in (int, float) \
            and not isinstance(node.value, bool):
        value = node.value + 1 if isinstance(node.value, int) else \
            (node.value * 2 if node.value != 0 else 1.0)
        out.append(("number", ast.Constant(value)))
    elif isinstance(node, ast.Call):
        func = node.func
        name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
        if name in SWAP_NAME:
            new_name = SWAP_NAME[name]
            new_func = (ast.Attribute(func.value, new_name, ast.Load())
                        if isinstance(func, ast.Attribute) else ast.Name(new_name, ast.Load()))
            out.append(("function", ast.Call(new_func, node.args, node.keywords)))
        if name in DROP_CALL and len(node.args) == 1 and not node.keywords:
            out.append(("dropped call", node.args[0]))
    return out


def enumerate_mutants(path: Path) -> list[Mutant]:
    source = path.read_text()
    tree = ast.parse(source)
    skip = _skip_lines(tree)
    in_f = _in_fstring(tree)
    annotations: set[int] = set()
    for node in ast.walk(tree):
        for ann in (getattr(node, "annotation", None), getattr(node, "returns", None)):
            if ann is not None:
                annotations.update(id(n) for n in ast.walk(ann))
    rel = str(path.resolve().relative_to(ROOT))
    out = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.expr) or id(node) in in_f or id(node) in annotations:
            continue
        if node.lineno in skip:
            continue
        before = ast.get_source_segment(source, node)
        if before is None:
            continue
        for kind, new in _variant(node):
            after = "(" + ast.unparse(ast.fix_missing_locations(new)) + ")"
            out.append(Mutant(rel, node.lineno, kind, before, after,
                              (node.lineno, node.col_offset),
                              (node.end_lineno, node.end_col_offset)))
    return out


def apply(source: str, m: Mutant) -> str:
    lines = source.splitlines(keepends=True)
    offsets = [0]
    for line in lines:
        offsets.append(offsets[-1] + len(line))

    def pos(line: int, col: int) -> int:   # ast columns are UTF-8 byte offsets
        text = lines[line - 1].encode()[:col].decode(errors="ignore")
        return offsets[line - 1] + len(text)
    a, b = pos(*m.start), pos(*m.end)
    return source[:a] + m.after + source[b:]


@functools.lru_cache(maxsize=None)
def _line_contexts(db: Path, module: str) -> dict[int, frozenset[str]]:
    """Every line of ``module`` that the recorded suite ran, with the contexts (test functions;
    "" for import time) that ran it: the database is read once a module."""
    from coverage.numbits import numbits_to_nums
    con = sqlite3.connect(db)
    try:
        rows = con.execute(
            "select c.context, l.numbits from line_bits l join file f on f.id = l.file_id "
            "join context c on c.id = l.context_id where f.path like ?", ("%/" + module,)
        ).fetchall()
    finally:
        con.close()
    by_line: dict[int, set[str]] = {}
    for context, numbits in rows:
        for line in numbits_to_nums(numbits):
            by_line.setdefault(line, set()).add(context.split("|")[0] if context else "")
    return {line: frozenset(c) for line, c in by_line.items()}


def covering_tests(db: Path | None, module: str, line: int,
                   fallback: Sequence[str]) -> Sequence[str]:
    """Test node ids that ran ``module:line``, from coverage's contexts; a line run at import
    is reached by every test file importing the module."""
    if db is None:
        return fallback
    contexts = _line_contexts(db, module).get(line, frozenset())
    found = {_node_id(c) for c in contexts if c} - {""}
    if "" in contexts:
        found |= set(importers(module))
    return sorted(found) or fallback


def _node_id(context: str) -> str:
    parts = context.split(".")
    for base in (ROOT, ROOT / "tests", ROOT / "tests" / "app"):
        for i in range(len(parts), 0, -1):
            path = Path(base, *parts[:i]).with_suffix(".py")
            if path.is_file():
                return str(path.relative_to(ROOT)) + "::" + "::".join(parts[i:])
    return ""


@functools.lru_cache(maxsize=None)
def _imported(test: Path) -> frozenset[str]:
    """The dotted names a test file imports: ``from X import a, b`` gives X, X.a and X.b."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(test.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
    return frozenset(names)


@functools.lru_cache(maxsize=None)
def importers(module: str) -> tuple[str, ...]:
    """Test files that import ``module`` or a name of its package (whose ``__init__`` may hand
    out the module's functions); ``app/`` and ``report/`` count as ``ccdcore_app`` and
    ``ccdcore_report``."""
    dotted = module.removesuffix(".py").replace("/", ".").removesuffix(".__init__")
    dotted = dotted.replace("app.", "ccdcore_app.", 1) if dotted.startswith("app.") else dotted
    dotted = dotted.replace("report.", "ccdcore_report.", 1) \
        if dotted.startswith("report.") else dotted
    package = dotted.rsplit(".", 1)[0]
    hits = []
    for test in sorted((ROOT / "tests").rglob("test_*.py")):
        names = _imported(test)
        if dotted in names or package in names:
            hits.append(str(test.relative_to(ROOT)))
    return tuple(hits)


def _verdict(code: int) -> str:
    """pytest's exit code as a verdict: a failure (1), a collection error the bug caused (2) or
    a crash (a signal) catch the bug; 0 lets it survive; anything else (no tests, a usage
    error) says nothing of it."""
    if code == 0:
        return "survived"
    if code in (1, 2) or code < 0:
        return "caught"
    return f"pytest exit {code}"


def _app_last(test: str) -> tuple[bool, str]:
    """The app's and browser tests are the slowest: run them after the library's."""
    return test.startswith("tests/app/"), test


def run(m: Mutant, clone: Path, tests: list[str], timeout: float) -> None:
    target = clone / m.module
    original = target.read_text()
    target.write_text(apply(original, m))
    try:
        compile(target.read_text(), str(target), "exec")
    except SyntaxError:
        target.write_text(original)
        m.status = "invalid"
        return
    t0 = time.perf_counter()
    tests = [t for t in tests if (clone / t.split("::")[0]).is_file()]
    m.tests = len(tests)
    try:
        if not tests:
            m.status = "not run by any test"
            return
        proc = subprocess.run(
            [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
             "-p", "no:randomly", *sorted(tests, key=_app_last)], cwd=clone,
            capture_output=True, text=True, timeout=timeout,
            env={**os.environ, "PYTHONPATH": str(clone)})
        m.status = _verdict(proc.returncode)
        failed = [ln for ln in proc.stdout.splitlines() if ln.startswith(("FAILED", "ERROR"))]
        m.killer = failed[0] if failed else (proc.stdout + proc.stderr).strip()[-300:]
    except subprocess.TimeoutExpired:
        m.status = "caught"
        m.killer = "timeout"
    finally:
        target.write_text(original)
        m.seconds = round(time.perf_counter() - t0, 1)


def _patch_targets(patch: Path) -> list[tuple[str, list[int]]]:
    """The modules a unified diff changes, with the new-side lines of each hunk."""
    out: list[tuple[str, list[int]]] = []
    for line in patch.read_text().splitlines():
        if line.startswith("+++ b/"):
            out.append((line[6:], []))
        elif line.startswith("@@") and out:
            new = line.split("+")[1].split(" ")[0].split(",")
            start, count = int(new[0]), int(new[1]) if len(new) > 1 else 1
            out[-1][1].extend(range(start, start + count))
    return out


def run_patches(folder: Path, clone: Path, db: Path | None, timeout: float, out: Path) -> int:
    """Apply each ``*.patch`` of ``folder`` to the clone in turn and run the tests that reach it:
    those that ran its changed lines (coverage contexts) and every test file importing its
    module. A hand-planted bug is counted as a mutant is."""
    results = json.loads(out.read_text()) if out.exists() else []
    done = {r["module"] for r in results}
    for patch in sorted(folder.glob("*.patch")):
        if patch.name in done:
            continue
        tests: set[str] = set()
        for module, lines in _patch_targets(patch):
            tests.update(importers(module))
            for ln in lines:
                tests.update(covering_tests(db, module, ln, []))
        files = {t.split("::")[0] for t in tests if (clone / t.split("::")[0]).is_file()}
        m = Mutant(patch.name, 0, "patch", "", "", (0, 0), (0, 0))
        subprocess.run(["git", "apply", str(patch.resolve())], cwd=clone, check=True)
        try:
            m.tests = len(tests)
            t0 = time.perf_counter()
            try:
                proc = subprocess.run(
                    [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
                     *sorted(files, key=_app_last)], cwd=clone, capture_output=True,
                    text=True, timeout=timeout, env={**os.environ, "PYTHONPATH": str(clone)})
                m.status = _verdict(proc.returncode)
                failed = [ln for ln in proc.stdout.splitlines()
                          if ln.startswith(("FAILED", "ERROR"))]
                m.killer = failed[0] if failed else proc.stdout.strip().splitlines()[-1]
            except subprocess.TimeoutExpired:
                m.status, m.killer = "caught", "timeout"
            m.seconds = round(time.perf_counter() - t0, 1)
        finally:
            subprocess.run(["git", "checkout", "--", "."], cwd=clone, check=True)
        results.append(asdict(m))
        out.write_text(json.dumps(results, indent=1))
        print(f"{m.status:9s} {patch.name} ({len(files)} files, {m.seconds}s) {m.killer[:90]}",
              flush=True)
    caught = sum(r["status"] == "caught" for r in results)
    print(f"caught {caught} of {len(results)} ({100 * caught / max(len(results), 1):.1f} %)")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("modules", nargs="*", type=Path)
    p.add_argument("--patches", type=Path, help="a folder of hand-planted *.patch files to run")
    p.add_argument("--coverage", type=Path, help="coverage data file with test contexts")
    p.add_argument("--clone", type=Path, required=True, help="a git clone to edit")
    p.add_argument("--sample", type=int, default=30, help="mutants per module (0: all)")
    p.add_argument("--seed", type=int, default=1288)
    p.add_argument("--timeout", type=float, default=400.0)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--limit", type=int, default=0, help="run only the first N drawn mutants")
    p.add_argument("--list", action="store_true", help="only list the drawn mutants")
    a = p.parse_args(argv)
    # a kill must still restore the clone's file (``run``'s ``finally``)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    if a.clone.resolve() == ROOT:
        p.error("--clone must be a throw-away clone, not this tree")
    if a.patches:
        return run_patches(a.patches, a.clone, a.coverage, a.timeout, a.out)
    rng = random.Random(a.seed)
    drawn: list = []
    for module in a.modules:
        ms = enumerate_mutants(module.resolve())
        if a.sample and len(ms) > a.sample:
            ms = rng.sample(ms, a.sample)
        drawn.append(sorted(ms, key=lambda m: (m.line, m.kind)))
    # round robin over the modules, so that a run cut short has sampled every one
    drawn = [m for group in itertools.zip_longest(*drawn) for m in group if m is not None]
    if a.limit:
        drawn = drawn[:a.limit]
    if a.list:
        for m in drawn:
            print(f"{m.module}:{m.line} {m.kind}: {m.before!r} -> {m.after!r}")
        return 0
    done = {}
    if a.out.exists():
        done = {(d["module"], d["line"], d["before"], d["after"]): d
                for d in json.loads(a.out.read_text())}
    results = []
    for i, m in enumerate(drawn):
        key = (m.module, m.line, m.before, m.after)
        if key in done and done[key]["status"] != "pending":
            results.append(done[key])
            continue
        fallback = importers(m.module)
        if "kernels" in m.module or "numba" in (ROOT / m.module).read_text():
            tests = sorted(set(covering_tests(a.coverage, m.module, m.line, [])) | set(fallback))
        else:
            tests = covering_tests(a.coverage, m.module, m.line, fallback)
        run(m, a.clone, tests, a.timeout)
        results.append(asdict(m))
        tmp = a.out.with_suffix(".tmp")
        tmp.write_text(json.dumps(results, indent=1))
        tmp.replace(a.out)
        print(f"[{i + 1}/{len(drawn)}] {m.status:9s} {m.module}:{m.line} {m.kind}: "
              f"{m.before[:50]!r} -> {m.after[:50]!r} ({m.tests} tests, {m.seconds}s)",
              flush=True)
    counted = [r for r in results if r["status"] in ("caught", "survived", "not run by any test")]
    caught = sum(r["status"] == "caught" for r in counted)
    print(f"caught {caught} of {len(counted)} ({100 * caught / max(len(counted), 1):.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
