"""The HTML calibration report (ccdcore_report, ``ccdcore report``): the numbers as the product has
them, the sections and plots of each demo, the skipped estimates, bad input (exit 2, nothing
written) and a file that loads nothing from anywhere."""
from __future__ import annotations

import contextlib
import dataclasses
import html
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ccdcore.cli.command import main
from ccdcore.common import format_pm
from ccdcore.guide import ptc_gate
from ccdcore.emva.results import EmvaSummary
from ccdcore.errors import CcdError
from ccdcore.flatfield.fit import correct
from ccdcore.product.make import CalibrationProduct, calibrate, load_product
from ccdcore.product.records import ProductEstimates
from ccdcore.response.methods import ResponseSummary
from ccdcore.session import Camera, open_session
from ccdcore.flatfield.uniformity import snup
from ccdcore_report import MAX_MAP_SIDE, build_report, write_report

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ROOT / "assets"
#: the Bokeh root placeholders carry random element ids: cut them before comparing sections
ROOT_DIV = re.compile(r'<div id="[^"]*" data-root-id="[^"]*" style="display: contents;"></div>')


def run(*argv: str) -> tuple[int, str, str]:
    """``main(argv)`` with stdout and stderr captured (usable in module-scoped fixtures)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def section(text: str, id_: str) -> str:
    """The HTML of ``<section id=id_>`` (sections do not nest)."""
    start = text.index(f'<section id="{id_}"')
    return ROOT_DIV.sub("", text[start:text.index("</section>", start)])


# ------------------------------------------------------------------------------ fixtures -------
@pytest.fixture(scope="module")
def h94(tmp_path_factory) -> dict:
    """healey94: the report from the session, and from a product folder ``calibrate`` wrote."""
    tmp = tmp_path_factory.mktemp("h94")
    code, out, err = run("report", str(ASSETS / "healey94"), "-o", str(tmp / "session.html"))
    assert code == 0, err
    code, _, err2 = run("calibrate", str(ASSETS / "healey94"), "-o", str(tmp / "calib"))
    assert code == 0, err2
    code, out3, err3 = run("report", str(tmp / "calib"), "-o", str(tmp / "calib.html"))
    assert code == 0, err3
    return {"html": (tmp / "session.html").read_text(), "stdout": out, "stderr": err,
            "calib_html": (tmp / "calib.html").read_text(), "calib": tmp / "calib",
            "product": load_product(tmp / "calib"), "tmp": tmp}


@pytest.fixture(scope="module")
def delasarte(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("dl")
    session = open_session(ASSETS / "delasarte07")
    product = calibrate(session)
    path = write_report(session, tmp / "dl.html", product=product)
    return {"html": path.read_text(), "product": product, "session": session}


# ------------------------------------------------------------------------------ healey94 -------
def test_cli_report_of_a_session_holds_the_estimates_as_the_product_has_them(h94):
    text, est = h94["html"], h94["product"].estimates
    assert "report written to" in h94["stdout"]
    assert "calibrate: photon transfer" in h94["stderr"]     # progress lines on stderr
    noise, dark, fp, plan = est.noise, est.dark, est.fixed_pattern, est.plan
    for expected in (
            format_pm(noise.A, noise.A_err, unit="DN/e\u207b"),
            format_pm(noise.sigma_c2, noise.sigma_c2_err, unit="DN\u00b2"),
            format_pm(noise.read_noise_e, noise.read_noise_e_err, unit="e\u207b"),
            f"{noise.chi2:.4g}", ptc_gate(noise).line(),
            f"with {noise.dof} degrees of freedom",
            format_pm(dark.mean, dark.mean_sem, unit="DN"),
            f"{dark.spatial_std:.4g} DN", f"{fp.spatial_std:.4g}",
            f"{fp.n1} \u00d7 {fp.n2}"):
        assert html.escape(expected) in text, expected
    hot = section(text, "dark")
    assert f"<td>hot pixels</td><td class=\"num\">{dark.n_hot}</td>" in hot
    assert f"<td>dead pixels</td><td class=\"num\">{dark.n_dead}</td>" in hot
    planned = section(text, "plan")
    assert f'<td class="num">{plan.n1_required}</td>' in planned
    assert f'<td class="num">{plan.n2_required}</td>' in planned
    for warning in plan.warnings:
        assert html.escape(warning) in planned
    for patch, sv in est.scene.items():
        assert html.escape(format_pm(sv.V_S, sv.V_S_err)) in section(text, "scene")


def test_the_ptc_and_maps_sections_and_the_skipped_list(h94):
    text, product = h94["html"], h94["product"]
    for id_ in ("summary", "noise", "dark", "fixed-pattern", "plan", "correction-check",
                "scene", "maps", "skipped", "provenance"):
        assert f'<section id="{id_}"' in text, id_
        assert f'<a href="#{id_}">' in text, id_          # in the table of contents
    for id_ in ("ptc", "ptc-loglog", "map-dark", "map-dark_var", "map-K", "map-K_err",
                "map-n1_used"):
        assert re.search(rf'<figure class="ccd-report-plot[^"]*" id="{id_}"', text), id_
    # no pixel is hot or dead on the demo: said, not drawn
    assert 'id="map-hot_dead">Hot and dead pixels: no pixel is flagged' in text
    skipped = section(text, "skipped")
    assert {s.estimate for s in product.skipped} >= {"flat_field", "response"}
    for s in product.skipped:
        assert html.escape(s.reason) in skipped
        assert f"<td>{s.code}</td>" in skipped
    assert "every pixel drawn" in section(text, "maps")   # 256 x 192: no reduction


def test_a_product_folder_gives_the_same_figures(h94):
    for id_ in ("noise", "dark", "fixed-pattern", "plan", "correction-check", "scene",
                "maps", "skipped"):
        assert section(h94["calib_html"], id_) == section(h94["html"], id_), id_
    # without the session: the roles are not known, the product's label and frame count are
    summary = section(h94["calib_html"], "summary")
    assert "Frames by role and group" not in summary
    assert html.escape(h94["product"].provenance.session) in summary


def test_provenance_names_version_session_steps_and_the_missing_hash(h94):
    prov = section(h94["html"], "provenance")
    product = h94["product"]
    assert f"ccdcore {product.provenance.ccdcore}" in prov
    assert html.escape(product.provenance.session) in prov
    if product.provenance.session_hash:
        assert product.provenance.session_hash in prov
    else:
        assert "unavailable" in prov
    for step, params in product.provenance.steps.items():
        for key, _ in params.items():
            assert f"<b>{html.escape(key)}</b>" in prov, (step, key)


def test_the_report_loads_nothing_from_outside(h94):
    text = h94["html"]
    assert not re.search(r"<script\b[^>]*\bsrc\s*=", text, re.I)
    assert not re.search(r"<link\b", text, re.I)
    assert not re.search(r"<img\b[^>]*\bsrc\s*=\s*[\"']?(?:https?:)?//", text, re.I)
    # outside the scripts' own text (BokehJS names a MathJax CDN it never loads here)
    markup = re.sub(r"(<script\b[^>]*>).*?(</script>)", r"\1\2", text, flags=re.S | re.I)
    assert not re.search(r"<iframe\b|@import|url\(\s*[\"']?(?:https?:)?//", markup, re.I)
    assert not re.search(r"\b(?:src|href)\s*=\s*[\"']?(?:https?:)?//", markup, re.I)
    # every anchor of the table of contents has its target
    for target in re.findall(r'<a href="#([^"]+)">', text):
        assert f'id="{target}"' in text, target
    assert text.count("<script") >= 2        # BokehJS and the figures, inline
    ids = re.findall(r'\bid="([^"]+)"', markup)
    assert len(ids) == len(set(ids)), sorted(i for i in ids if ids.count(i) > 1)


def test_the_report_stays_offline_when_panel_is_imported(h94):
    """Panel's models declare scripts of their own; Bokeh lists them for every document once
    Panel is imported (as in the app): the report must not link them."""
    import panel  # noqa: F401

    text = build_report(h94["product"])
    assert not re.search(r"<script\b[^>]*\bsrc\s*=|<link\b", text, re.I)
    assert section(text, "noise") == section(h94["html"], "noise")


def test_the_report_verb_does_not_load_panel(h94, tmp_path):
    code = ("import sys; from ccdcore.cli.command import main; "
            f"rc = main(['report', {str(h94['calib'])!r}, '-o', {str(tmp_path / 'r.html')!r}]); "
            "print(rc, sorted(m for m in ('panel', 'holoviews') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True)
    assert out.stdout.split("\n")[-2] == "0 []", out.stdout + out.stderr


# ------------------------------------------------------------------------------ other demos ----
def test_delasarte07_has_snup_tables_and_flat_maps(delasarte):
    text, product, session = delasarte["html"], delasarte["product"], delasarte["session"]
    flat = section(text, "flat-field")
    ff = product.estimates.flat_field
    for c in ff.channels:
        assert f"<td>{c.name}</td><td class=\"num\">{c.k:.5g}</td>" in flat
    base = snup(product.maps["flat_base"], layout="rgb")
    for c in base.channels:
        assert format_pm(c.snup, c.snup_err, unit="%") in flat
    # the held-out table: the first frame of a group other than the base, before and after
    base_key = tuple(ff.base)
    key = next(k for k in session.flat_groups(setting=ff.setting) if tuple(k) != base_key
               and k[1] == base_key[1])
    rec = session.flat_groups(setting=ff.setting)[key][0]
    frame = session.read(rec)
    before = snup(frame, layout="rgb")
    after = snup(correct(frame, product.maps["flat_G"], product.maps["flat_O"]), layout="rgb")
    held = flat[flat.index("ccd-report-snup-held-out"):]
    rows = held[held.index(html.escape(rec.relpath)):]
    for b, a in zip(before.channels, after.channels):    # one row per channel, in order
        cells = (f"<td>{b.name}</td><td class=\"num\">{format_pm(b.snup, b.snup_err, unit='%')}"
                 f"</td><td class=\"num\">{format_pm(a.snup, a.snup_err, unit='%')}</td>")
        assert cells in rows[:rows.index("</tr>") + 1], b.name
        rows = rows[rows.index("</tr>") + 5:]
    assert after["G"].snup < before["G"].snup / 2          # the correction works
    for name in ("flat_G", "flat_O", "flat_dark", "flat_base"):
        for ch in ("R", "G", "B"):
            assert f'id="map-{name}-{ch}"' in text, (name, ch)


def test_delasarte07_from_the_product_alone_says_what_needs_the_session(delasarte):
    text = build_report(delasarte["product"])
    flat = section(text, "flat-field")
    assert "ccd-report-snup-base" in flat and "ccd-report-snup-held-out" not in flat
    assert "Not measured: the report was made from the calibration product alone" in flat


def test_tsin01_has_the_response_section(tmp_path):
    code, _, err = run("report", str(ASSETS / "tsin01"), "-o", str(tmp_path / "t.html"))
    assert code == 0, err
    text = (tmp_path / "t.html").read_text()
    resp = section(text, "response")
    r = load_product_of(tmp_path, "tsin01").estimates.response
    for i, ch in enumerate(r.channels):
        assert html.escape(format_pm(r.sigma_s[i], r.sigma_s_err[i])) in resp
        assert html.escape(format_pm(r.sigma_c2[i], r.sigma_c2_err[i], unit="DN")) in resp
    z = round(0.5 * (r.levels - 1))
    assert format_pm(r.g[0][z], r.g_err[0][z]) in resp
    assert re.search(r'<figure class="ccd-report-plot[^"]*" id="response-curves"', text)
    # the prediction agreement (sec. 4.2) of the product's response, pooled and per pair
    a = r.agreement
    table = _table_html(resp, "ccd-report-response-agreement")
    assert _row(table, "all")[1:4] == [f"{getattr(a, k):.2f}" for k in ("rms", "rms_fitted",
                                                                         "rms_blend")]
    pairs = _table_html(resp, "ccd-report-response-pairs")
    assert len(re.findall(r"<tr><td>", pairs)) == len(r.exposure_times) - 1


def _table_html(text: str, cls: str) -> str:
    start = text.index(f'<table class="{cls}">')
    return text[start:text.index("</table>", start)]


def _row(table: str, first: str) -> list[str]:
    """The cells (text, unescaped) of the table row whose first cell is ``first``."""
    for row in re.findall(r"<tr>(.*?)</tr>", table):
        cells = [html.unescape(c) for c in re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", row)]
        if cells and cells[0] == first:
            return cells
    raise AssertionError(f"no row {first!r}")


@pytest.fixture(scope="module")
def rgb_response(tmp_path_factory) -> ResponseSummary:
    """A colour bracket's response (Debevec & Malik, fast) as a product holds it."""
    from ccdcore.response.brackets import load_bracket
    from ccdcore.response.methods import response_of
    from ccdcore.simulate import simulate

    root = tmp_path_factory.mktemp("rgb") / "bracket"
    simulate("tsin01", root, seed=5, size=(64, 48), layout="rgb")
    result = response_of(load_bracket(open_session(root)), "debevec")
    return result.summary()


def _with_response(r: ResponseSummary) -> CalibrationProduct:
    return CalibrationProduct(maps={}, estimates=ProductEstimates(response=r),
                              camera=Camera(name="rgb", bits=8, layout="rgb"))


def test_response_agreement_pooled_per_channel_and_per_pair(rgb_response):
    r = rgb_response
    a = r.agreement
    resp = section(build_report(_with_response(r)), "response")
    table = _table_html(resp, "ccd-report-response-agreement")
    for row in [a, *a.channels]:
        name = getattr(row, "channel", "all")
        assert _row(table, name)[1:4] == [f"{getattr(row, k):.2f}" for k in (
            "rms", "rms_fitted", "rms_blend")], name
    assert _row(table, "all")[4] == str(sum(c.n for c in a.channels))
    pairs = _table_html(resp, "ccd-report-response-pairs")
    header = re.findall(r"<th>(.*?)</th>", pairs)
    t = r.exposure_times
    for c in a.channels:
        ch = c.channel
        col = header.index(f"{ch}: RMS")
        assert header[col + 1] == f"{ch}: fitted"
        assert header[col + 2] == f"{ch}: ratio fit/nominal"
        for p in c.pairs:
            cells = _row(pairs, f"{p.j + 1}\u2192{p.k + 1}")
            assert cells[1] == f"{t[p.j]:.4g} \u2192 {t[p.k]:.4g}"
            assert cells[col:col + 3] == [
                f"{p.rms:.2f}", f"{p.rms_fitted:.2f}",
                f"{p.ratio_fitted / (t[p.k] / t[p.j]):.3f}"], (ch, p)


def test_response_agreement_a_bad_frame_shows_in_its_pairs(tmp_path):
    """Image 5's exposure time written 30 % too long: the report's pairs 4\u21925 and 5\u21926
    predict worst in every channel, and their fitted ratios say which way (about 1/1.3 and
    1.3 of the nominal ones); the other pairs stay near 1."""
    from ccdcore.response.brackets import load_bracket
    from ccdcore.response.methods import response_of
    from ccdcore.simulate import simulate

    root = tmp_path / "bad"
    simulate("tsin01", root, seed=5, size=(64, 48), layout="rgb")
    manifest = root / "session.toml"
    text = manifest.read_text()
    m = re.search(r'(s0_k04\.tif", role = "bracket", exposure = )([0-9.]+)', text)
    manifest.write_text(text.replace(m.group(0), m.group(1) + repr(float(m.group(2)) * 1.3)))
    br = load_bracket(open_session(root))
    # by default the bracket's own exposures are estimated and the frame is named
    auto = response_of(br, "debevec")
    assert auto.exposures.used == "estimated"
    assert any(r.startswith("s0_k03 to s0_k04") or r.startswith("s0_k04 to s0_k05")
               for r in auto.exposures.summary().off_runs()), auto.exposures.summary().off_runs()
    # at the listed exposures the report's pairs show it
    r = response_of(br, "debevec", exposures="listed").summary()
    pairs = _table_html(section(build_report(_with_response(r)), "response"),
                        "ccd-report-response-pairs")
    header = re.findall(r"<th>(.*?)</th>", pairs)
    names = [f"{j}\u2192{j + 1}" for j in range(1, len(r.exposure_times))]
    for ch in ("R", "G", "B"):
        rms = {n: float(_row(pairs, n)[header.index(f"{ch}: RMS")]) for n in names}
        ratio = {n: float(_row(pairs, n)[header.index(f"{ch}: ratio fit/nominal")])
                 for n in names}
        assert sorted(rms, key=rms.get)[-2:] in (["4\u21925", "5\u21926"],
                                                 ["5\u21926", "4\u21925"]), (ch, rms)
        assert ratio["4\u21925"] < 0.85 and ratio["5\u21926"] > 1.15, (ch, ratio)
        assert all(abs(v - 1) < 0.1 for n, v in ratio.items()
                   if n not in ("4\u21925", "5\u21926")), (ch, ratio)


def test_response_agreement_text_is_escaped_and_absent_agreement_is_no_table(rgb_response):
    r = rgb_response
    a = dataclasses.replace(r.agreement, channels=tuple(
        dataclasses.replace(c, channel="<i>R</i>") if c.channel == "R" else c
        for c in r.agreement.channels))
    resp = section(build_report(_with_response(dataclasses.replace(r, agreement=a))),
                   "response")
    assert "<i>R</i>" not in resp and "&lt;i&gt;R&lt;/i&gt;: RMS" in resp
    resp = section(build_report(_with_response(dataclasses.replace(r, agreement=None))),
                   "response")
    assert "ccd-report-response-agreement" not in resp and "ccd-report-response-g" in resp


def load_product_of(tmp: Path, demo: str) -> CalibrationProduct:
    code, _, err = run("calibrate", str(ASSETS / demo), "-o", str(tmp / f"{demo}-calib"))
    assert code == 0, err
    return load_product(tmp / f"{demo}-calib")


def test_change_has_the_change_section(tmp_path):
    from ccdcore.change.detector import LABEL_CHANGE
    from ccdcore.change.session import session_change

    code, _, err = run("report", str(ASSETS / "change"), "-o", str(tmp_path / "c.html"))
    assert code == 0, err
    assert "change detection" in err
    text = (tmp_path / "c.html").read_text()
    change = section(text, "change")
    result, _ = session_change(open_session(ASSETS / "change"))
    counts = result.counts()
    assert f"{LABEL_CHANGE}: change \u2014 {counts[LABEL_CHANGE]:,} pixels" in change
    assert f"0: unchanged (background) \u2014 {counts[0]:,} pixels" in change
    assert f'<td class="num">{result.threshold:.4g}</td>' in change
    for id_ in ("change-labels", "change-d2"):
        assert re.search(rf'<figure class="ccd-report-plot[^"]*" id="{id_}"', text), id_
    # no estimate of the product can be made from two brackets: every one is listed skipped
    assert "Skipped estimates" in text and "no ptc frames" in section(text, "skipped")


# ------------------------------------------------------------------------------ EMVA 1288 ------
def emva_dict() -> dict:
    """Figures, notes and an SNR curve to write over the demo's EMVA 1288 figures."""
    u_p = [100.0, 1000.0, 5000.0, 20000.0]
    return {"K": 0.1, "K_err": 0.002, "QE": 50.0, "QE_err": 1.0, "sigma_d": 4.2,
            "sigma_d_err": 0.1, "sigma_d_ptc": None, "u_e_sat": 32000.0, "u_p_sat": 64000.0,
            "u_p_min": 11.3, "SNR_max": 181.0, "DR": 5800.0, "DR_dB": 75.3, "LE_min": -0.01,
            "LE_max": 0.02, "DSNU1288": None, "DSNU1288_err": None, "PRNU1288": 0.5,
            "notes": ["a note about <saturation>"],
            "snr_curve": {"u_p": u_p, "snr": [5.0, 20.0, 48.0, None],
                          "snr_model": [5.1, 21.0, 49.0, 99.0]}}


@pytest.fixture(scope="module")
def emva_demo() -> EmvaSummary:
    """The EMVA 1288 figures of the emva1288 demo as a product holds them."""
    from ccdcore.emva.datasheet import emva_figures

    return emva_figures(ASSETS / "emva1288").summary()


def with_emva(product: CalibrationProduct, emva: EmvaSummary | None) -> CalibrationProduct:
    return dataclasses.replace(product, emva1288=emva)


def test_emva1288_figures_table_notes_and_plots(h94, emva_demo):
    emva_figs = EmvaSummary.from_dict({**emva_demo.to_dict(), **emva_dict()}, "emva_dict")
    text = build_report(with_emva(h94["product"], emva_figs))
    emva = section(text, "emva1288")
    assert html.escape(format_pm(0.1, 0.002, unit="DN/e\u207b")) in emva
    assert format_pm(50.0, 1.0, unit="%") in emva
    assert ('<tr><td>Dark signal nonuniformity</td><td>DSNU1288</td><td class="num">not '
            'determined</td>') in emva
    assert "a note about &lt;saturation&gt;" in emva
    for id_ in ("emva-snr", "emva-ptc", "emva-linearity"):
        assert f'id="{id_}"' in text, id_


def test_emva1288_figures_with_missing_keys_are_refused_and_none_is_no_section(h94, tmp_path):
    """Figures lacking keys cannot reach the report (``load_product`` refuses them, naming the
    key); a product without figures has no EMVA 1288 section."""
    folder = tmp_path / "calib"
    with_emva(h94["product"], None).save(folder)
    manifest = folder / "calibration.json"
    doc = json.loads(manifest.read_text())
    doc["emva1288"] = {"K": 0.1, "snr_curve": {"u_p": [1.0]}}
    manifest.write_text(json.dumps(doc))
    with pytest.raises(CcdError, match=r"'emva1288\.standard' is missing"):
        load_product(folder)
    assert 'id="emva1288"' not in build_report(with_emva(h94["product"], None))


# ------------------------------------------------------------------------------ properties -----
def test_building_from_a_product_computes_nothing(h94, monkeypatch):
    import ccdcore.change.session
    import ccdcore_report.build

    def refuse(*a, **k):
        raise AssertionError("recomputed")

    monkeypatch.setattr(ccdcore_report.build, "calibrate", refuse)
    monkeypatch.setattr(ccdcore_report.build, "estimate_all", refuse)
    monkeypatch.setattr(ccdcore.change.session, "session_change", refuse)
    session = open_session(ASSETS / "healey94")
    text = build_report(session, product=h94["product"])
    assert section(text, "noise") == section(h94["html"], "noise")


def test_strings_from_the_session_are_escaped(h94):
    product = dataclasses.replace(h94["product"], camera=Camera(
        name='<script>alert("x")</script> & co', bits=8, layout="mono"),
        notes=("<b>bold</b>",))
    text = build_report(product)
    assert "<script>alert" not in text and "<b>bold</b>" not in text
    assert "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; co" in text
    assert "&lt;b&gt;bold&lt;/b&gt;" in text


def test_large_maps_are_reduced_and_the_caption_says_so(h94):
    rng = np.random.default_rng(11)
    shape = (1000, 2000)                    # 8 MB of float32: the file must stay far smaller
    dark = rng.normal(10.0, 0.5, shape).astype(np.float32)
    product = CalibrationProduct(maps={"dark": dark}, camera=Camera(name="big", bits=12))
    text = build_report(product)
    factor = int(np.ceil(max(shape) / MAX_MAP_SIDE))
    assert f"2000 \u00d7 1000 px drawn at 1:{factor} (each screen pixel is the mean of a " \
           f"{factor}\u00d7{factor} block" in text
    assert len(text.encode()) < len(h94["html"].encode()) + dark.nbytes / 4


# ------------------------------------------------------------------------------ bad input ------
def test_bad_inputs_exit_2_naming_the_file_and_write_nothing(h94, tmp_path):
    from ccdcore.io.frames import write_outputs

    out = tmp_path / "r.html"
    write_outputs(tmp_path, {out.name: lambda p: p.write_text("an earlier report")})
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "calibration.json").write_text("{not json")
    plain = tmp_path / "plain"
    (plain / "scene").mkdir(parents=True)
    from ccdcore.io.frames import write_image

    write_image(plain / "scene" / "a.tif", np.full((8, 8), 100, np.uint16), bits=12)
    missing = tmp_path / "nowhere"
    for source, named in ((missing, missing), (broken, broken / "calibration.json"),
                          (plain, plain)):
        code, _, err = run("report", str(source), "-o", str(out))
        assert code == 2, (source, err)
        errors = [line for line in err.splitlines() if "error:" in line]
        assert len(errors) == 1 and err.splitlines()[-1] == errors[0], err
        assert errors[0].startswith(f"ccdcore report: error: {named}: "), err
        assert "Traceback" not in err
        assert out.read_text() == "an earlier report"
    # an output over an input, or a folder
    manifest = h94["calib"] / "calibration.json"
    before = manifest.read_bytes()
    code, _, err = run("report", str(h94["calib"]), "-o", str(manifest))
    assert code == 2 and "overwrite an input" in err
    assert manifest.read_bytes() == before
    session_toml = ASSETS / "healey94" / "session.toml"
    code, _, err = run("report", str(ASSETS / "healey94"), "-o", str(session_toml))
    assert code == 2 and str(session_toml) in err
    code, _, err = run("report", str(h94["calib"]), "-o", str(tmp_path))
    assert code == 2 and "is a folder" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [".ccdcore-outputs.json", "broken", "plain",
                                                         "r.html"]

