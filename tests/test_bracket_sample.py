"""Bracket traces at a camera's resolution: a bounded, even sample of the pixels, with every
check and the comparagrams made on every pixel; the HDR merge in bands of rows."""
from __future__ import annotations

import numpy as np
import pytest

from ccdcore.errors import CcdError
from ccdcore.response import brackets as br
from ccdcore.response import hdr_merge as hm


def _bracket(shape=(60, 80), n=4, seed=0, rgb=False):
    """A smooth scene at ``n`` exposures (8-bit), some pixels saturated in the longest."""
    rng = np.random.default_rng(seed)
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w]
    scene = 0.2 + 0.8 * (xx / w) * (0.5 + 0.5 * yy / h)
    t = 2.0 ** np.arange(n)
    frames = []
    for k in range(n):
        z = np.clip(scene * t[k] * 60 + rng.normal(0, 2, shape), 0, 255).astype(np.uint8)
        frames.append(np.stack([z, z // 2 + 1, z], -1) if rgb else z)
    return frames, t


def test_sample_is_bounded_deterministic_and_spread():
    frames, t = _bracket((120, 100))
    full = br.bracket_data(frames, t, 8)["L"]
    a = br.bracket_data(frames, t, 8, max_pixels=500)["L"]
    b = br.bracket_data(frames, t, 8, max_pixels=500)["L"]
    assert a.n_pixels == 500 < full.n_pixels
    assert np.array_equal(a.pixels, b.pixels) and np.array_equal(a.z, b.z)
    # a subset of the full traces, in increasing order, with the same values there
    assert np.all(np.diff(a.pixels) > 0)
    pos = np.searchsorted(full.pixels, a.pixels)
    assert np.array_equal(full.pixels[pos], a.pixels)
    for f in ("z", "valid", "kept"):
        assert np.array_equal(getattr(full, f)[:, pos], getattr(a, f))
    # spread over the frame: every tenth of the rows and of the columns holds some of it
    ys, xs = np.divmod(a.pixels, a.shape[1])
    assert np.unique(ys * 10 // a.shape[0]).size == 10
    assert np.unique(xs * 10 // a.shape[1]).size == 10
    # an even stride over the usable pixels' ranks
    assert np.ptp(np.diff(pos)) <= 1
    assert br.bracket_data(frames, t, 8, max_pixels=10 ** 9)["L"].n_pixels == full.n_pixels


def test_default_sample_is_fit_pixels_and_none_keeps_every_pixel():
    frames, t = _bracket((600, 500), n=2)
    d = br.bracket_data(frames, t, 8)["L"]
    assert d.n_pixels == br.FIT_PIXELS
    assert d.z.dtype == np.int32 and d.pixels.dtype == np.int64
    every = br.bracket_data(frames, t, 8, max_pixels=None)["L"]
    assert every.n_pixels > br.FIT_PIXELS


def test_max_pixels_none_reproduces_the_whole_traces():
    """``max_pixels=None``: the arrays the traces were built from before sampling, i.e.
    every pixel with a usable code and the masks of preprocess / kept_mask."""
    frames, t = _bracket((40, 50), rgb=True)
    out = br.bracket_data(frames, t, 8, layout="rgb", max_pixels=None, bloom_radius=2,
                          border=2)
    for c, d in out.items():
        i = "RGB".index(c)
        planes = [f[..., i] for f in frames]
        valid = np.stack([br.preprocess(p, 256, bloom_radius=2, border=2)
                          for p in planes]).reshape(len(planes), -1)
        kept = np.stack([br.kept_mask(p, 256, bloom_radius=2, border=2)
                         for p in planes]).reshape(len(planes), -1)
        keep = np.flatnonzero(valid.any(axis=0))
        z = np.stack([p.reshape(-1) for p in planes]).astype(np.int32)
        assert np.array_equal(d.pixels, keep)
        assert np.array_equal(d.z, z[:, keep]) and d.z.dtype == np.int32
        assert np.array_equal(d.valid, valid[:, keep])
        assert np.array_equal(d.kept, kept[:, keep])


def test_code_beyond_bits_outside_the_sample_is_refused():
    frames, t = _bracket((100, 100))
    frames = [f.astype(np.uint16) for f in frames]
    sample = br.bracket_data(frames, t, 8, max_pixels=50)["L"].pixels
    outside = next(p for p in range(1, 10_000) if p not in set(sample.tolist()))
    bad = frames[1].copy()
    bad.reshape(-1)[outside] = 300
    with pytest.raises(CcdError, match="exceeds the camera's 8 bits"):
        br.bracket_data([frames[0], bad] + frames[2:], t, 8, max_pixels=50)


def test_one_changing_pixel_outside_the_sample_is_not_a_constant_bracket():
    h, w = 50, 60
    frames = [np.full((h, w), 100, np.uint8) for _ in range(3)]
    with pytest.raises(CcdError, match="every usable code is 100"):
        br.bracket_data(frames, [1, 2, 4], 8, border=0, bloom_radius=0, max_pixels=10)
    sample = br.bracket_data([frames[0], frames[1] + (np.arange(h * w).reshape(h, w) == 0)],
                             [1, 2], 8, border=0, bloom_radius=0, max_pixels=10)["L"].pixels
    y, x = divmod(int(sample[1]) + 1, w)   # a pixel between two sampled ones
    assert int(sample[1]) + 1 not in set(sample.tolist())
    moved = [f.copy() for f in frames]
    moved[2][y, x] = 150
    d = br.bracket_data(moved, [1, 2, 4], 8, border=0, bloom_radius=0, max_pixels=10)["L"]
    assert y * w + x not in set(d.pixels.tolist())
    assert d.n_pixels == 10


def test_no_usable_pixel_still_refused():
    frames = [np.full((30, 30), 255, np.uint8)] * 2
    with pytest.raises(CcdError, match="no usable pixel"):
        br.bracket_data(frames, [1, 2], 8, max_pixels=5)


def test_pair_counts_are_the_comparagrams_of_every_pixel():
    frames, t = _bracket((30, 40), n=4, rgb=True)
    order = [2, 0, 3, 1]
    out = br.bracket_data([frames[i] for i in order], t[order], 8, layout="rgb", max_pixels=7)
    for c, d in out.items():
        i = "RGB".index(c)
        assert d.pair_counts is not None and d.pair_counts.shape == (3, 256, 256)
        assert d.pair_counts.dtype == np.int64
        for j in range(3):
            direct = np.zeros((256, 256), np.int64)
            np.add.at(direct, (frames[j][..., i].ravel(), frames[j + 1][..., i].ravel()), 1)
            assert np.array_equal(d.pair_counts[j], direct)
        assert d.take(np.arange(3)).pair_counts is d.pair_counts
    many = br.bracket_data([f[..., 0].astype(np.uint16) for f in frames], t, 13)["L"]
    assert many.pair_counts is None          # 8192 levels: more than PAIR_LEVELS_MAX


def test_dilate_disk_is_the_binary_dilation():
    from scipy import ndimage

    rng = np.random.default_rng(3)
    for r in range(0, 7):
        m = rng.random((23, 31)) < 0.05
        yy, xx = np.mgrid[-r:r + 1, -r:r + 1]
        disk = yy * yy + xx * xx <= r * r
        assert np.array_equal(br.dilate_disk(m, r), ndimage.binary_dilation(m, structure=disk))


def _reference_merge(frames, models, bloom_radius):
    """The whole-frame merge of eqs. 9, 18, 19 as stacked float64 arrays (the formulation the
    banded merge must equal bit for bit)."""
    out = []
    for c, model in models.items():
        z = np.stack([f if f.ndim == 2 else f[..., "RGB".index(c)] for f in frames]
                     ).astype(np.int64)
        L, N = model.levels, z.shape[0]
        clipped = (z <= 0) | (z >= L - 1)
        bloomed = np.stack([br.bloom_mask(p, L, bloom_radius) for p in z])
        usable, fallback = ~clipped & ~bloomed, ~clipped
        a, b = model.a[:, None, None], model.b[:, None, None]
        sig = np.maximum(np.stack([hm.noise_sigma(model, z[k], k) for k in range(N)]), 1e-12)
        pred = (model.g[z] - b) / a

        def combine(mask):
            q = np.where(mask, a / sig, 0.0)
            total = q.sum(axis=0)
            n = mask.sum(axis=0)
            with np.errstate(invalid="ignore", divide="ignore"):
                return (q * np.where(mask, pred, 0.0)).sum(axis=0) / total, np.sqrt(n) / total, n

        r, s, n = combine(usable)
        flags = np.zeros(z.shape[1:], np.uint8)
        none = n == 0
        r2, s2, n2 = combine(fallback)
        bo = none & (n2 > 0)
        r, s, n = np.where(bo, r2, r), np.where(bo, s2, s), np.where(bo, n2, n)
        flags[bo] = hm.FLAG_BLOOMED
        rest = none & (n2 == 0)
        order = np.argsort(model.a)
        short, long_ = int(order[0]), int(order[-1])
        sat = rest & (z[short] >= L - 1)
        dark = rest & ~sat
        r = np.where(sat, (model.g[L - 1] - model.b[short]) / model.a[short], r)
        r = np.where(dark, (model.g[1] - model.b[long_]) / model.a[long_], r)
        s = np.where(rest, np.inf, s)
        flags[sat], flags[dark] = hm.FLAG_SATURATED, hm.FLAG_DARK
        out.append((r, s, flags, n.astype(np.int16)))
    return out


@pytest.mark.parametrize("band_pixels", [1, 97, 1000, 2 ** 18])
def test_banded_merge_equals_the_whole_frame_merge_bit_for_bit(monkeypatch, band_pixels):
    rng = np.random.default_rng(5)
    h, w, n = 37, 45, 4
    scene = rng.random((h, w)) ** 3
    t = np.array([0.5, 1.0, 3.0, 9.0])
    frames = []
    for k in range(n):
        z = np.clip(scene * t[k] * 300 + rng.normal(0, 3, (h, w)), 0, 255).astype(np.uint8)
        frames.append(np.stack([z, z // 2, np.minimum(z.astype(int) * 2, 255)], -1
                               ).astype(np.uint8))
    frames[0][:3, :3] = 255                      # saturated in every image
    frames[-1][-3:, -3:] = 0                     # dark in every image
    g = np.cumsum(rng.random(256))
    g /= g[-1]
    models = {c: hm.ResponseModel(g, t * rng.uniform(0.9, 1.1, n), rng.normal(0, 0.01, n),
                                  0.01, 0.002, 0.3) for c in "RGB"}
    monkeypatch.setattr(hm, "BAND_PIXELS", band_pixels)
    got = hm.merge(frames, models, layout="rgb", bloom_radius=3)
    want = _reference_merge(frames, models, 3)
    for i, name in enumerate(("radiance", "sigma", "flags", "used")):
        ref = np.stack([o[i] for o in want], axis=-1)
        arr = getattr(got, name)
        assert arr.dtype == ref.dtype and arr.tobytes() == ref.tobytes(), name
    assert set(np.unique(got.flags).tolist()) >= {hm.FLAG_OK, hm.FLAG_SATURATED, hm.FLAG_DARK,
                                                   hm.FLAG_BLOOMED}
