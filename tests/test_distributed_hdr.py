"""The HDR merge and change detection per row band on a Dask cluster.

One real ``LocalCluster`` of two worker processes (one thread each) serves the module.
:func:`ccdcore.distributed.client.band_merge` reads each band of every bracket frame with a halo of
rows covering the blooming disk and runs the same :func:`ccdcore.response.hdr.merge` on it; the
assembled maps must be **bit-identical** to the whole-frame merge (``assert_array_equal``,
NaN-aware), on tsin01 (mono, 8 frames, saturated pixels in the two longest exposures), on the
change demo (RGB) and on a synthetic Bayer bracket whose saturated spots are placed so that band
edges cut through their blooming disks; with bands of a few rows every edge is exercised.  Then
``session_change`` and the ``hdr`` / ``change`` verbs with a cluster against the streamed ones,
and a bad bracket file.  Nothing is timed.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest


from ccdcore.distributed import client as ccd_dist
from ccdcore.distributed.client import DaskReducer  # noqa: E402
from ccdcore.change.detector import ChangeOptions  # noqa: E402
from ccdcore.change.session import session_change  # noqa: E402
from ccdcore.cli.command import main  # noqa: E402
from ccdcore.errors import CcdError  # noqa: E402
from ccdcore.io.frames import read_image, write_image  # noqa: E402
from ccdcore.response.brackets import bracket_records  # noqa: E402
from ccdcore.response.hdr import (FLAG_BLOOMED, FLAG_SATURATED, ResponseModel,  # noqa: E402
                                  merge, merge_bracket)
from ccdcore.session import open_session  # noqa: E402

ASSETS = Path(__file__).resolve().parents[1] / "assets"
TSIN = ASSETS / "tsin01"
CHANGE = ASSETS / "change"
G = (np.arange(256) / 255.0) ** 1.2
#: the change demo's noise terms (truth.json); any fixed model serves: only equality is tested
NOISE = (0.015, 0.01, 1.0)


def _same(out, ref):
    assert out.channels == ref.channels and out.layout == ref.layout
    for key in ("radiance", "sigma", "flags", "used"):
        a, b = getattr(out, key), getattr(ref, key)
        assert a.dtype == b.dtype and a.shape == b.shape, key
        np.testing.assert_array_equal(a, b, err_msg=key)


def _tsin():
    s = open_session(TSIN)
    recs = bracket_records(s)
    truth = json.loads((TSIN / "truth.json").read_text())
    model = ResponseModel(np.asarray(truth["g"], np.float64),
                          np.array([f["a"] for f in truth["frames"]], np.float64),
                          np.array([f["b"] for f in truth["frames"]], np.float64),
                          truth["sigma_s"], truth["sigma_c1"], truth["sigma_c2"])
    return recs, [read_image(r.path) for r in recs], model


def _change_models(recs):
    t = np.array([r.exposure for r in recs], np.float64)
    return {c: ResponseModel(G, t, np.zeros(t.size), *NOISE) for c in "RGB"}


@pytest.fixture(scope="module")
def bayer(tmp_path_factory):
    """A synthetic 3-frame Bayer (RGGB) bracket of 40 × 24: a smooth scene with saturated spots
    in every frame (flag SATURATED, their neighbours BLOOMED) and spots saturated in the longest
    frame only; the spots' rows are spread so that 2-, 4- and 6-row bands cut through their
    disks at every offset."""
    root = tmp_path_factory.mktemp("bayer")
    rng = np.random.default_rng(14)
    h, w = 40, 24
    E = np.linspace(0.05, 0.6, h * w).reshape(h, w) * (1 + 0.1 * rng.random((h, w)))
    for k, y in enumerate((3, 8, 14, 19, 25, 30, 36)):
        E[y, (5 * k + 3) % w] = 50.0            # saturated in every frame
        E[(y + 2) % h, (5 * k + 11) % w] = 3.0  # saturated in the longest frame only
    t = np.array([0.25, 0.5, 1.0])
    paths = []
    for k, tk in enumerate(t):
        v = np.clip(tk * E, 0, 1)
        z = np.clip(np.round(255 * v ** (1 / 1.2) + rng.normal(0, 1, E.shape)), 0, 255)
        z[tk * E >= 1] = 255
        paths.append(write_image(root / f"k{k}.tif", z.astype(np.uint8)))
    models = {c: ResponseModel(G, t, np.zeros(3), *NOISE) for c in ("R", "G1", "G2", "B")}
    frames = [read_image(p) for p in paths]
    return [str(p) for p in paths], frames, models


# --------------------------------------------------------------------------------------------
def test_halo():
    assert ccd_dist.merge_halo("mono", 3) == 3 and ccd_dist.merge_halo("rgb", 3) == 3
    assert ccd_dist.merge_halo("bayer-rggb", 3) == 6 and ccd_dist.merge_halo("mono", 0) == 0
    assert ccd_dist.merge_halo("mono", -1) == 0


@pytest.mark.parametrize("radius", [3, 1, 0])
def test_band_merge_tsin01(client, radius):
    """Mono, 8 frames (the weights' sums over 8 images); 4851 saturated pixels in the longest
    frame, so the blooming mask changes the radiance along many band edges."""
    recs, frames, model = _tsin()
    ref = merge(frames, model, layout="mono", bloom_radius=radius)
    for rows in (None, 1, 2, 3, 5, 7):
        out = ccd_dist.band_merge(client, recs, model, layout="mono", bloom_radius=radius,
                                  shape=frames[0].shape, band_rows=rows)
        _same(out, ref)


def test_band_merge_change_rgb(client):
    s = open_session(CHANGE)
    for role in ("reference", "target"):
        recs = bracket_records(s, role=role)
        frames = [read_image(r.path) for r in recs]
        models = _change_models(recs)
        ref = merge(frames, models, layout="rgb", bloom_radius=3)
        assert ref.radiance.shape == frames[0].shape
        for rows in (None, 2, 3, 4, 7):
            _same(ccd_dist.band_merge(client, recs, models, layout="rgb", bloom_radius=3,
                                      shape=frames[0].shape, band_rows=rows), ref)


@pytest.mark.parametrize("radius", [3, 2])
def test_band_merge_bayer_cuts_through_bloom(client, bayer, radius):
    paths, frames, models = bayer
    ref = merge(frames, models, layout="bayer-rggb", bloom_radius=radius)
    assert ref.radiance.shape == (20, 12, 4)
    assert np.any(ref.flags == FLAG_SATURATED) and np.any(ref.flags == FLAG_BLOOMED)
    for rows in (None, 2, 4, 6):
        out = ccd_dist.band_merge(client, paths, models, layout="bayer-rggb",
                                  bloom_radius=radius, shape=frames[0].shape, band_rows=rows)
        _same(out, ref)


def test_band_merge_mono_flags_at_band_edges(client, bayer):
    """The Bayer bracket read as mono: saturated and bloomed pixels right at the edges of
    1- to 5-row bands."""
    paths, frames, _ = bayer
    model = ResponseModel(G, np.array([0.25, 0.5, 1.0]), np.zeros(3), *NOISE)
    ref = merge(frames, model, layout="mono", bloom_radius=3)
    assert np.any(ref.flags == FLAG_SATURATED) and np.any(ref.flags == FLAG_BLOOMED)
    for rows in (1, 2, 3, 4, 5):
        _same(ccd_dist.band_merge(client, paths, model, layout="mono", bloom_radius=3,
                                  shape=frames[0].shape, band_rows=rows), ref)


def test_merge_bracket_streamed_and_cluster(client):
    recs, frames, model = _tsin()
    streamed = merge_bracket(recs, model, layout="mono")
    _same(streamed, merge(frames, model, layout="mono"))
    _same(merge_bracket(recs, model, layout="mono", reducer=DaskReducer(client), band_rows=9), streamed)


# --------------------------------------------------------------------------------------------
def _message(fn):
    with pytest.raises(CcdError) as info:
        fn()
    return type(info.value), str(info.value)


def test_merge_errors_same_message(client, bayer, tmp_path):
    paths, frames, models = bayer
    # a model per channel missing; a calibration of another number of images; codes above
    # the response's levels
    cases = [({c: m for c, m in models.items() if c != "B"}, paths),
             ({c: ResponseModel(G, m.a[:2], m.b[:2], *NOISE) for c, m in models.items()},
              paths)]
    short = {c: ResponseModel(G[:128], m.a, m.b, *NOISE) for c, m in models.items()}
    cases.append((short, paths))
    for ms, ps in cases:
        streamed = _message(lambda: merge([read_image(p) for p in ps], ms,
                                          layout="bayer-rggb"))
        cluster = _message(lambda: merge_bracket(ps, ms, layout="bayer-rggb", reducer=DaskReducer(client),
                                                 band_rows=4))
        assert cluster == streamed
    # tsin01's longest frame with garbage in its lower strips, and a response of 128 codes:
    # the top bands read every frame and fail in the merge (codes outside the response), the
    # bands below fail to read the frame, which is what the streamed path reports (it reads
    # every frame first)
    recs, _, model = _tsin()
    data = bytearray(Path(recs[-1].path).read_bytes())
    data[12000:14000] = np.random.default_rng(14).integers(0, 256, 2000, np.uint8).tobytes()
    (tmp_path / "bad.tif").write_bytes(bytes(data))
    ps = [str(r.path) for r in recs[:-1]] + [str(tmp_path / "bad.tif")]
    low = ResponseModel(G[:128], model.a, model.b, *NOISE)
    streamed = _message(lambda: merge_bracket(ps, low, layout="mono"))
    assert "bad.tif" in streamed[1]
    assert _message(lambda: merge_bracket(ps, low, layout="mono", reducer=DaskReducer(client),
                                          band_rows=8)) == streamed
    odd = write_image(tmp_path / "odd.tif", np.zeros((40, 22), np.uint8))
    ps = paths[:2] + [str(odd)]
    streamed = _message(lambda: merge([read_image(p) for p in ps], models,
                                      layout="bayer-rggb"))
    assert _message(lambda: merge_bracket(ps, models, layout="bayer-rggb",
                                          reducer=DaskReducer(client))) == streamed


@pytest.fixture
def damaged(tmp_path):
    """A copy of the change demo, headers cached, then the target's k02 cut short: only the
    workers meet it."""
    root = tmp_path / "change"
    shutil.copytree(CHANGE, root)
    s = open_session(root)
    for r in s.frames:
        s.header(r)
    recs = bracket_records(s, role="target")
    cut = recs[2].path
    data = cut.read_bytes()
    cut.write_bytes(data[:len(data) // 2])
    return s


def test_bad_bracket_file_same_message(client, damaged):
    calib_free = dict(calib=None, bloom_radius=3)
    streamed = _message(lambda: session_change(damaged, ChangeOptions(), **calib_free))
    assert "k02.tif" in streamed[1] and "\n" not in streamed[1]
    cluster = _message(lambda: session_change(damaged, ChangeOptions(), reducer=DaskReducer(client),
                                              band_rows=8, **calib_free))
    assert cluster == streamed
    recs = bracket_records(damaged, role="target")
    models = _change_models(recs)
    streamed = _message(lambda: merge_bracket(recs, models, layout="rgb"))
    assert _message(lambda: merge_bracket(recs, models, layout="rgb", reducer=DaskReducer(client),
                                          session=damaged, band_rows=5)) == streamed


# --------------------------------------------------------------------------------------------
def test_session_change_with_client_equals_streamed(client):
    s = open_session(CHANGE)
    opts = ChangeOptions(pfa=0.01)
    streamed, s_in = session_change(s, opts)
    cluster, c_in = session_change(open_session(CHANGE), opts, reducer=DaskReducer(client),
                                   band_rows=11)
    for key in ("E_ref", "sigma_ref", "E_tgt", "sigma_tgt"):
        np.testing.assert_array_equal(getattr(c_in, key), getattr(s_in, key), err_msg=key)
    assert c_in.channels == s_in.channels and c_in.files == s_in.files
    np.testing.assert_array_equal(cluster.labels, streamed.labels)
    np.testing.assert_array_equal(cluster.d2, streamed.d2)
    np.testing.assert_array_equal(cluster.valid, streamed.valid)
    assert cluster.threshold == streamed.threshold and cluster.scale == streamed.scale
    assert len(cluster.clusters) == len(streamed.clusters)
    for a, b in zip(cluster.clusters, streamed.clusters):
        np.testing.assert_array_equal(a.M, b.M)
        np.testing.assert_array_equal(a.M_cov, b.M_cov)
        assert a.pixels == b.pixels


# --------------------------------------------------------------------------------------------
def test_cli_hdr_workers_same_radiance(capsys, tmp_path):
    assert main(["hdr", str(TSIN), "-o", str(tmp_path / "s"), "--json"]) == 0
    streamed = json.loads(capsys.readouterr().out)
    assert main(["hdr", str(TSIN), "-o", str(tmp_path / "c"), "--json", "--workers", "2"]) == 0
    cluster = json.loads(capsys.readouterr().out)
    assert streamed["scheduler"] == ccd_dist.STREAMED
    assert cluster["scheduler"].startswith("dask tcp://") and "(2 workers)" in \
        cluster["scheduler"]
    assert cluster["flags"] == streamed["flags"]
    for name in ("radiance.exr", "sigma.exr", "flags.png"):
        a = read_image(tmp_path / "s" / name)
        b = read_image(tmp_path / "c" / name)
        np.testing.assert_array_equal(b, a, err_msg=name)
        assert (tmp_path / "c" / name).read_bytes() == (tmp_path / "s" / name).read_bytes()


def test_cli_change_scheduler(client, capsys, tmp_path):
    assert main(["change", str(CHANGE), "-o", str(tmp_path / "s"), "--json"]) == 0
    streamed = json.loads(capsys.readouterr().out)
    address = client.scheduler.address
    assert main(["change", str(CHANGE), "-o", str(tmp_path / "c"), "--json",
                 "--scheduler", address]) == 0
    cluster = json.loads(capsys.readouterr().out)
    assert cluster.pop("scheduler") == ccd_dist.describe(client)
    assert streamed.pop("scheduler") == ccd_dist.STREAMED
    for d in (streamed, cluster):
        d.pop("files")
    assert cluster == streamed
    for name in ("labels.png", "d2.exr"):
        np.testing.assert_array_equal(read_image(tmp_path / "c" / name),
                                      read_image(tmp_path / "s" / name))


def test_cli_hdr_bad_scheduler(capsys, monkeypatch, tmp_path):
    monkeypatch.setattr(ccd_dist, "CONNECT_TIMEOUT", 1)
    out = tmp_path / "unused"
    assert main(["change", str(CHANGE), "-o", str(out), "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert capsys.readouterr().err.startswith("ccdcore change: error: tcp://127.0.0.1:1: ")
    assert not out.exists()
    assert main(["hdr", str(TSIN), "-o", str(out), "--scheduler", "tcp://127.0.0.1:1"]) == 2
    assert capsys.readouterr().err.startswith("ccdcore hdr: error: tcp://127.0.0.1:1: ")
    assert not out.exists()


def test_cli_hdr_calib_frames_read_by_the_workers(client, capsys, tmp_path, monkeypatch):
    """With ``--calib`` and a cluster the client reads no frame (the workers do): the client's
    readers are made to fail, and the maps equal the streamed ones."""
    import ccdcore.io.frames
    import ccdcore.session.records

    assert main(["calibrate", str(TSIN), "-o", str(tmp_path / "p")]) == 0
    capsys.readouterr()
    assert main(["hdr", str(TSIN), "--calib", str(tmp_path / "p"), "-o", str(tmp_path / "s"),
                 "--json"]) == 0
    streamed = json.loads(capsys.readouterr().out)

    def refuse(*args, **kwargs):
        raise AssertionError("a frame was read on the client")

    monkeypatch.setattr(ccdcore.session.records, "read_image", refuse)
    monkeypatch.setattr(ccdcore.io.frames, "read_image", refuse)
    assert main(["hdr", str(TSIN), "--calib", str(tmp_path / "p"), "-o", str(tmp_path / "c"),
                 "--json", "--scheduler", client.scheduler.address]) == 0
    cluster = json.loads(capsys.readouterr().out)
    monkeypatch.undo()
    assert cluster["source"] == streamed["source"] and cluster["flags"] == streamed["flags"]
    for name in ("radiance.exr", "sigma.exr", "flags.png"):
        np.testing.assert_array_equal(read_image(tmp_path / "c" / name),
                                      read_image(tmp_path / "s" / name), err_msg=name)
