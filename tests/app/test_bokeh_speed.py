"""app/static/bokeh_speed.js answers BokehJS's `--bk-*` visual lookups with "" without asking the
CSS cascade.  That is exact only while no stylesheet the app loads defines such a variable: these
tests keep it so, for the app's own CSS and for the Panel and Bokeh it runs on."""
from __future__ import annotations

import re
from pathlib import Path

import bokeh
import panel

import ccdcore_app

#: a visual property's CSS variable: --bk-[prefix-](line|fill|text|hatch)-NAME, being defined
VISUAL_VARIABLE = re.compile(r"--bk-[a-z0-9-]*?(?:line|fill|text|hatch)-[a-z-]+\s*:")


def _defined(paths) -> dict[str, list[str]]:
    found: dict[str, list[str]] = {}
    for path in paths:
        hits = VISUAL_VARIABLE.findall(Path(path).read_text(encoding="utf-8", errors="replace"))
        if hits:
            found[str(path)] = sorted(set(hits))
    return found


def test_the_pattern_finds_a_definition():
    assert VISUAL_VARIABLE.findall(":host { --bk-line-color: red; }") == ["--bk-line-color:"]
    assert VISUAL_VARIABLE.findall(".x{--bk-major-label-text-color :#333}") == \
        ["--bk-major-label-text-color :"]
    assert VISUAL_VARIABLE.findall("color: var(--bk-line-color);") == []   # a use, not a definition


def test_the_app_defines_no_bokeh_visual_variable():
    root = Path(ccdcore_app.__file__).resolve().parent
    files = [*root.rglob("*.py"), *root.rglob("*.css"), *root.rglob("*.js")]
    assert files
    assert _defined(files) == {}


def test_panel_and_bokeh_define_no_bokeh_visual_variable():
    bokeh_static = Path(bokeh.__file__).resolve().parent / "server" / "static"
    panel_dist = Path(panel.__file__).resolve().parent / "dist"
    files = [*bokeh_static.rglob("*.min.js"), *bokeh_static.rglob("*.css"),
             *panel_dist.rglob("*.css"), *(panel_dist / "panel.min.js",)]
    assert len(files) > 5
    assert _defined(files) == {}
