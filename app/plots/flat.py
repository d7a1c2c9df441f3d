"""Pure plot- and table-building functions of the Flat field page (no widgets, no state).

Everything shown comes from ccdcore's result objects (:mod:`ccdcore.flatfield.fit`,
:mod:`ccdcore.flatfield.uniformity`); nothing here estimates anything, it only arranges numbers and
arrays for display ("value ± error" text is :func:`ccdcore.common.format_pm`'s). Every function
returns a HoloViews element, arrays, a DataFrame or a string, so the pipeline is tested without a
browser.

Public objects
--------------
CHANNEL_COLORS
    Line colour per channel name (``R``, ``G``, ``B``, ``L``, ``G1``, ``G2``).
group_label(key)
    ``(level, exposure)`` of a flat group as a short label: ``"L3 · 40 ms"``.
flagged_pixels(flags)
    Rows and columns of the flagged pixels of a channel (the page marks them on G).
snup_frame(before, after)
    The per-channel SNUP table of a frame before and after correction (display strings).
averaging_plot(result), averaging_frame(result)
    Table 1 of de Lasarte et al. 2007: SNUP against the number N of averaged frames, with
    ccdcore's prediction sqrt(SNUP_fixed² + SNUP_temporal²/N), per channel.
linearity_plot(lin, channel), linearity_frame(lin)
    Fig. 2: mean level against exposure per radiance level, the fitted lines, the linear range
    shaded and the saturation onset marked; the ranges per channel.
study_heatmap(study, channel), study_frame(study, channel)
    Fig. 3 / Tables 3–5: SNUP after correction of every flat group with every candidate base.
zero_dark_frame(zero), settings_frame(comparison), kmap_frame(comparison)
    Table 2 (zero vs non-zero dark image) and the K̂-against-G comparison.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import holoviews as hv
import numpy as np
import pandas as pd
from numpy.typing import NDArray

from ccdcore.common import format_pm
from ccdcore.flatfield.fit import BaseStudy, KMapComparison, SettingsComparison, ZeroDark
from ccdcore.flatfield.uniformity import AveragingResult, Linearity, SnupResult


__all__ = ["CHANNEL_COLORS", "group_label", "flagged_pixels",
           "snup_frame", "averaging_plot", "averaging_frame", "linearity_plot",
           "linearity_frame", "study_heatmap", "study_frame", "zero_dark_frame",
           "settings_frame", "kmap_frame", "LEVEL_COLORS"]

#: line colour per channel
CHANNEL_COLORS: dict[str, str] = {"R": "#d62728", "G": "#2ca02c", "B": "#1f77b4",
                                  "L": "#343a40", "G1": "#2ca02c", "G2": "#98c379"}
#: colours of the radiance levels in the linearity plot
LEVEL_COLORS: tuple[str, ...] = ("#4a6fa5", "#e07b39", "#5a9e6f", "#9b59b6", "#c0392b",
                                 "#16a085", "#7f8c8d", "#d4ac0d")


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float, np.floating)) and math.isfinite(x)


def group_label(key: Sequence[Any] | None) -> str:
    """``(level, exposure)`` as ``"L3 · 40 ms"`` (``"uncorrected"`` for None)."""
    if key is None:
        return "uncorrected"
    level, exposure = key
    lv = "L?" if level is None else f"L{level}"
    if exposure is None:
        return f"{lv} \u00b7 ? s"
    t = float(exposure)
    text = f"{t * 1000:g} ms" if t < 1 else f"{t:g} s"
    return f"{lv} \u00b7 {text}"


# ------------------------------------------------------------------------------ images --------
def flagged_pixels(flags: NDArray, limit: int = 20_000) -> tuple[NDArray, NDArray]:
    """Rows and columns of the flagged pixels of one channel (the first ``limit`` of them in
    raster order: more crosses than that would hide the map)."""
    rows, cols = np.nonzero(np.asarray(flags, dtype=bool))
    return rows[:limit], cols[:limit]


# ------------------------------------------------------------------------------ tables --------
def snup_frame(before: SnupResult, after: SnupResult | None) -> pd.DataFrame:
    """Per channel: mean and SNUP (± standard error, eq. 5) before and after correction."""
    rows = []
    for c in before.channels:
        a = None if after is None else after[c.name]
        rows.append({"channel": c.name,
                     "mean before (DN)": f"{c.mean:.2f}",
                     "SNUP before (%)": format_pm(c.snup, c.snup_err),
                     "mean after (DN)": "" if a is None else f"{a.mean:.2f}",
                     "SNUP after (%)": "" if a is None else format_pm(a.snup, a.snup_err),
                     "pixels": c.n})
    return pd.DataFrame(rows, columns=["channel", "mean before (DN)", "SNUP before (%)",
                                       "mean after (DN)", "SNUP after (%)", "pixels"])


# ------------------------------------------------------------------------------ averaging -----
def averaging_plot(result: AveragingResult, *, logx: bool = True) -> hv.Overlay:
    """SNUP of the average of N frames (points with ± error bars) and ccdcore's prediction
    sqrt(SNUP_fixed² + SNUP_temporal²/N) (lines), one colour per channel."""
    layers: list[hv.Element] = []
    n_max = max(r.N for r in result.rows)
    grid = np.unique(np.geomspace(1, max(n_max, 2), 60))
    for name in dict.fromkeys(r.channel for r in result.rows):
        rows = result.channel(name)
        color = CHANNEL_COLORS.get(name, "#343a40")
        fixed, temporal = result.snup_fixed.get(name), result.snup_temporal.get(name)
        if _finite(fixed) and _finite(temporal):
            pred = np.sqrt(fixed ** 2 + temporal ** 2 / grid)
            layers.append(hv.Curve((grid, pred), "N", "SNUP (%)", label=f"{name} predicted")
                          .opts(color=color, line_dash="dashed", line_width=1.5))
        pts = [(r.N, r.snup, r.snup_err) for r in rows]
        layers.append(hv.ErrorBars(pts, "N", ["SNUP (%)", "err"]).opts(color=color))
        layers.append(hv.Scatter([(n, s) for n, s, _ in pts], "N", "SNUP (%)", label=name)
                      .opts(color=color, size=8, tools=["hover"]))
    ns = sorted({r.N for r in result.rows})
    return hv.Overlay(layers).opts(
        logx=logx, responsive=True, height=340, legend_position="right", show_grid=True,
        padding=0.1, xticks=[(n, str(n)) for n in ns],
        title="SNUP of the average of N frames (Table 1)",
        xlabel="N (frames averaged)", ylabel="SNUP (%)")


def averaging_frame(result: AveragingResult) -> pd.DataFrame:
    """Table 1: N, channel, SNUP ± error, prediction, reduction relative to N = 1."""
    return pd.DataFrame([{"N": r.N, "channel": r.channel,
                          "SNUP (%)": format_pm(r.snup, r.snup_err),
                          "predicted (%)": f"{r.predicted:.3f}" if _finite(r.predicted) else "",
                          "reduction (%)": f"{r.reduction_pct:.1f}"} for r in result.rows],
                        columns=["N", "channel", "SNUP (%)", "predicted (%)", "reduction (%)"])


# ------------------------------------------------------------------------------ linearity -----
def linearity_plot(lin: Linearity, channel: str) -> hv.Overlay:
    """Fig. 2: mean level (DN, dark included) against exposure for one channel.

    Points per radiance level (open markers past the linear part), the fitted line dark + fit
    (ccdcore's ``fit_dn``), the linear range [lo, upper) of the channel shaded, the saturation
    level (``saturation_dn``) as a dashed line and each level's saturation onset exposure as a
    vertical line.
    """
    pts = [p for p in lin.points if p.channel == channel and p.exposure is not None]
    layers: list[hv.Element] = []
    rng = lin.ranges.get(channel)
    upper = lin.upper.get(channel, math.inf)
    top = max([p.mean_dn for p in pts] + [lin.full_scale or 0.0]) if pts else 1.0
    if rng is not None:
        hi = upper if _finite(upper) else top
        layers.append(hv.HSpan(rng[0], hi).opts(color="#5cb85c", alpha=0.12, line_alpha=0))
        layers.append(hv.HLine(rng[0]).opts(color="#5cb85c", line_width=1, line_dash="dotted"))
    sat = lin.saturation_dn.get(channel)
    if sat is not None:
        layers.append(hv.HLine(sat).opts(color="#d9534f", line_dash="dashed", line_width=1.5))
    levels = list(dict.fromkeys(p.level for p in pts))
    for i, level in enumerate(levels):
        color = LEVEL_COLORS[i % len(LEVEL_COLORS)]
        lp = sorted((p for p in pts if p.level == level), key=lambda p: p.exposure)
        name = f"level {level}"
        fitted = [(p.exposure, p.dark_dn + p.fit_dn) for p in lp if p.fit_dn is not None]
        if fitted:
            layers.append(hv.Curve(fitted, "exposure (s)", "mean level (DN)")
                          .opts(color=color, line_width=1.5, alpha=0.8))
        data = pd.DataFrame({"exposure (s)": [p.exposure for p in lp],
                             "mean level (DN)": [p.mean_dn for p in lp],
                             "signal above dark (DN)": [p.signal_dn for p in lp],
                             "linear": ["yes" if p.linear else "no" if p.linear is False
                                        else "no fit" for p in lp]})
        vdims = ["mean level (DN)", "signal above dark (DN)", "linear"]
        lin_pts = data[data["linear"] != "no"]
        bad_pts = data[data["linear"] == "no"]
        layers.append(hv.Scatter(lin_pts, "exposure (s)", vdims, label=name)
                      .opts(color=color, size=8, tools=["hover"]))
        if len(bad_pts):
            layers.append(hv.Scatter(bad_pts, "exposure (s)", vdims, label=f"{name} non-linear")
                          .opts(color=color, size=9, marker="x", tools=["hover"]))
        onset = next((f.saturation_exposure for f in lin.fits
                      if f.channel == channel and f.level == level
                      and f.saturation_exposure is not None), None)
        if onset is not None:
            layers.append(hv.VLine(onset).opts(color=color, line_dash="dashed", line_width=1))
    return hv.Overlay(layers).opts(
        logx=True, responsive=True, height=380, legend_position="right", show_grid=True,
        title=f"Linear response range \u2014 channel {channel} (shaded; dashed: saturation)",
        xlabel="exposure (s)", ylabel="mean level (DN, dark included)")


def linearity_frame(lin: Linearity) -> pd.DataFrame:
    """Per channel: the linear range [lo, hi], the lowest non-linear level and the saturation."""
    rows = []
    for c in lin.channels:
        r = lin.ranges.get(c)
        u = lin.upper.get(c, math.inf)
        s = lin.saturation_dn.get(c)
        rows.append({"channel": c,
                     "linear from (DN)": "" if r is None else f"{r[0]:.1f}",
                     "linear to (DN)": "" if r is None else f"{r[1]:.1f}",
                     "non-linear from (DN)": f"{u:.1f}" if _finite(u) else "",
                     "saturation onset (DN)": "" if s is None else f"{s:.1f}"})
    return pd.DataFrame(rows, columns=["channel", "linear from (DN)", "linear to (DN)",
                                       "non-linear from (DN)", "saturation onset (DN)"])


# ------------------------------------------------------------------------------ base study ----
def study_heatmap(study: BaseStudy, channel: str) -> hv.HeatMap:
    """SNUP (%) after correction: corrected flat group (x) against base image (y), one channel;
    the top row is the uncorrected SNUP; the recommended base is marked with ★."""
    table = study.table(channel)
    images = list(dict.fromkeys(img for per in table.values() for img in per))
    bases = [b for b in table if b is not None]

    def blabel(b: Any) -> str:
        text = group_label(b)
        return text + " \u2605" if b is not None and b == study.recommended else text

    data = []
    for b in ([None] if None in table else []) + bases:
        for img in images:
            v = table[b].get(img)
            if v is not None:
                data.append((group_label(img), blabel(b), float(v)))
    values = [v for *_, v in data]
    hi = float(np.percentile(values, 95)) if values else 1.0
    return hv.HeatMap(data, kdims=["corrected group", "base image"], vdims=["SNUP (%)"]).opts(
        cmap="viridis", colorbar=True, clim=(0.0, hi), tools=["hover"], responsive=True,
        height=max(320, 26 * (len(bases) + 1) + 120), xrotation=60, invert_yaxis=True,
        title=f"SNUP after correction \u2014 channel {channel} (\u2605 recommended base)")


def study_frame(study: BaseStudy, channel: str) -> pd.DataFrame:
    """Tables 3–5: rows the corrected groups, columns ``uncorrected`` and each base image."""
    table = study.table(channel)
    images = list(dict.fromkeys(img for per in table.values() for img in per))
    cols = {group_label(b) + (" \u2605" if b is not None and b == study.recommended else ""): b
            for b in ([None] if None in table else []) + [b for b in table if b is not None]}
    rows = []
    for img in images:
        row: dict[str, Any] = {"corrected group": group_label(img)}
        for label, b in cols.items():
            v = table[b].get(img)
            row[label] = None if v is None else round(float(v), 3)
        rows.append(row)
    return pd.DataFrame(rows, columns=["corrected group", *cols])


# ------------------------------------------------------------------------------ settings ------
def zero_dark_frame(zero: dict[str, ZeroDark]) -> pd.DataFrame:
    """Per setting and channel: the fraction of dark pixel values equal to 0."""
    rows = []
    for setting, z in zero.items():
        for c, f in z.fractions.items():
            rows.append({"setting": setting, "channel": c, "zero pixels (%)": f"{100 * f:.2f}",
                         "clipped at zero": "yes" if z.clipped else "no"})
    return pd.DataFrame(rows, columns=["setting", "channel", "zero pixels (%)",
                                       "clipped at zero"])


def settings_frame(comparison: SettingsComparison) -> pd.DataFrame:
    """Table 2: mean SNUP (± std over images) after correction per setting and channel."""
    rows = []
    for r in comparison.rows:
        rows.append({"setting": r["setting"], "channel": r["channel"],
                     "SNUP after (%)": format_pm(r["snup_mean"], r["snup_std"]),
                     "images": r["n"],
                     "zero dark pixels (%)": "" if r["zero_fraction"] is None
                     else f"{100 * r['zero_fraction']:.2f}",
                     "base": group_label(r["base"])})
    return pd.DataFrame(rows, columns=["setting", "channel", "SNUP after (%)", "images",
                                       "zero dark pixels (%)", "base"])


def kmap_frame(comparison: KMapComparison) -> pd.DataFrame:
    """Per channel: SNUP raw / after G / after K̂ / shot-noise limit, and the residuals against
    the true flat field when it was given."""
    def pct(v: Any) -> str:
        return f"{v:.3f}" if _finite(v) else ""

    rows = []
    for r in comparison.rows:
        row = {"channel": r["channel"], "SNUP raw (%)": pct(r["snup_raw"]),
               "SNUP after G (%)": pct(r["snup_G"]), "SNUP after K\u0302 (%)": pct(r["snup_K"]),
               "shot-noise limit (%)": pct(r.get("snup_limit"))}
        if "residual_G_pct" in r:
            row.update({"residual G (%)": pct(r["residual_G_pct"]),
                        "residual K\u0302 (%)": pct(r["residual_K_pct"]),
                        "high-pass residual G (%)": pct(r["residual_hf_G_pct"]),
                        "high-pass residual K\u0302 (%)": pct(r["residual_hf_K_pct"])})
        rows.append(row)
    return pd.DataFrame(rows)


def dark_text(flat: Any) -> str:
    """The dark image DL_0 of a :class:`~ccdcore.flatfield.fit.FlatField` in words (markdown): the
    dark frames averaged, the dark model o + c·t (its frames, temperature and exposure), or
    de Lasarte's zero-dark form when there were no darks."""
    if flat.dark_source == "zero":
        return ("**Dark image DL_0:** zero — no dark frames, so the flat field is made in de "
                "Lasarte's zero-dark form (DL_0 = 0); the camera's black level stays in G and O")
    at = "without exposure time" if flat.dark_exposure is None else \
        f"at {flat.dark_exposure:g} s"
    if flat.dark_source == "model":
        m = flat.dark_model
        temp = "" if m.temperature is None else f" at {m.temperature:g} °C"
        return (f"**Dark image DL_0:** the dark model o + c·t {at}, fitted per pixel on "
                f"{m.n} biases and darks{temp} (exposures "
                f"{', '.join(f'{t:g}' for t in m.exposures)} s; median current "
                f"{np.median(m.current):.4g} DN/s, {int(m.hot_current.sum())} hot pixels; "
                f"{len(m.excluded)} darks at other temperatures left out)")
    n = flat.dark.n
    return (f"**Dark image DL_0:** {n} dark frame{'s' if n != 1 else ''} {at} (they follow "
            "the base exposure)")


def held_out_frame(check: Any) -> pd.DataFrame:
    """The held-out check (:class:`ccdcore.flatfield.check.HeldOutCheck`) per channel: SNUP of the
    corrected held-out flat, the noise floor, their ratio, and the verdict."""
    if check is None:
        return pd.DataFrame()

    def pct(v: Any) -> str:
        return "–" if v is None else f"{v:.4g}"
    return pd.DataFrame([{"channel": c.name, "SNUP before (%)": pct(c.snup_raw),
                          "SNUP after (%)": pct(c.snup), "floor (%)": pct(c.floor),
                          "SNUP / floor": "–" if c.ratio is None else f"{c.ratio:.3f}",
                          "verdict": ("pass" if c.ratio is not None and c.ratio <= check.factor
                                      else "warn")}
                         for c in check.channels])
