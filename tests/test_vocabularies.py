"""Closed vocabularies live in one place each: Bayer layouts (``channels.is_bayer``), validation
problem codes (``session.records.ProblemCode`` and its fixes, the table in docs/session.md) and
gate verdicts (``guide.GateStatus``)."""
from __future__ import annotations

import ast
import dataclasses
import json
import re
from pathlib import Path

import pytest

from ccdcore import channels, guide
from ccdcore.errors import CcdError
from ccdcore.session import Problem, ProblemCode
from ccdcore.session import records as session_records

ROOT = Path(__file__).resolve().parents[1]
SOURCES = sorted((ROOT / "ccdcore").rglob("*.py"))
BAYER = {"bayer-rggb", "bayer-bggr", "bayer-grbg", "bayer-gbrg"}


# ------------------------------------------------------------------------------ layouts -----
@pytest.mark.parametrize("layout", channels.LAYOUTS)
def test_is_bayer_on_every_layout(layout):
    assert channels.is_bayer(layout) is (layout in BAYER)
    # the same answer as the layout's channels: the four CFA planes exactly for a mosaic
    assert channels.is_bayer(layout) is (channels.channel_names(layout) == channels.PLANES)


def test_the_bayer_layouts_are_the_patterns():
    assert {lay for lay in channels.LAYOUTS if channels.is_bayer(lay)} == BAYER
    assert BAYER == {f"bayer-{p}" for p in channels.PATTERNS}


@pytest.mark.parametrize("spelling, bayer", [("BAYER-RGGB", True), (" bayer-gbrg ", True),
                                             ("rggb", True), ("GRBG", True), ("Mono", False),
                                             (" RGB", False)])
def test_is_bayer_reads_names_as_the_other_functions_do(spelling, bayer):
    assert channels.is_bayer(spelling) is bayer
    assert channels.channel_names(spelling) == (channels.PLANES if bayer else
                                                channels.channel_names(spelling.strip()))


@pytest.mark.parametrize("name", ["", "bayer", "bayer-", "bayer-xyzw", "bayerish", "rgba",
                                  "4-channel", "cmyk", None, 3, ("mono",)])
def test_is_bayer_refuses_unknown_names_as_channel_names_does(name):
    with pytest.raises(CcdError) as want:
        channels.channel_names(name)
    with pytest.raises(CcdError) as got:
        channels.is_bayer(name)
    assert (got.value.where, got.value.problem) == (want.value.where, want.value.problem)


def test_is_bayer_is_public():
    assert "is_bayer" in channels.__all__


def test_no_layout_name_is_matched_by_its_spelling():
    """``startswith("bayer")`` on a layout is what :func:`channels.is_bayer` replaces."""
    bad = [f"{p.relative_to(ROOT)}:{i}" for p in SOURCES
           for i, line in enumerate(p.read_text().splitlines(), 1)
           if re.search(r"""startswith\(\s*["']bayer["']\s*\)""", line)]
    assert bad == []


def test_layouts_are_an_enum_written_as_their_names(tmp_path):
    """Layout is a string enum: LAYOUTS are its names, check_layout returns a member, and a
    member compares equal to, prints as, and is written to JSON and TOML as its name."""
    import tomllib

    import tomli_w

    assert channels.LAYOUTS == tuple(m.value for m in channels.Layout)
    assert channels.check_layout((4, 6), None) is channels.Layout.MONO
    assert channels.check_layout((4, 6, 3), "RGB ") is channels.Layout.RGB
    assert channels.check_layout((4, 6), "grbg") is channels.Layout.BAYER_GRBG
    assert channels.Layout.MONO == "mono" and str(channels.Layout.BAYER_RGGB) == "bayer-rggb"
    assert json.loads(json.dumps({"layout": channels.Layout.RGB})) == {"layout": "rgb"}
    text = tomli_w.dumps({"camera": {"layout": channels.Layout.BAYER_BGGR}})
    assert tomllib.loads(text) == {"camera": {"layout": "bayer-bggr"}}


def test_no_layout_is_compared_with_a_spelled_name():
    """A layout is compared with a :class:`channels.Layout` member, never with its spelling."""
    every = SOURCES + sorted((ROOT / "app").rglob("*.py")) + sorted(
        (ROOT / "report").rglob("*.py"))
    bad = [f"{p.relative_to(ROOT)}:{i}" for p in every
           for i, line in enumerate(p.read_text().splitlines(), 1)
           if re.search(r"""layout\s*[!=]=\s*["'](mono|rgb|bayer-\w+)["']""", line)]
    assert bad == []


# ------------------------------------------------------------------------ problem codes -----
def test_every_problem_code_has_a_fix():
    assert len(ProblemCode) > 0
    for code in ProblemCode:
        assert isinstance(code, str) and code == code.value and str(code) == code.value
        assert re.fullmatch(r"[a-z]+(-[a-z]+)*", code.value), code
        assert isinstance(code.fix, str) and code.fix.strip(), code
    assert len({c.value for c in ProblemCode}) == len(ProblemCode)


def test_guide_fixes_are_the_enums():
    assert guide.FIXES == {c.value: c.fix for c in ProblemCode}
    assert all(type(k) is str for k in guide.FIXES)
    for code in ProblemCode:   # looked up by member or by its string alike
        assert guide.FIXES[code] == guide.FIXES[code.value] == code.fix


def test_a_problem_takes_only_a_problem_code():
    p = Problem("a.tif", "file not found", code=ProblemCode.FILE_NOT_FOUND, roles=("dark",))
    assert p.code is ProblemCode.FILE_NOT_FOUND and p.code == "file-not-found"
    for bad in ("no-such-code", "", "File-Not-Found", "invalid"):
        with pytest.raises(ValueError, match="ProblemCode"):
            Problem("a.tif", "x", code=bad)
    for bad in (None, 3, b"duplicate"):
        with pytest.raises(TypeError, match="ProblemCode"):
            Problem("a.tif", "x", code=bad)
    with pytest.raises(TypeError):
        Problem("a.tif", "x")   # no code: required
    with pytest.raises(ValueError):
        ProblemCode("no-such-code")


def test_a_problem_read_back_from_its_dict_has_the_member():
    """What a cache or a JSON reader rebuilds from the plain fields is the same problem."""
    for code in ProblemCode:
        p = Problem("w", "m", "warning", code=code, roles=("scene",))
        plain = {f.name: json.loads(json.dumps(getattr(p, f.name)))
                 for f in dataclasses.fields(p)}
        assert type(plain["code"]) is str
        back = Problem(**plain | {"roles": tuple(plain["roles"])})
        assert back == p and back.code is code


def test_the_serialised_problem_is_unchanged():
    p = Problem("a.tif", "m", "warning", code=ProblemCode.DEPRECATED_NOTE, roles=("flat",))
    d = p.to_dict()
    assert d == {"where": "a.tif", "message": "m", "severity": "warning",
                 "code": "deprecated-note", "roles": ["flat"]}
    assert type(d["code"]) is str
    assert json.loads(json.dumps(d)) == d
    assert f"{p.code}" == "deprecated-note" and json.dumps(p.code) == '"deprecated-note"'


def _problem_calls() -> list[tuple[str, ast.Call]]:
    out = []
    for path in SOURCES:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "Problem":
                out.append((f"{path.relative_to(ROOT)}:{node.lineno}", node))
    return out


def test_every_problem_is_made_with_a_member():
    calls = _problem_calls()
    assert len(calls) > 20
    for where, call in calls:
        kw = {k.arg: k.value for k in call.keywords}
        assert "code" in kw, where
        assert not isinstance(kw["code"], ast.Constant), f"{where}: a bare code"
        if isinstance(kw["code"], ast.Attribute):
            assert getattr(kw["code"].value, "id", None) == "ProblemCode", where


def _code_references() -> dict[str, list[str]]:
    """``ProblemCode.NAME`` -> where ccdcore names it (outside the enum's own body)."""
    refs: dict[str, list[str]] = {}
    for path in SOURCES:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and getattr(node.value, "id", None) == \
                    "ProblemCode" and node.attr.isupper():
                refs.setdefault(node.attr, []).append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return refs


def test_every_code_emitted_is_a_member_and_every_member_is_emitted():
    refs = _code_references()
    assert set(refs) - set(ProblemCode.__members__) == set()      # no unknown member named
    assert set(ProblemCode.__members__) - set(refs) == set()      # no member never used


def test_no_bare_code_string_is_passed_for_a_problem():
    """The helpers that pass a code on (``assemble``'s ``once``, its path-code table) get
    members too: no string literal equal to a code stands next to ``code=`` or in a call of
    ``once``."""
    values = {c.value for c in ProblemCode}
    path = ROOT / "ccdcore" / "session" / "assemble.py"
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "once":
            assert not any(isinstance(a, ast.Constant) and a.value in values
                           for a in node.args), node.lineno
        if isinstance(node, ast.Dict):
            assert not any(isinstance(v, ast.Constant) and v.value in values
                           for v in node.values), node.lineno


def _docs_problem_table() -> list[list[str]]:
    text = (ROOT / "docs" / "session.md").read_text()
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines)
                 if re.match(r"\|\s*code\s*\|\s*severity\s*\|", line))
    header = [c.strip() for c in lines[start].strip().strip("|").split("|")]
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        assert len(cells) == len(header), line
        rows.append(cells)
    assert header[:3] == ["code", "severity", "meaning"]
    return [header] + rows


def test_docs_table_lists_exactly_the_codes_with_their_fixes():
    header, *rows = _docs_problem_table()
    listed = [c for row in rows for c in re.findall(r"`([^`]+)`", row[0])]
    assert len(listed) == len(set(listed)), "a code listed twice"
    assert set(listed) == {c.value for c in ProblemCode}
    assert "fix" in header
    fix = header.index("fix")
    for row in rows:
        (code,) = re.findall(r"`([^`]+)`", row[0])
        assert row[1] in ("error", "warning"), row
        assert row[fix] == ProblemCode(code).fix, code


def test_problem_code_lives_in_records():
    assert session_records.ProblemCode is ProblemCode
    assert "ProblemCode" in session_records.__all__


# -------------------------------------------------------------------------- gate status -----
def test_gate_status_members():
    assert [s.value for s in guide.GateStatus] == ["pass", "warn", "fail", "skip"]
    assert "GateStatus" in guide.__all__


@pytest.mark.parametrize("status", ["pass", "warn", "fail", "skip"])
def test_a_gate_reads_a_bare_status_as_its_member(status):
    gate = guide.Gate(status, "summary")
    assert gate.status is guide.GateStatus(status) and gate.status == status
    d = gate.to_dict()
    assert d["status"] == status and type(d["status"]) is str
    assert json.loads(json.dumps(d))["status"] == status
    assert f"{gate.status}" == status
    assert {"pass": 1, "warn": 2, "fail": 3, "skip": 4}[gate.status]   # the app's lookups


@pytest.mark.parametrize("status", ["passed", "failed", "warning", "", None, "PASS"])
def test_a_gate_refuses_an_unknown_status(status):
    with pytest.raises(ValueError):
        guide.Gate(status, "summary")


def test_guide_makes_gates_with_members_only():
    tree = ast.parse((ROOT / "ccdcore" / "guide.py").read_text())
    statuses = {s.value for s in guide.GateStatus}
    bad = [n.lineno for n in ast.walk(tree)
           if isinstance(n, ast.Call) and getattr(n.func, "id", None) == "Gate"
           and n.args and isinstance(n.args[0], ast.Constant)]
    bad += [n.lineno for n in ast.walk(tree)
            if isinstance(n, ast.Compare) and any(isinstance(c, ast.Constant) and c.value in
                                                  statuses for c in n.comparators)]
    assert bad == []
