"""K̂ band by band on a Dask cluster (ccdcore.distributed.client.fixed_pattern_bands).

eqs. 45–50 run on the workers in bands of rows, so no process holds the n1 full-frame averages;
the result must equal the streamed :class:`~ccdcore.fixedpattern.FixedPattern` exactly: every map
``np.array_equal``, σ̂, the configuration levels and the noise ``==`` (numpy's pairwise sums are
rebuilt from the bands' pieces, and ē_i's column running sums are carried from band to band).
Small bands (16 and 7 rows) force many halos and chained bands.  Nothing is timed.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest


from ccdcore.distributed import band_tasks as dask_bands
from ccdcore.distributed import kmap as dask_kmap
from ccdcore.distributed import client as ccd_dist
from ccdcore.distributed.client import DaskReducer  # noqa: E402
from ccdcore.dark.frame import dark_reference  # noqa: E402
from ccdcore.errors import CcdError  # noqa: E402
from ccdcore.fixedpattern import fixed_pattern_map  # noqa: E402
from ccdcore.kmap_kernels import box_mean, box_mean_band, pw_pieces, pw_total  # noqa: E402
from ccdcore.session import open_session  # noqa: E402

HEALEY = Path(__file__).resolve().parents[1] / "assets" / "healey94"
MAPS = ("K", "K_var", "n1_used", "rejected", "m_bar")


@pytest.fixture(scope="module")
def healey():
    return open_session(HEALEY)


@pytest.fixture(scope="module")
def dark(healey):
    return dark_reference(healey)


def _assert_same(a, b):
    for name in MAPS:
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    for name in ("sigma_hat", "config_levels", "noise_var_e", "var_bound", "mean",
                 "spatial_std", "notes", "config_ids", "n1", "n2", "window"):
        assert getattr(a, name) == getattr(b, name), name
    assert b.to_dict() == a.to_dict()


def _message(fn):
    with pytest.raises(CcdError) as info:
        fn()
    return type(info.value), str(info.value)


# --------------------------------------------------------------------------------------------
# the pieces, without a cluster
def test_pairwise_pieces_rebuild_numpy_sum():
    """numpy's pairwise sum of a whole frame, rebuilt from cuts anywhere (inside a block,
    blocks spanning several cuts, single values): the same bits as ``numpy.sum``/``mean``."""
    rng = np.random.default_rng(45)
    for shape in ((192, 256), (7, 13), (100, 3), (1, 5)):
        x = rng.standard_normal(shape) * 1e3 + rng.standard_normal(shape)
        n, flat = x.size, x.ravel()
        for cuts in ([0, n], sorted({0, n, *rng.integers(0, n, 9).tolist()}),
                     list(range(0, n, max(1, n // 50))) + [n]):
            pieces = [pw_pieces(flat[a:b], a, n) for a, b in zip(cuts[:-1], cuts[1:])]
            assert pw_total(n, pieces) == float(np.sum(x))
            assert pw_total(n, pieces) / n == float(x.mean())


@pytest.mark.parametrize("window", [3, 5, 9])
def test_box_mean_band_equals_whole_frame(window):
    """ē band by band (halo m//2 + 1 above, m//2 below, running sums carried): the same bits
    as the whole frame's ē, for every band height down to 1 row."""
    rng = np.random.default_rng(window)
    x = rng.standard_normal((61, 37)) * 100 + 50
    ref = np.empty_like(x)
    box_mean(x, window, ref)
    s1 = window // 2
    for band in (1, 2, 7, 16, 61):
        out, tmp = np.empty_like(x), np.empty(x.shape[1])
        for y0 in range(0, x.shape[0], band):
            rows = min(band, x.shape[0] - y0)
            top, bottom = min(s1 + 1, y0), min(s1, x.shape[0] - y0 - rows)
            part = np.ascontiguousarray(x[y0 - top:y0 + rows + bottom])
            box_mean_band(part, window, x.shape[0], y0 - top, y0, tmp, out[y0:y0 + rows])
        assert np.array_equal(out, ref), band


# --------------------------------------------------------------------------------------------
# on the cluster
@pytest.mark.parametrize("band_rows", [None, 16, 7])
def test_equal_to_streamed(client, healey, dark, band_rows):
    streamed = fixed_pattern_map(healey, dark)
    configs = list(healey.fixed_pattern_configs().items())
    _assert_same(streamed, ccd_dist.fixed_pattern_bands(client, configs, dark,
                                                        band_rows=band_rows))


def test_fixed_pattern_map_uses_the_bands(client, healey, dark, monkeypatch):
    """``fixed_pattern_map(client=)``: the default bands (one band here), then 16-row bands
    through BAND_BYTES; the dark reference computed inside on the cluster too."""
    streamed = fixed_pattern_map(healey, dark)
    _assert_same(streamed, fixed_pattern_map(healey, dark, reducer=DaskReducer(client)))
    calls = []
    real = dask_bands.bands
    monkeypatch.setattr(dask_bands, "bands", lambda *a, **k: calls.append(real(*a, **k)) or
                        calls[-1])
    n1 = len(healey.fixed_pattern_configs())
    monkeypatch.setattr(dask_bands, "BAND_BYTES", 16 * 3 * 8 * 256 * (n1 // 2 + 1))
    _assert_same(streamed, fixed_pattern_map(healey, reducer=DaskReducer(client)))
    assert len(calls[-1]) == 12 and {rows for _, rows in calls[-1]} == {16}


@pytest.mark.parametrize("window,center", [(5, "median"), (9, "mean"), (3, "median")])
def test_windows_and_centres(client, healey, dark, window, center):
    streamed = fixed_pattern_map(healey, dark, window=window, center=center, p=1.0)
    configs = list(healey.fixed_pattern_configs().items())
    for band_rows in (16, 5):
        _assert_same(streamed, ccd_dist.fixed_pattern_bands(
            client, configs, dark, window=window, center=center, p=1.0, band_rows=band_rows))


def test_bad_frame_same_message(client, healey, tmp_path, monkeypatch):
    """Garbage in the pixel data of C03_F01 (only the workers meet it): the streamed error."""
    root = tmp_path / "healey94"
    shutil.copytree(HEALEY, root)
    s = open_session(root)
    for r in s.frames:
        s.header(r)
    rec = s.fixed_pattern_configs()[3][1]
    data = bytearray(rec.path.read_bytes())
    data[200:2000] = np.random.default_rng(14).integers(0, 256, 1800, np.uint8).tobytes()
    rec.path.write_bytes(bytes(data))
    zeros = np.zeros((192, 256))
    streamed = _message(lambda: fixed_pattern_map(s, zeros))
    assert "C03_F01.tif" in streamed[1]
    n1 = len(s.fixed_pattern_configs())
    monkeypatch.setattr(dask_bands, "BAND_BYTES", 16 * 3 * 8 * 256 * (n1 // 2 + 1))
    assert _message(lambda: fixed_pattern_map(s, zeros, reducer=DaskReducer(client))) == streamed


def test_unlit_configuration_same_message(client, healey):
    """A dark reference above every frame: the first configuration is not above the dark
    level, with the streamed message (level from the bands' pairwise sums)."""
    high = np.full((192, 256), 300.0)
    streamed = _message(lambda: fixed_pattern_map(healey, high))
    assert "not above the dark level" in streamed[1]
    configs = list(healey.fixed_pattern_configs().items())
    assert _message(lambda: ccd_dist.fixed_pattern_bands(client, configs, high,
                                                         band_rows=16)) == streamed


def _float_configs(tmp_path, seed, h=53, w=41):
    """Five configurations of three float64 frames (not integer-valued), a spot in the third
    (rejected slopes), and a float dark map."""
    from ccdcore.io.frames import write_image

    rng = np.random.default_rng(seed)
    gain = 1.0 + rng.normal(0.0, 0.01, (h, w))
    yy, xx = np.mgrid[0:h, 0:w]
    configs = {}
    for c in range(5):
        light = 300.0 + 40.0 * c + 0.7 * (1 + c) * xx + 0.3 * yy
        if c == 2:
            light[20:24, 10:14] *= 1.2                               # a spot: rejected
        configs[c + 1] = [write_image(tmp_path / f"C{c}_F{k}.tif",
                                      gain * light + rng.normal(0.0, 1.5, (h, w)) / 3.0)
                          for k in range(3)]
    return configs, 10.0 + rng.normal(0.0, 0.5, (h, w)) / 7.0


@pytest.mark.parametrize("window", [5, 9])
def test_float_frames(client, tmp_path, window):
    """Float frames: numpy's pairwise sums (levels, noise, σ̂) round, so only the rebuilt
    pairwise blocks give the streamed bits (on healey94's quarter-integer averages every sum is
    exact).  A spot in one configuration makes rejections."""
    from ccdcore.io.frames import read_image

    configs, dark = _float_configs(tmp_path, 47 + window)
    streamed = fixed_pattern_map({c: [read_image(p) for p in ps] for c, ps in configs.items()},
                                 dark, window=window)
    assert streamed.rejected.any()
    for band_rows in (None, 16, 6):
        _assert_same(streamed, ccd_dist.fixed_pattern_bands(
            client, list(configs.items()), dark, window=window, band_rows=band_rows))


def test_slope_chain_carries_the_column_sums(tmp_path):
    """The slope tasks of the bands, run here in a chain: the column running sums handed from
    band to band end as those of one pass down the whole frame (scipy's running sums, whose
    rounding at a row depends on every row above).  A filter of each band and its halo alone
    gives ē to within rounding only, which the float32 slopes nearly always hide; this checks
    the chain itself."""
    from ccdcore.io.frames import read_image
    from ccdcore.stats import pixel_moments

    configs, dark = _float_configs(tmp_path, 50)
    groups = tuple(ccd_dist.frames_of(ps) for ps in configs.values())
    h, w = dark.shape
    window, s1 = 5, 2
    want = []
    for ps in configs.values():
        e = pixel_moments(read_image(p) for p in ps).mean - dark
        tmp = np.empty(w)
        box_mean_band(e, window, h, 0, 0, tmp, np.empty((h, w)))
        want.append(tmp)
    tmp = None
    for y0, rows in ccd_dist.bands(h, w, band_rows=8):
        top, bottom = min(s1 + 1, y0), min(s1, h - y0 - rows)
        p1 = dask_kmap._kmap_average_task(groups, dark[y0 - top:y0 + rows + bottom], y0, rows,
                                          top, bottom, w, h)
        out = dask_kmap._kmap_slopes_task(p1, tmp, y0, rows, top, h, window, False)
        tmp = dask_kmap._kmap_pick(out, "tmp")
    assert np.array_equal(tmp[1], np.array(want))
