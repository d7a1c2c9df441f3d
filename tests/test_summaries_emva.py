"""Tests of the records of the EMVA 1288 figures (``ccdcore.emva.results.EmvaSummary`` and the
records it nests from ``ccdcore.emva.dark`` and ``ccdcore.emva.spatial``): every summary
round-trips through JSON, its JSON is what the result's ``to_dict()`` gives (and what the
figures' attributes gave through ``json_safe`` before the records), a damaged object is refused
with the key's path, and ``rows()`` carry the figures (for ``EmvaSummary``: the headline
figures of the datasheet, :data:`ccdcore.emva.sheet.HEADLINE` of
:func:`ccdcore.emva.sheet.datasheet_rows`, those determined, under their symbols).

The figures are computed fresh: on the demo session ``assets/emva1288`` and on a small
simulated session (``ccdcore.simulate``, fixed seed), with the ``None`` branches (no spatial
sets, no dark current, no split, no PRNU) made by replacing fields.
"""
from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ccdcore.common import json_safe
from ccdcore.emva.datasheet import EmvaFigures, emva_figures
from ccdcore.emva.dark import DarkCurrentSummary, DarkLineSummary, dark_current
from ccdcore.emva.results import (DarkPointSummary, EmvaPointSummary, EmvaSummary,
                                  SnrCurveSummary, SpatialSetSummary)
from ccdcore.emva.sheet import DATASHEET, HEADLINE, datasheet_rows
from ccdcore.emva.spatial import (NonuniformitySplitSummary, SpatialPlotsSummary,
                                  VarianceSplitSummary, nonuniformity_split, variance_split)
from ccdcore.errors import CcdError
from ccdcore.records import Record
from ccdcore.simulate import simulate

DEMO = Path(__file__).resolve().parents[1] / "assets" / "emva1288"


# --------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def demo() -> EmvaFigures:
    """The demo session: every section (photon transfer, dark current, spatial sets)."""
    return emva_figures(DEMO)


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> EmvaFigures:
    """A small simulated session without photon transfer (``sigma_d_ptc`` ``None``)."""
    root = tmp_path_factory.mktemp("emva") / "s"
    simulate("emva1288", root, seed=3, size=(32, 24), steps=6, L=4)
    return emva_figures(root, with_ptc=False)


def _unresolved() -> Any:
    """A dark current whose mean falls with the exposure time: not determinable, with bounds
    and a poor-fit note."""
    return dark_current([0.1, 0.2, 0.3, 0.4], [10.0, 9.9, 9.8, 9.85], [0.01] * 4,
                        [1.0, 1.01, 0.99, 1.0], [0.02] * 4, 0.1, 0.001)


def _bounded_split() -> Any:
    """A split of two pattern-free images: every part not determinable, with its bound."""
    rng = np.random.default_rng(11)
    dark = variance_split(100.0 + rng.normal(0.0, 0.5, (24, 32)), 4.0, 16)
    bright = variance_split(900.0 + rng.normal(0.0, 0.5, (24, 32)), 4.0, 16)
    return nonuniformity_split(bright, dark, 0.1, 0.001)


@pytest.fixture(scope="module")
def cases(demo: EmvaFigures, sim: EmvaFigures) -> dict[str, EmvaFigures]:
    nan = float("nan")
    return {
        "demo": demo,
        "sim": sim,
        # no spatial sets, no dark current, no split, no plots; σ_d below the quantisation
        "none": dataclasses.replace(sim, spatial=None, spatial_dark=None, split=None,
                                    spatial_plots=None, dark_current=None, DSNU1288=None,
                                    DSNU1288_err=None, PRNU1288=None, PRNU1288_err=None,
                                    sigma_d=nan, sigma_d_err=nan, sigma_y_dark_err=nan),
        # PRNU not a number (no snr_total), a dark current below three exposure times (no
        # lines) and a split whose parts are bounds
        "degenerate": dataclasses.replace(
            sim, PRNU1288=nan, PRNU1288_err=nan,
            dark_current=dark_current([0.1, 0.1], [10.0, 10.1], [0.01] * 2, [1.0, 1.0],
                                      [0.02] * 2, 0.1, 0.001),
            split=_bounded_split()),
        "unresolved": dataclasses.replace(sim, dark_current=_unresolved()),
    }


def _text(d: Any) -> str:
    return json.dumps(d, allow_nan=False)


def _round_trip(cls: type[Record], s: Record) -> None:
    back = cls.from_dict(json.loads(_text(s.to_dict())), "calibration.json")
    assert back == s
    assert _text(back.to_dict()) == _text(s.to_dict())


def _plain(v: Any, path: str = "") -> None:
    """Every value of a summary is a plain Python value: records, tuples, dicts, str, bool,
    int, finite float or None."""
    if isinstance(v, Record):
        for f in dataclasses.fields(v):   # type: ignore[arg-type]
            _plain(getattr(v, f.name), f"{path}.{f.name}")
    elif isinstance(v, tuple):
        for x in v:
            _plain(x, path)
    elif isinstance(v, dict):
        for k, x in v.items():
            assert type(k) is str, path
            _plain(x, f"{path}.{k}")
    elif isinstance(v, float):
        assert type(v) is float and math.isfinite(v), path
    else:
        assert v is None or type(v) in (str, bool, int), (path, type(v))


# --------------------------------------------------------------------------------------------
# the JSON of before: the figures' attributes through json_safe, as to_dict() wrote them
# --------------------------------------------------------------------------------------------
def _attrs(obj: Any, names: tuple[str, ...] | None = None) -> dict[str, Any]:
    names = names or tuple(f.name for f in dataclasses.fields(obj))
    return {k: json_safe(getattr(obj, k)) for k in names}


def _old_split(split: Any) -> dict[str, Any]:
    out = {k: json_safe(v) for k, v in split.figures().items()}
    out["bounds"] = {k: json_safe(v) for k, v in split.bounds}
    out.update(dark=_attrs(split.dark), bright=_attrs(split.bright), notes=list(split.notes))
    return out


def _old_dark_current(dc: Any) -> dict[str, Any]:
    out = {k: json_safe(v) for k, v in dc.figures().items()}
    out.update(u_I_mean_bound=json_safe(dc.u_I_mean_bound),
               u_I_var_bound=json_safe(dc.u_I_var_bound),
               mean_line=None if dc.mean_line is None else _attrs(dc.mean_line),
               var_line=None if dc.var_line is None else _attrs(dc.var_line),
               exposures=json_safe(list(dc.exposures)), notes=list(dc.notes))
    return out


def _old_snr(f: EmvaFigures) -> dict[str, Any]:
    u_p = np.array([p.u_p for p in f.points])
    y = np.array([p.u_y - p.u_y_dark for p in f.points])
    s2 = np.array([p.s2_y for p in f.points])
    with np.errstate(divide="ignore", invalid="ignore"):
        measured = np.where(s2 > 0, y / np.sqrt(np.where(s2 > 0, s2, 1.0)), np.nan)
    eta = f.QE / 100.0
    base = f.sigma_d ** 2 + 1.0 / 12.0 / f.K ** 2 + eta * u_p
    out = {"u_p": json_safe(u_p), "snr": json_safe(measured),
           "snr_model": json_safe(eta * u_p / np.sqrt(base))}
    if f.DSNU1288 is not None and f.PRNU1288 is not None \
            and math.isfinite(f.DSNU1288) and math.isfinite(f.PRNU1288):
        total = base + f.DSNU1288 ** 2 + (f.PRNU1288 / 100.0 * eta * u_p) ** 2
        out["snr_total"] = json_safe(eta * u_p / np.sqrt(total))
    return out


_POINT_KEYS = ("level", "exposure", "u_p", "u_y", "u_y_err", "u_y_dark", "s2_y", "s2_y_err",
               "s2_y_dark", "s2_y_dark_err", "n_pixels", "in_sensitivity_fit",
               "in_linearity_fit", "saturation")
_SET_KEYS = ("level", "exposure", "L", "u_p", "u_y", "s2_stack", "s2_measured", "s2", "s2_err",
             "n_pixels")
_SPLIT_KEYS = tuple(f"{w}_{p}{e}" for w in ("DSNU1288", "PRNU1288")
                    for p in ("row", "col", "pixel") for e in ("", "_err"))


def _old_emva(f: EmvaFigures) -> dict[str, Any]:
    """What ``EmvaFigures.to_dict()`` gave before the records (its former code, condensed)."""
    names = [fl.name for fl in dataclasses.fields(f)]
    out: dict[str, Any] = {"standard": "EMVA 1288 release 3.1",
                           "definitions": "emva1288 1.0.2 (Results1288)"}
    out.update(_attrs(f, tuple(names[:names.index("points")]) + (
        "sigma_d_consistent", "quantisation_limited")))
    out["snr_curve"] = _old_snr(f)
    out["points"] = [_attrs(p, _POINT_KEYS) for p in f.points]
    out["dark_points"] = [{**_attrs(d, ("exposure", "u_y_dark", "u_y_dark_err", "s2_y_dark",
                                        "s2_y_dark_err")), "relpaths": list(d.relpaths)}
                          for d in f.dark_points]
    for key in ("spatial", "spatial_dark"):
        sp = getattr(f, key)
        out[key] = None if sp is None else _attrs(sp, _SET_KEYS)
    out["notes"] = list(f.notes)
    out["source"] = f.source
    dc = f.dark_current
    out.update({k: json_safe(v) for k, v in (dc.figures() if dc is not None else dict.fromkeys(
        ("u_I_mean", "u_I_mean_err", "u_I_var", "u_I_var_err"))).items()})
    out["dark_current"] = None if dc is None else _old_dark_current(dc)
    out.update({k: json_safe(v) for k, v in (
        f.split.figures() if f.split is not None else dict.fromkeys(_SPLIT_KEYS)).items()})
    out["nonuniformity_split"] = None if f.split is None else _old_split(f.split)
    pl = f.spatial_plots
    out["spatial_plots"] = None if pl is None else json_safe(
        {"spectrograms": pl.spectrograms, "levels": pl.levels, "histograms": pl.histograms,
         "accumulated": pl.accumulated, "profiles": pl.profiles})
    return out


# --------------------------------------------------------------------------------------------
# round trips and byte identity
# --------------------------------------------------------------------------------------------
NAMES = ("demo", "sim", "none", "degenerate", "unresolved")


@pytest.mark.parametrize("name", NAMES)
def test_emva_summary_round_trips_and_is_what_to_dict_gave(cases, name):
    f = cases[name]
    s = f.summary()
    _plain(s)
    _round_trip(EmvaSummary, s)
    assert _text(s.to_dict()) == _text(f.to_dict()) == _text(_old_emva(f))
    assert list(s.to_dict()) == [fl.name for fl in dataclasses.fields(EmvaSummary)]


@pytest.mark.parametrize("name", NAMES)
def test_nested_summaries_round_trip_and_match_their_results(cases, name):
    f = cases[name]
    for p in f.points:
        _round_trip(EmvaPointSummary, p.summary())
        assert _text(p.to_dict()) == _text(_attrs(p, _POINT_KEYS))
    for d in f.dark_points:
        _round_trip(DarkPointSummary, d.summary())
        assert _text(d.to_dict()) == _text(d.summary().to_dict())
    for sp in (f.spatial, f.spatial_dark):
        if sp is not None:
            _round_trip(SpatialSetSummary, sp.summary())
            assert _text(sp.to_dict()) == _text(_attrs(sp, _SET_KEYS))
    _round_trip(SnrCurveSummary, f.snr_summary())
    assert _text(f.snr_curve()) == _text(_old_snr(f))
    dc = f.dark_current
    if dc is not None:
        _round_trip(DarkCurrentSummary, dc.summary())
        assert _text(dc.to_dict()) == _text(_old_dark_current(dc))
        for line in (dc.mean_line, dc.var_line):
            if line is not None:
                _round_trip(DarkLineSummary, line.summary())
                assert _text(line.to_dict()) == _text(_attrs(line))
    if f.split is not None:
        _round_trip(NonuniformitySplitSummary, f.split.summary())
        assert _text(f.split.to_dict()) == _text(_old_split(f.split))
        for part in (f.split.dark, f.split.bright):
            _round_trip(VarianceSplitSummary, part.summary())
            assert _text(part.to_dict()) == _text(_attrs(part))
    if f.spatial_plots is not None:
        _round_trip(SpatialPlotsSummary, f.spatial_plots.summary())
        assert _text(f.spatial_plots.to_dict()) == _text(_old_emva(f)["spatial_plots"])


def test_the_none_branches_are_kept(cases):
    none = cases["none"].summary()
    assert (none.spatial, none.spatial_dark, none.dark_current, none.nonuniformity_split,
            none.spatial_plots) == (None,) * 5
    assert none.sigma_d is None and none.sigma_d_err is None and none.u_I_mean is None
    assert all(getattr(none, k) is None for k in _SPLIT_KEYS)
    assert none.snr_curve.snr_total is None and "snr_total" not in none.to_dict()["snr_curve"]
    assert none.snr_curve.snr_model and all(v is None for v in none.snr_curve.snr_model)
    assert cases["sim"].summary().sigma_d_ptc is None            # photon transfer not run

    deg = cases["degenerate"].summary()
    assert deg.PRNU1288 is None and "snr_total" not in deg.to_dict()["snr_curve"]
    assert deg.dark_current is not None
    assert (deg.dark_current.mean_line, deg.dark_current.var_line) == (None, None)
    assert deg.nonuniformity_split is not None
    assert set(deg.nonuniformity_split.bounds) == set(_SPLIT_KEYS[::2])
    assert all(getattr(deg, k) is None for k in _SPLIT_KEYS)

    demo = cases["demo"].summary()
    assert demo.snr_curve.snr_total is not None and demo.sigma_d_ptc is not None
    assert demo.dark_current is not None and demo.dark_current.mean_line is not None
    assert demo.spatial_plots is not None and demo.nonuniformity_split is not None


def test_an_object_from_before_the_dark_current_and_the_split_reads_them_as_none(demo):
    d = demo.to_dict()
    newer = ["u_I_mean", "u_I_mean_err", "u_I_var", "u_I_var_err", "dark_current",
             *_SPLIT_KEYS, "nonuniformity_split", "spatial_plots"]
    old = {k: v for k, v in d.items() if k not in newer}
    s = EmvaSummary.from_dict(old, "calibration.json", "emva1288")
    assert all(getattr(s, k) is None for k in newer)
    assert s.K == demo.K and s.points == demo.summary().points
    rows = {r.label: r for r in s.rows()}
    assert "\u03bc_I.mean" not in rows and rows["K"].value == demo.K


# --------------------------------------------------------------------------------------------
# damaged objects
# --------------------------------------------------------------------------------------------
def _damaged(d: dict[str, Any], path: tuple[Any, ...], value: Any = None,
             drop: bool = False) -> dict[str, Any]:
    d = copy.deepcopy(d)
    target = d
    for k in path[:-1]:
        target = target[k]
    if drop:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return d


@pytest.mark.parametrize("path, value, drop, message", [
    (("K",), "0.1", False, r"'emva1288\.K' must be a number, got the string '0\.1'"),
    (("QE",), None, True, r"'emva1288\.QE' is missing"),
    (("index_u_ysat",), 1.5, False, r"'emva1288\.index_u_ysat' must be an integer"),
    (("points", 0, "u_y"), "x", False, r"'emva1288\.points\.u_y' must be a number"),
    (("dark_points", 1, "relpaths"), ["a"], False, r"'emva1288\.dark_points\.relpaths' must"),
    (("snr_curve", "snr"), 3.0, False, r"'emva1288\.snr_curve\.snr' must be an array"),
    (("snr_curve", "snr_total", 0), "x", False, r"'emva1288\.snr_curve\.snr_total' must be"),
    (("notes",), "one note", False, r"'emva1288\.notes' must be an array"),
    (("source",), 3, False, r"'emva1288\.source' must be a string"),
    # inside optional records (``X | None``)
    (("spatial", "L"), None, True, r"'emva1288\.spatial\.L' is missing"),
    (("dark_current", "mean_line", "slope"), None, True,
     r"'emva1288\.dark_current\.mean_line\.slope' is missing"),
    (("nonuniformity_split", "bounds"), [], False,
     r"'emva1288\.nonuniformity_split\.bounds' must be an object"),
    (("spatial_plots", "profiles", "dark_vertical", "mid"), None, False,
     r"'emva1288\.spatial_plots\.profiles\.dark_vertical\.mid' must be an array"),
])
def test_a_damaged_object_is_refused_with_its_key_path(demo, path, value, drop, message):
    bad = _damaged(demo.to_dict(), path, value, drop)
    with pytest.raises(CcdError, match=message) as err:
        EmvaSummary.from_dict(bad, "calibration.json", "emva1288")
    assert str(err.value).startswith("calibration.json: ")


@pytest.mark.parametrize("cls, key, path, value, drop, message", [
    (SpatialSetSummary, "spatial", ("L",), None, True, r"'emva1288\.spatial\.L' is missing"),
    (DarkCurrentSummary, "dark_current", ("u_I_mean",), "x", False,
     r"'emva1288\.dark_current\.u_I_mean' must be a number"),
    (DarkCurrentSummary, "dark_current", ("exposures", 2), None, False,
     r"'emva1288\.dark_current\.exposures' must be a number"),
    (NonuniformitySplitSummary, "nonuniformity_split", ("bright", "s2_row"), "big", False,
     r"'emva1288\.nonuniformity_split\.bright\.s2_row' must be a number"),
    (NonuniformitySplitSummary, "nonuniformity_split", ("dark",), None, True,
     r"'emva1288\.nonuniformity_split\.dark' is missing"),
    (SpatialPlotsSummary, "spatial_plots", ("histograms", "DSNU", "count", 0), 1.5, False,
     r"'emva1288\.spatial_plots\.histograms\.DSNU\.count' must be an integer"),
    (SpatialPlotsSummary, "spatial_plots", ("levels", "sigma_y_stack_dark"), None, True,
     r"'emva1288\.spatial_plots\.levels\.sigma_y_stack_dark' is missing"),
    (SpatialPlotsSummary, "spatial_plots", ("spectrograms", "PRNU_vertical", "f"), {}, False,
     r"'emva1288\.spatial_plots\.spectrograms\.PRNU_vertical\.f' must be an array"),
])
def test_a_damaged_nested_record_is_refused_with_its_key_path(demo, cls, key, path, value, drop,
                                                              message):
    bad = _damaged(demo.to_dict()[key], path, value, drop)
    with pytest.raises(CcdError, match=message):
        cls.from_dict(bad, "calibration.json", f"emva1288.{key}")


def test_a_damaged_bound_or_line_is_refused(cases):
    d = cases["degenerate"].split.to_dict()
    d["bounds"]["DSNU1288_row"] = "small"
    with pytest.raises(CcdError, match=r"'bounds\.DSNU1288_row' must be a number"):
        NonuniformitySplitSummary.from_dict(d, "calibration.json")
    line = cases["demo"].dark_current.mean_line.to_dict()
    del line["slope"]
    with pytest.raises(CcdError, match=r"'emva1288\.dark_current\.mean_line\.slope' is "
                                       r"missing"):
        DarkLineSummary.from_dict(line, "calibration.json", "emva1288.dark_current.mean_line")


# --------------------------------------------------------------------------------------------
# rows
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_rows_are_the_headline_of_the_datasheet(cases, name):
    f = cases[name]
    s = f.summary()
    rows = s.rows()
    sheet = [r for r in datasheet_rows(s) if r.key in HEADLINE and r.value is not None]
    back = EmvaSummary.from_dict(json.loads(json.dumps(f.to_dict())))
    assert sheet == [r for r in datasheet_rows(back) if r.key in HEADLINE and r.value is not None]
    assert len(rows) == len(sheet) and set(HEADLINE) <= {k for _, k, _, _, _ in DATASHEET}
    for row, want in zip(rows, sheet):
        assert row.label == want.symbol and row.unit == want.unit
        assert (row.value, row.error) == (want.value, want.error), want.key
        assert row.meaning and row.text is None
    assert len({r.label for r in rows}) == len(rows)            # each figure once
    by = {r.label: r for r in rows}
    assert by["K"].value == f.K and by["K"].error == f.K_err
    assert by["\u03b7"].value == f.QE
    assert by["DR"].unit == "dB" and by["DR"].value == f.DR_dB
    assert str(by["K"]) == f"K {by['K'].shown}"


def test_rows_leave_out_what_is_missing(cases):
    rows = {r.label: r for r in cases["none"].summary().rows()}
    assert "\u03c3_d" not in rows and "DSNU1288" not in rows and "\u03bc_I.mean" not in rows
    assert list(rows) == ["\u03b7", "K", "\u03bc_e.sat", "DR"]
    demo = {r.label: r for r in cases["demo"].summary().rows()}
    assert list(demo) == ["\u03b7", "K", "\u03c3_d", "\u03bc_e.sat", "DR", "\u03bc_I.mean",
                          "DSNU1288", "PRNU1288"]


def test_rows_of_the_dark_current(cases):
    dc = cases["demo"].dark_current
    rows = dc.summary().rows()
    assert rows[0].label == "Dark current from the mean, \u03bc_I.mean"
    assert (rows[0].value, rows[0].error, rows[0].unit) == (dc.u_I_mean, dc.u_I_mean_err,
                                                            "e\u207b/s")
    assert (rows[1].value, rows[1].error) == (dc.u_I_var, dc.u_I_var_err)
    assert rows[2].value == len(set(dc.exposures))
    assert rows[3].value == dc.mean_line.chi2_dof and rows[4].value == dc.var_line.chi2_dof

    un = _unresolved()
    rows = un.summary().rows()
    assert rows[0].value is None and f"{un.u_I_mean_bound:.3g}" in rows[0].text
    assert rows[1].value is None and f"{un.u_I_var_bound:.3g}" in rows[1].text

    line = dc.mean_line.summary()
    lr = {r.label: r for r in line.rows()}
    assert (lr["slope"].value, lr["slope"].error) == (line.slope, line.slope_err)
    assert lr["chi2/dof"].value == line.chi2_dof and lr["dof"].value == line.dof
    assert 0.0 <= lr["Q"].value <= 1.0


def test_rows_of_the_split_and_the_plots(cases):
    split = cases["demo"].split
    rows = split.summary().rows()
    names = {key: (name, symbol) for _, key, name, symbol, _ in DATASHEET}
    assert [r.label for r in rows] == [", ".join(names[k]) for k in _SPLIT_KEYS[::2]]
    for row, key in zip(rows, _SPLIT_KEYS[::2]):
        assert (row.value, row.error) == (getattr(split, key), getattr(split, f"{key}_err"))
    bounded = _bounded_split().summary()
    for row, key in zip(bounded.rows(), _SPLIT_KEYS[::2]):
        assert row.value is None and f"{bounded.bounds[key]:.3g}" in row.text

    vs = split.bright.summary().rows()
    assert (vs[2].value, vs[2].error) == (split.bright.s2, split.bright.s2_err)
    assert (vs[5].value, vs[5].error) == (split.bright.s2_pixel, split.bright.s2_pixel_err)

    plots = cases["demo"].spatial_plots
    pr = {r.label: r for r in plots.summary().rows()}
    assert pr["PRNU1288"].value == plots.levels["PRNU1288"]
    assert pr["DSNU1288 in DN"].value == plots.levels["DSNU1288_DN"]


def test_rows_of_points_and_sets(demo):
    p = demo.points[demo.index_u_ysat]
    rows = {r.label: r for r in p.summary().rows()}
    assert rows["photons, \u03bc_p"].value == p.u_p
    assert (rows["mean signal, \u03bc_y"].value, rows["mean signal, \u03bc_y"].error) == (
        p.u_y, p.u_y_err)
    assert "saturation point" in rows["used in"].text
    d = demo.dark_points[0].summary()
    assert d.rows()[1].value == d.u_y_dark and d.relpaths[0] in d.rows()[3].text
    sp = demo.spatial.summary()
    assert sp.rows()[0].value == sp.L and sp.rows()[4].value == sp.s2
    snr = demo.snr_summary()
    assert snr.rows()[0].value == len(demo.points)
