"""The report's EMVA 1288 datasheet section (ccdcore_report.sections.emva_section) and its plots
(ccdcore_report.emva_figures), on products of the emva1288 package's DatasetGenerator.

Two products: ``full`` has an exposure-time series with a resolvable dark current and the
spatial sets, its DSNU and PRNU made of row, column and pixel parts, so every figure of the
datasheet is determined; ``plain`` has no dark current and no spatial sets, so the dark
currents and every DSNU and PRNU figure are not determined, each with its reason.

Tolerances
----------
* What a plot draws is the figures' numbers copied, or one line of arithmetic on them
  (offset + slope·t, the deviation from linearity): equal to 1e-12 relative, float rounding.
* The extreme deviations from linearity against LE_min and LE_max: the datasheet computes them
  with the same formula from the same floats, in another order of operations: 1e-9 relative.
"""
from __future__ import annotations

import dataclasses
import html
import re
from pathlib import Path

import numpy as np
import pytest

# emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (see docs/notes.md)
np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)  # noqa: E731

from emva1288.camera.dataset_generator import DatasetGenerator  # noqa: E402

from ccdcore.common import format_pm  # noqa: E402
from ccdcore.emva.results import EmvaSummary  # noqa: E402
from ccdcore.errors import CcdError  # noqa: E402
from ccdcore.emva.sheet import DATASHEET, datasheet_rows, linearity_deviation  # noqa: E402
from ccdcore.product.make import calibrate  # noqa: E402
from ccdcore.session import open_session  # noqa: E402
from ccdcore_report import build_report  # noqa: E402
from ccdcore_report import emva_figures as ef  # noqa: E402
from ccdcore_report.html import Doc  # noqa: E402
from ccdcore_report.sections import emva_section  # noqa: E402

W, H = 64, 48
L = 8
EXACT = 1e-12
#: the Bokeh root placeholders carry random element ids
ROOT_DIV = re.compile(r'<div id="[^"]*" data-root-id="[^"]*" style="display: contents;"></div>')
#: every plot of the section, in the standard's order
PLOT_IDS = ("emva-ptc", "emva-snr", "emva-linearity", "emva-linearity-deviation",
            "emva-dark-signal", "emva-dark-variance", "emva-spectrogram-dsnu-horizontal",
            "emva-spectrogram-dsnu-vertical", "emva-spectrogram-prnu-horizontal",
            "emva-spectrogram-prnu-vertical", "emva-histogram-dsnu", "emva-histogram-prnu",
            "emva-accumulated-dsnu", "emva-accumulated-prnu", "emva-profile-horizontal",
            "emva-profile-vertical")
SPATIAL_IDS = tuple(i for i in PLOT_IDS if i.startswith(("emva-spectrogram", "emva-histogram",
                                                         "emva-accumulated", "emva-profile")))


def generate(out: Path, **kwargs) -> DatasetGenerator:
    """The reference generator's exposure-time series (12-bit TIFF) with its spatial sets; a
    dark signal far from 0 and a full well above the ADC's range (clean saturation)."""
    args = dict(steps=12, L=L, image_format="tif", outdir=str(out), width=W, height=H,
                bit_depth=12, seed=5, u_esat=60000.0, dark_signal_0=50.0)
    args.update(kwargs)
    return DatasetGenerator(**args)


def section(text: str, id_: str = "emva1288") -> str:
    start = text.index(f'<section id="{id_}"')
    return ROOT_DIV.sub("", text[start:text.index("</section>", start)])


def renderer(model, name: str):
    found = model.select(name=name)
    assert len(found) == 1, name
    return found[0]


def data(model, name: str) -> dict[str, np.ndarray]:
    return {k: np.asarray(v) for k, v in renderer(model, name).data_source.data.items()}


def legend_labels(fig) -> list[str]:
    return [item.label["value"] for legend in fig.legend for item in legend.items]


@pytest.fixture(scope="module")
def full(tmp_path_factory) -> dict:
    rng = np.random.default_rng(3)
    dsnu = rng.normal(0, 2, (H, 1)) + rng.normal(0, 3, (1, W)) + rng.normal(0, 4, (H, W))
    prnu = (1 + rng.normal(0, 0.004, (H, 1)) + rng.normal(0, 0.004, (1, W))
            + rng.normal(0, 0.008, (H, W)))
    gen = generate(tmp_path_factory.mktemp("emva") / "full", dsnu=dsnu, prnu=prnu,
                   dark_current_ref=3000)
    product = calibrate(gen.descriptor_path)
    return {"product": product, "emva": product.emva1288, "html": build_report(product)}


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> dict:
    """No dark current and the spatial sets left out (the generator writes them last: L
    bright frames of one level, then L dark frames)."""
    gen = generate(tmp_path_factory.mktemp("emva") / "plain", dark_current_ref=0)
    session = open_session(gen.descriptor_path)
    spatial = session.frames[-2 * L:]
    assert [r.role for r in spatial] == ["ptc"] * L + ["dark"] * L
    assert len({r.level for r in spatial[:L]}) == 1
    product = calibrate(dataclasses.replace(session, frames=session.frames[:-2 * L]))
    return {"product": product, "emva": product.emva1288, "html": build_report(product)}


# ---------------------------------------------------------------------------------------------
# the section in the report
# ---------------------------------------------------------------------------------------------
def row_html(row, value: str) -> str:
    return (f"<tr><td>{html.escape(row.name)}</td><td>{html.escape(row.symbol)}</td>"
            f'<td class="num">{html.escape(value)}</td>')


def test_the_datasheet_lists_every_figure_in_the_standards_order(full):
    text, emva = full["html"], full["emva"]
    sec = section(text)
    assert "<h2>EMVA 1288 datasheet</h2>" in sec
    assert '<a href="#emva1288">EMVA 1288 datasheet</a>' in text      # table of contents
    rows = datasheet_rows(emva)
    assert [r.key for r in rows] == [d[1] for d in DATASHEET]
    at = 0
    for r in rows:
        assert r.value is not None, (r.key, r.note)       # this session determines them all
        expected = row_html(r, format_pm(getattr(emva, r.key), getattr(emva, f"{r.key}_err"),
                                         unit=r.unit))
        found = sec.find(expected, at)
        assert found > at, r.key                           # present, and after the one before
        at = found
    # the groups in the standard's order, each once
    groups = re.findall(r'<th colspan="\d" scope="rowgroup"[^>]*>([^<]+)</th>', sec)
    assert groups == list(dict.fromkeys(d[0] for d in DATASHEET))
    # no reason column when every figure is determined, and the old key table is gone
    assert "why not determined" not in sec and "<th>key</th>" not in sec


def test_a_figure_not_determined_shows_its_reason_and_bound(plain):
    sec, emva = section(plain["html"]), plain["emva"]
    rows = {r.key: r for r in datasheet_rows(emva)}
    missing = [k for k, r in rows.items() if r.value is None]
    assert {"u_I_mean", "u_I_var", "DSNU1288", "PRNU1288_pixel"} <= set(missing)
    assert "<th>why not determined</th>" in sec
    for key in missing:
        r = rows[key]
        assert row_html(r, "not determined") + f"<td>{html.escape(r.note)}</td></tr>" in sec, key
    bound = emva.dark_current.u_I_mean_bound
    assert bound > 0 and f"below {bound:.3g} e-/s" in rows["u_I_mean"].note
    assert "no spatial sets" in rows["DSNU1288"].note
    # the determined figures are still written with their errors
    assert row_html(rows["K"], format_pm(emva.K, emva.K_err, unit="DN/e\u207b")) in sec
    # the plots the data allow are drawn, with the reason in the dark plot's caption
    for id_ in PLOT_IDS:
        assert (f'id="{id_}"' in sec) == (id_ not in SPATIAL_IDS), id_
    assert html.escape(rows["u_I_mean"].note) in sec.split('id="emva-dark-signal"')[1]
    assert "No spatial nonuniformity plots: the session has no spatial sets" in sec
    # notes the table shows are not repeated below it, the others are
    listed = re.findall(r"<li>(.*?)</li>", sec)
    assert html.escape(rows["u_I_mean"].note) not in listed
    others = [n for n in emva.notes if n not in {r.note for r in rows.values()}]
    assert others and all(html.escape(n) in listed for n in others)


def test_every_plot_is_in_the_report_in_the_standards_order(full):
    text = full["html"]
    sec = section(text)
    where = [sec.find(f'<figure class="ccd-report-plot" id="{id_}">') for id_ in PLOT_IDS]
    assert all(w > 0 for w in where), dict(zip(PLOT_IDS, where))
    assert where == sorted(where)
    headings = [sec.find(h) for h in ("<h3>Sensitivity, linearity and noise</h3>",
                                      "<h3>Dark current</h3>",
                                      "<h3>Spatial nonuniformity and defect pixels</h3>")]
    assert headings == sorted(headings) and headings[0] > 0
    assert where[3] < headings[1] < where[4] and where[5] < headings[2] < where[6]
    # each caption names the plot as the standard does
    for id_, name in (("emva-linearity-deviation", "Deviation from linearity"),
                      ("emva-spectrogram-prnu-vertical", "Vertical spectrogram of the PRNU"),
                      ("emva-histogram-dsnu", "Logarithmic histogram of the DSNU"),
                      ("emva-accumulated-prnu", "Accumulated histogram of the PRNU"),
                      ("emva-profile-vertical", "Vertical profiles")):
        caption = sec.split(f'id="{id_}">')[1].split("</figcaption>")[0]
        assert f"<figcaption>{name} (sec. " in caption, id_
    # offline as ever: no script or style fetched
    assert not re.search(r"<script\b[^>]*\bsrc\s*=|<link\b", text, re.I)


def test_an_older_product_without_the_new_keys_still_gets_its_section(full):
    # the keys added since the first figures read as None; the dark points (in every product,
    # never without the key) are empty
    older = {k: v for k, v in full["emva"].to_dict().items()
             if k not in ("dark_current", "spatial_plots", "nonuniformity_split")}
    emva = EmvaSummary.from_dict({**older, "dark_points": []}, "calibration.json", "emva1288")
    doc = Doc()
    emva_section(doc, emva)
    text = "".join(v for kind, v in doc.parts if kind == "html")
    assert "No dark-current plots: the product holds no dark points" in text
    assert "No spatial nonuniformity plots: the product holds no spatial plots" in text
    assert 'id="emva-dark-signal"' not in text and 'id="emva-ptc"' in text


# ---------------------------------------------------------------------------------------------
# the figures' data
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("which, build, key, line_key, scale", [
    ("mean", ef.dark_signal_figure, "u_y_dark", "mean_line", 1),
    ("var", ef.dark_variance_figure, "s2_y_dark", "var_line", 2)])
def test_dark_plots_draw_the_points_and_the_dark_current_line(full, which, build, key,
                                                              line_key, scale):
    emva = full["emva"]
    fig = build(emva)
    t = np.array([p.exposure for p in emva.dark_points])
    y = np.array([getattr(p, key) for p in emva.dark_points])
    e = np.array([getattr(p, f"{key}_err") for p in emva.dark_points])
    pts = data(fig, "dark-points")
    np.testing.assert_array_equal(pts["t"], t)
    np.testing.assert_array_equal(pts["y"], y)
    np.testing.assert_allclose(pts["hi"] - pts["lo"], 2 * e, rtol=EXACT)
    line = getattr(emva.dark_current, line_key)
    drawn = data(fig, "dark-line")
    assert drawn["x"].tolist() == [t.min(), t.max()]
    np.testing.assert_allclose(drawn["y"], line.offset + line.slope * drawn["x"],
                               rtol=EXACT)
    # the line drawn is the one the datasheet's dark current comes from (slope / K or / K²)
    current = getattr(emva, f"u_I_{which}")
    assert line.slope / emva.K ** scale == pytest.approx(current, rel=1e-9)
    assert format_pm(current, getattr(emva, f"u_I_{which}_err"),
                     unit="e\u207b/s") in fig.title.text


def test_dark_plots_without_their_data(full, plain):
    emva = full["emva"]
    assert ef.dark_signal_figure(dataclasses.replace(emva, dark_points=emva.dark_points[:1])) \
        is None
    assert ef.dark_variance_figure(dataclasses.replace(emva, dark_points=())) is None
    # a product of before the dark current: the points, no line, "not determined"
    fig = ef.dark_signal_figure(dataclasses.replace(emva, dark_current=None, u_I_mean=None))
    assert not fig.select(name="dark-line") and len(data(fig, "dark-points")["t"]) == 12
    assert "not determined" in fig.title.text
    # not resolved: the bound in the title, the (flat) line still drawn
    p = plain["emva"]
    assert (f"below {p.dark_current.u_I_var_bound:.3g} e\u207b/s"
            in ef.dark_variance_figure(p).title.text)
    assert ef.dark_current_text(p, "mean").startswith("\u03bc_I.mean not determined: below")


def test_linearity_deviation_is_the_datasheets(full):
    emva = full["emva"]
    a, b = emva.linearity_slope, emva.linearity_offset
    pts = emva.points
    u_p = np.array([p.u_p for p in pts])
    Y = np.array([p.u_y - p.u_y_dark for p in pts])
    want = 100 * (Y - (a * u_p + b)) / (a * u_p + b)
    d = linearity_deviation(emva)
    np.testing.assert_allclose(d["deviation"], want, rtol=EXACT)
    in_fit = np.array([p.in_linearity_fit for p in pts])
    np.testing.assert_array_equal(d["in_fit"], in_fit)
    assert want[in_fit].min() == pytest.approx(emva.LE_min, rel=1e-9)
    assert want[in_fit].max() == pytest.approx(emva.LE_max, rel=1e-9)

    fig = ef.linearity_deviation_figure(emva)
    fit = data(fig, "deviation-fit")
    np.testing.assert_allclose(fit["deviation"], want[in_fit], rtol=EXACT)
    np.testing.assert_array_equal(fit["u_p"], u_p[in_fit])
    for key in ("LE_min", "LE_max"):
        assert set(data(fig, key)["y"]) == {getattr(emva, key)}
    # every point is drawn once: in the fit, outside it, or pinned at the edge when far off
    # (this set's first point, a few % off, and the last, past saturation)
    shown = [data(fig, n) for n in ("deviation-fit", "deviation-outside", "deviation-off-scale")]
    assert sorted(np.concatenate([s["u_p"] for s in shown])) == sorted(u_p)
    off = shown[2]
    lo, hi = fig.y_range.start, fig.y_range.end
    assert np.all((off["deviation"] < lo) | (off["deviation"] > hi))
    assert np.all((off["y"] > lo) & (off["y"] < hi))
    assert np.all((off["marker"] == "triangle") == (off["deviation"] > hi))
    assert lo < emva.LE_min and emva.LE_max < hi and np.all(abs(want[in_fit]) < hi - lo)


def test_linearity_deviation_needs_the_fitted_line(full):
    # figures without the fitted line are refused where they are read (a product at its
    # load); figures without points give no deviation
    emva = {**full["emva"].to_dict(), "linearity_slope": None}
    with pytest.raises(CcdError, match=r"'emva1288\.linearity_slope' must be a number"):
        EmvaSummary.from_dict(emva, "calibration.json", "emva1288")
    emva = dataclasses.replace(full["emva"], points=())
    assert linearity_deviation(emva) is None and ef.linearity_deviation_figure(emva) is None


@pytest.mark.parametrize("which", ef.SPECTROGRAMS)
def test_spectrograms_draw_the_amplitudes_and_labelled_levels(full, which):
    emva = full["emva"]
    fig = ef.spectrogram_figure(emva, which)
    spec = getattr(emva.spatial_plots.spectrograms, which)
    f, amp = np.array(spec.f), np.array(spec.amplitude)
    drawn = data(fig, "spectrum")
    keep = amp > 0
    np.testing.assert_array_equal(drawn["x"], f[keep])
    np.testing.assert_array_equal(drawn["y"], amp[keep])
    assert type(fig.y_scale).__name__ == "LogScale"
    levels = emva.spatial_plots.levels.to_dict()
    keys = (("DSNU1288_DN", "sigma_y_stack_dark", "sigma_y_stack_dark_avg")
            if which.startswith("DSNU") else
            ("PRNU1288", "sigma_y_stack_percent", "sigma_y_stack_avg_percent"))
    for key in keys:
        line = data(fig, f"level-{key}")
        assert set(line["y"]) == {levels[key]}
        assert line["x"].tolist() == [f[keep].min(), f[keep].max()]
    labels = legend_labels(fig)
    kind = which.split("_")[0]
    assert any(lab.startswith(f"{kind}1288") for lab in labels)
    assert any(lab.startswith("temporal noise of one") for lab in labels)
    assert any(lab.startswith(f"white-noise floor of the average of {L} ") for lab in labels)
    # the floor is what averaging L frames leaves of one frame's noise
    assert levels[keys[2]] == pytest.approx(levels[keys[1]] / np.sqrt(L), rel=EXACT)


@pytest.mark.parametrize("which, pixels", [("DSNU", H * W), ("PRNU", (H - 4) * (W - 4))])
def test_histograms_count_every_pixel_once(full, which, pixels):
    emva = full["emva"]
    hist = getattr(emva.spatial_plots.histograms, which)
    x, count = np.array(hist.x), np.array(hist.count)
    fig = ef.histogram_figure(emva, which)
    drawn = data(fig, "counts")
    width = x[1] - x[0]
    np.testing.assert_allclose(drawn["x"], (x + width / 2)[count > 0], rtol=EXACT, atol=1e-12)
    np.testing.assert_array_equal(drawn["count"], count[count > 0])
    assert drawn["count"].sum() == pixels      # every pixel (the high-pass image: 2 cut a side)
    model = data(fig, "model")
    np.testing.assert_array_equal(model["y"], np.array(hist.model)[np.array(hist.model) > 0])
    assert fig.y_range.start == 0.5 and type(fig.y_scale).__name__ == "LogScale"
    unit = "e\u207b" if which == "DSNU" else "% of the mean signal"
    assert unit in fig.xaxis[0].axis_label

    acc = getattr(emva.spatial_plots.accumulated, which)
    fig = ef.accumulated_histogram_figure(emva, which)
    drawn = data(fig, "accumulated")
    percent = np.array(acc.percent)
    np.testing.assert_array_equal(drawn["percent"], percent[percent > 0])
    assert drawn["percent"][0] == 100.0 and np.all(np.diff(drawn["percent"]) <= 0)


@pytest.mark.parametrize("which, n", [("horizontal", W), ("vertical", H)])
def test_profiles_stack_the_signal_over_the_dark(full, which, n):
    emva = full["emva"]
    layout = ef.profile_figure(emva, which)
    bright, dark = layout.children
    assert bright.x_range is dark.x_range
    for part, fig in (("bright", bright), ("dark", dark)):
        prof = getattr(emva.spatial_plots.profiles, f"{part}_{which}")
        for key in ("mean", "min", "max", "mid"):
            drawn = data(fig, f"{part}-{key}")
            np.testing.assert_array_equal(drawn["x"], prof.index)
            np.testing.assert_array_equal(drawn["y"], getattr(prof, key))
        assert len(prof.index) == n
    # the signal is the bright image less the dark one: its mean profile is far above the dark
    assert min(data(bright, "bright-min")["y"]) > max(data(dark, "dark-max")["y"])


def test_spatial_plots_are_none_without_spatial_sets(plain):
    emva = plain["emva"]
    assert emva.spatial_plots is None
    for which in ef.SPECTROGRAMS:
        assert ef.spectrogram_figure(emva, which) is None
    for which in ef.HISTOGRAMS:
        assert ef.histogram_figure(emva, which) is None
        assert ef.accumulated_histogram_figure(emva, which) is None
    for which in ef.PROFILES:
        assert ef.profile_figure(emva, which) is None
    with pytest.raises(ValueError, match="DSNU_horizontal"):
        ef.spectrogram_figure(emva, "DSNU")
    with pytest.raises(ValueError, match="horizontal, vertical"):
        ef.profile_figure(emva, "bright_horizontal")
