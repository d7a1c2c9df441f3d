"""The reductions over frames on a Dask cluster (ccdcore.distributed.client).

One real ``LocalCluster`` of two worker processes (one thread each) serves the module. On the
bundled demos every wired reduction equals the streamed one: ``np.array_equal`` for the moment
maps (means, variances, the maps built from them, the uncertainty maps), and the stated relative
tolerance ``PTC_RTOL`` (1e-12) for photon transfer, whose σ̂²_N is merged over bands.  Small bands
(a few rows, an odd height, so the last band is short) exercise the band edges.  A worker killed
mid-run, a truncated or corrupt file, a bad scheduler address are covered; nothing is timed.
"""
from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest


from ccdcore.distributed import band_tasks as dask_bands
from ccdcore.distributed import client as ccd_dist
from ccdcore.distributed.client import DaskReducer  # noqa: E402
from ccdcore.cli.command import main  # noqa: E402
from ccdcore.dark.frame import dark_reference  # noqa: E402
from ccdcore.errors import CcdError  # noqa: E402
from ccdcore.fixedpattern import fixed_pattern_map  # noqa: E402
from ccdcore.io.frames import read_image  # noqa: E402
from ccdcore.flatfield.fit import flat_field, flat_field_from_session  # noqa: E402
from ccdcore.noise import photon_transfer  # noqa: E402
from ccdcore.product.make import calibrate  # noqa: E402
from ccdcore.progress import Cancelled, Tracker, tracking  # noqa: E402
from ccdcore.session import open_session  # noqa: E402
from ccdcore.stats import pixel_moments  # noqa: E402

ASSETS = Path(__file__).resolve().parents[1] / "assets"
HEALEY = ASSETS / "healey94"
DELASARTE = ASSETS / "delasarte07"
RTOL = ccd_dist.PTC_RTOL


@pytest.fixture(scope="module")
def healey():
    return open_session(HEALEY)


@pytest.fixture(params=["one band", "7-row bands"])
def band_rows(request, monkeypatch):
    """The default (the demo frames fit one band), or bands of 7 rows (an odd height: the last
    band is shorter, and the rows of neighbouring bands meet at every 7th row)."""
    if request.param == "7-row bands":
        # 7 rows of healey94's 256 px (three float64 accumulators); delasarte07's 96 × 3 px
        # frames get 6-row bands
        monkeypatch.setattr(dask_bands, "BAND_BYTES", 7 * 3 * 8 * 256)
        return 7
    return None


def _same(a, b):
    return np.array_equal(a, b, equal_nan=True)


# --------------------------------------------------------------------------------------------
def test_bands_cover_every_row_once():
    for h, rows, even in ((192, 7, False), (192, 192, False), (191, 8, False), (64, 7, True),
                          (82, 20, True),
                          (5, 100, False), (1, 1, False)):
        cut = ccd_dist.bands(h, 10, band_rows=rows, even=even)
        covered = np.concatenate([np.arange(y, y + n) for y, n in cut])
        assert np.array_equal(covered, np.arange(h))
        assert max(n for _, n in cut) <= max(rows, 2 if even else 1)
        assert len({n for _, n in cut[:-1]}) <= 1 and cut[-1][1] <= cut[0][1]
        if even:
            assert all(y % 2 == 0 for y, _ in cut)
    assert [n for _, n in ccd_dist.bands(2048, 10, band_rows=682)] == [512] * 4
    # default: three float64 accumulators of at most BAND_BYTES, about that much
    cut = ccd_dist.bands(100_000, 4096)
    assert all(n * 4096 * 24 <= ccd_dist.BAND_BYTES for _, n in cut)
    assert cut[0][1] * 4096 * 24 > 0.9 * ccd_dist.BAND_BYTES
    with pytest.raises(CcdError, match="band_rows"):
        ccd_dist.bands(10, 10, band_rows=0)


def test_band_moments_equal_pixel_moments(client, healey, band_rows):
    recs = healey.fixed_pattern_configs()[1] + healey.fixed_pattern_configs()[2]
    streamed = pixel_moments(healey.iter_frames(recs))
    cluster = ccd_dist.band_moments(client, recs)
    assert cluster.n == streamed.n == len(recs)
    assert _same(cluster.mean, streamed.mean) and _same(cluster.var, streamed.var)
    # the order of the frames matters (the first frame is the shift): reversed is still the
    # same mean and variance to rounding, and bit-identical to the reversed stream
    rev = ccd_dist.band_moments(client, recs[::-1])
    assert _same(rev.var, pixel_moments(healey.iter_frames(recs[::-1])).var)


def test_band_moments_float_frames_keep_the_order(client, tmp_path, band_rows):
    """Float frames (not integer-valued) make the shifted sums order dependent: the bands are
    bit-identical to the stream only when every task takes the frames in the stream's order."""
    from ccdcore.io.frames import write_image

    rng = np.random.default_rng(1994)
    paths = []
    for k in range(9):
        frame = 1000.0 + 37.0 * k + rng.normal(0.0, 3.0, (40, 256))      # float64
        paths.append(write_image(tmp_path / f"f{k}.tif", frame))
    streamed = pixel_moments(read_image(p) for p in paths)
    got = ccd_dist.band_moments(client, paths)
    assert _same(got.mean, streamed.mean) and _same(got.var, streamed.var)


def test_dark_reference(client, healey, band_rows):
    a = dark_reference(healey)
    b = dark_reference(healey, reducer=DaskReducer(client))
    assert b.s == a.s
    for name in ("mean_map", "var_map", "hot_mask", "dead_mask", "sem_map"):
        assert _same(getattr(a, name), getattr(b, name)), name
    assert b.to_dict() == a.to_dict()


def test_fixed_pattern_map(client, healey, band_rows):
    dark = dark_reference(healey)
    a = fixed_pattern_map(healey, dark)
    b = fixed_pattern_map(healey, dark, reducer=DaskReducer(client))
    for name in ("K", "K_var", "n1_used", "rejected", "m_bar"):
        assert _same(getattr(a, name), getattr(b, name)), name
    assert b.to_dict() == a.to_dict()
    # the dark reference made inside, on the cluster too
    c = fixed_pattern_map(healey, reducer=DaskReducer(client))
    assert _same(c.K, a.K) and _same(c.K_var, a.K_var)


def _ptc_close(a, b):
    for key in ("A", "A_err", "sigma_c2", "sigma_c2_err", "chi2", "read_noise_e",
                "conversion_gain_e_per_dn", "black_level_dn"):
        assert getattr(b, key) == pytest.approx(getattr(a, key), rel=1e-9), key
    for p, q in zip(a.points, b.points, strict=True):
        assert q.mu == p.mu and q.mu_raw == p.mu_raw         # integer sums: exact
        assert q.clipped_fraction == p.clipped_fraction and q.n_pixels == p.n_pixels
        assert q.var == pytest.approx(p.var, rel=RTOL, abs=0)
        assert q.var_err == pytest.approx(p.var_err, rel=RTOL, abs=0)
        assert (q.used, q.exclusion) == (p.used, p.exclusion)


def test_photon_transfer(client, healey, band_rows):
    _ptc_close(photon_transfer(healey), photon_transfer(healey, reducer=DaskReducer(client)))
    roi = (13, 21, 101, 77)
    _ptc_close(photon_transfer(healey, roi=roi), photon_transfer(healey, roi=roi, reducer=DaskReducer(client)))


def test_photon_transfer_black_level_from_darks(client, healey, band_rows):
    """Without [camera] black_level, b0 is the dark frames' mean: summed band by band."""
    s = dataclasses.replace(healey, camera=dataclasses.replace(healey.camera, black_level=None))
    a, b = photon_transfer(s, roi=(5, 3, 200, 150)), photon_transfer(s, roi=(5, 3, 200, 150),
                                                                     reducer=DaskReducer(client))
    assert a.black_level_source == b.black_level_source == "dark_mean"
    assert b.black_level_dn == a.black_level_dn
    _ptc_close(a, b)


@pytest.mark.parametrize("setting", ["NZDI", "ZDI"])
def test_flat_field(client, band_rows, setting):
    """Both offset settings: ZDI's darks are clipped at zero, so the zero-dark fractions
    (counted band by band) are not all 0."""
    s = open_session(DELASARTE)
    a = flat_field_from_session(s, setting=setting)
    b = flat_field_from_session(s, setting=setting, reducer=DaskReducer(client))
    for name in ("G", "O", "flags", "G_rel_err"):
        assert _same(getattr(a, name), getattr(b, name)), name
    for which in ("dark", "base"):
        ma, mb = getattr(a, which), getattr(b, which)
        assert mb.n == ma.n and _same(ma.mean, mb.mean) and _same(ma.var, mb.var)
    assert b.to_dict() == a.to_dict()          # including the zero-dark fractions
    # flat_field itself with records (or paths) on the cluster
    darks = s.dark_groups(setting=b.setting)[b.dark_exposure]
    base = s.flat_groups(setting=b.setting)[b.base_key]
    c = flat_field([r.path for r in darks], list(base), layout="rgb", reducer=DaskReducer(client))
    assert _same(c.G, a.G) and _same(c.O, a.O)


def test_flat_field_bayer_bands_keep_the_cfa(client, healey, band_rows):
    """healey94's mono frames read as an RGGB mosaic: bands start on even rows (7-row bands
    become 6), so every band's CFA planes, zero counts and flags are the frame's."""
    darks = healey.dark_frames()
    base = max(healey.ptc_levels().values(), key=lambda recs: recs[0].level)
    a = flat_field(healey.iter_frames(darks), healey.iter_frames(base), layout="bayer-rggb")
    b = flat_field(darks, base, layout="bayer-rggb", reducer=DaskReducer(client))
    for name in ("G", "O", "flags"):
        assert _same(getattr(a, name), getattr(b, name)), name
    assert b.to_dict() == a.to_dict()
    if band_rows:
        assert {n % 2 for _, n in ccd_dist.bands(192, 256, even=True)} == {0}


def test_get_client_address_and_environment(client, monkeypatch):
    address = client.scheduler.address
    with ccd_dist.get_client(address) as c:
        assert ccd_dist.describe(c) == f"dask {address} (2 workers)"
    monkeypatch.setenv(ccd_dist.SCHEDULER_ENV, address)
    with ccd_dist.get_client() as c:
        assert c.scheduler.address == address
    monkeypatch.delenv(ccd_dist.SCHEDULER_ENV)
    with ccd_dist.get_client() as c:
        assert c is None and ccd_dist.describe(c) == "streamed (this process)"
    with pytest.raises(CcdError, match="not both"):
        with ccd_dist.get_client(address, 2):
            pass


def test_calibrate_product_and_provenance(client):
    a = calibrate(HEALEY)
    b = calibrate(HEALEY, reducer=DaskReducer(client))
    assert sorted(b.maps) == sorted(a.maps)
    for name in a.maps:
        assert _same(a.maps[name], b.maps[name]), name
    assert a.provenance.scheduler == "streamed (this process)"
    sched = b.provenance.scheduler
    assert client.scheduler.address in sched and "(2 workers)" in sched
    assert b.estimates.dark == a.estimates.dark
    assert b.estimates.fixed_pattern == a.estimates.fixed_pattern
    assert b.estimates.noise.A == pytest.approx(a.estimates.noise.A, rel=1e-9)


# --------------------------------------------------------------------------------------------
class _KillOnFirstBand(Tracker):
    """Kills one worker process when the first band comes back (tasks are still queued)."""

    def __init__(self, pid: int):
        super().__init__()
        self.pid, self.killed = pid, False

    def frame(self, done=None, total=None):
        super().frame(done, total)
        if not self.killed:
            self.killed = True
            os.kill(self.pid, signal.SIGKILL)


def test_worker_killed_mid_run(client, healey, monkeypatch):
    recs = [r for recs in healey.fixed_pattern_configs().values() for r in recs]
    monkeypatch.setattr(dask_bands, "BAND_BYTES", 2 * 3 * 8 * 256)    # 2-row bands: 96 tasks
    expected = pixel_moments(healey.iter_frames(recs))
    pids = client.run(os.getpid)
    victim = sorted(pids.values())[0]
    tracker = _KillOnFirstBand(victim)
    with tracking(tracker):
        got = ccd_dist.band_moments(client, recs)
    assert tracker.killed and tracker.done == tracker.total == 96
    assert _same(got.mean, expected.mean) and _same(got.var, expected.var)
    client.wait_for_workers(2, timeout=60)       # the nanny restarts the killed worker


class _CancelOnFirstBand(Tracker):
    def frame(self, done=None, total=None):
        super().frame(done, total)
        self.cancel()


def test_cancel_stops_and_cancels_the_tasks(client, healey, monkeypatch):
    monkeypatch.setattr(dask_bands, "BAND_BYTES", 2 * 3 * 8 * 256)
    recs = [r for recs in healey.fixed_pattern_configs().values() for r in recs]
    tracker = _CancelOnFirstBand()
    with tracking(tracker), pytest.raises(Cancelled) as info:
        ccd_dist.band_moments(client, recs)
    assert tracker.done == 1

    def tasks() -> int:   # the traceback in ``info`` still holds the futures: only a cancel
        return client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks))
    for _ in range(600):          # the scheduler forgets them within 30 s even on a busy machine
        if tasks() == 0:
            break
        time.sleep(0.05)
    assert tasks() == 0 and info.value is not None


# --------------------------------------------------------------------------------------------
@pytest.fixture
def damaged(tmp_path):
    """A copy of healey94 opened (headers cached), then one dark frame cut short and one ptc and
    one fixed-pattern frame with garbage in their pixel data: only the workers meet them."""
    root = tmp_path / "healey94"
    shutil.copytree(HEALEY, root)
    s = open_session(root)
    for r in s.frames:
        s.header(r)
    cut = s.dark_frames()[3].path
    with open(cut, "r+b") as f:
        f.truncate(os.path.getsize(cut) // 2)
    rng = np.random.default_rng(14)
    for rec in (s.ptc_levels()[2][1], s.fixed_pattern_configs()[3][1]):
        data = bytearray(rec.path.read_bytes())
        data[200:2000] = rng.integers(0, 256, 1800, dtype=np.uint8).tobytes()
        rec.path.write_bytes(bytes(data))
    return s


def _message(fn):
    with pytest.raises(CcdError) as info:
        fn()
    return type(info.value), str(info.value)


def test_unreadable_file_same_message(client, damaged):
    zeros = np.zeros((192, 256))
    cases = [(lambda **k: dark_reference(damaged, **k), "dark_003.tif"),
             (lambda **k: photon_transfer(damaged, **k), "L02_b.tif"),
             (lambda **k: fixed_pattern_map(damaged, zeros, **k), "C03_F01.tif")]
    for fn, name in cases:
        streamed = _message(fn)
        cluster = _message(lambda: fn(reducer=DaskReducer(client)))
        assert cluster == streamed
        assert name in cluster[1] and "\n" not in cluster[1]


def test_nonfinite_pixels_same_message(client, tmp_path):
    """Float ptc and dark frames with NaN: the streamed message, counted over the bands."""
    from ccdcore.io.frames import write_image
    from ccdcore.simulate import simulate

    root = tmp_path / "nan"
    simulate("healey94", root, seed=14, size=(64, 48), n_dark=4, levels=3, n1=2, n2=1,
             scene_levels=(0.5,), max_intensity=None)
    s = open_session(root)
    for rec in s.by_role("ptc") + s.dark_frames():
        write_image(rec.path, read_image(rec.path).astype(np.float32))
    bad = s.ptc_levels()[2][1]
    frame = read_image(bad.path)
    frame[5, 7] = frame[40, 60] = np.nan             # rows 5 and 40: two different bands
    write_image(bad.path, frame)
    s = open_session(root)
    streamed = _message(lambda: photon_transfer(s))
    assert "2 NaN or infinite pixel values" in streamed[1] and bad.relpath in streamed[1]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(dask_bands, "BAND_BYTES", 7 * 3 * 8 * 64)
        assert _message(lambda: photon_transfer(s, reducer=DaskReducer(client))) == streamed
    dark = s.dark_frames()[1]
    frame = read_image(dark.path)
    frame[0, 0] = np.inf
    write_image(dark.path, frame)
    s = dataclasses.replace(open_session(root), camera=dataclasses.replace(
        s.camera, black_level=None))
    streamed = _message(lambda: photon_transfer(s))
    assert dark.relpath in streamed[1]
    assert _message(lambda: photon_transfer(s, reducer=DaskReducer(client))) == streamed


def test_header_checks_same_message(client, healey, tmp_path):
    """A frame of another shape, and a colour frame, among the darks: checked on the client
    from the headers, with the streamed messages."""
    from ccdcore.io.frames import write_image
    from ccdcore.session import FrameRecord

    odd = FrameRecord(write_image(tmp_path / "odd.tif", np.zeros((100, 120), np.uint8)),
                      "odd.tif", "dark")
    rgb = FrameRecord(write_image(tmp_path / "rgb.tif", np.zeros((192, 256, 3), np.uint8)),
                      "rgb.tif", "dark")
    darks = list(healey.dark_frames()[:3])
    for recs in (darks + [odd], darks + [rgb]):
        streamed = _message(lambda: dark_reference([(r, read_image(r.path)) for r in recs]))
        assert _message(lambda: dark_reference(recs, reducer=DaskReducer(client))) == streamed
    configs = {1: healey.fixed_pattern_configs()[1], 2: (rgb,)}
    dark = dark_reference(healey)
    streamed = _message(lambda: fixed_pattern_map(
        {c: [(r, read_image(r.path)) for r in recs] for c, recs in configs.items()}, dark))
    assert _message(lambda: fixed_pattern_map(configs, dark, reducer=DaskReducer(client))) == streamed


def test_first_unreadable_frame_is_reported(client, damaged, monkeypatch):
    """Two bad darks: dark_001 with garbage in its first strips, dark_003 cut short.  Bands
    below the garbage read dark_001 and fail at dark_003; the error reported is still the
    streamed one, dark_001's."""
    data = bytearray(damaged.dark_frames()[1].path.read_bytes())
    data[200:2000] = bytes(1800)
    damaged.dark_frames()[1].path.write_bytes(bytes(data))
    streamed = _message(lambda: dark_reference(damaged))
    assert "dark_001.tif" in streamed[1]
    monkeypatch.setattr(dask_bands, "BAND_BYTES", 7 * 3 * 8 * 256)
    assert _message(lambda: dark_reference(damaged, reducer=DaskReducer(client))) == streamed


# --------------------------------------------------------------------------------------------
def test_cli_workers_ptc_json(capsys):
    assert main(["ptc", str(HEALEY), "--json"]) == 0
    streamed = json.loads(capsys.readouterr().out)
    assert main(["ptc", str(HEALEY), "--json", "--workers", "2"]) == 0
    cluster = json.loads(capsys.readouterr().out)
    for key in ("A", "sigma_c2", "A_err", "sigma_c2_err", "read_noise_e"):
        assert cluster[key] == pytest.approx(streamed[key], rel=1e-9), key
    for p, q in zip(streamed["points"], cluster["points"], strict=True):
        assert q["mu"] == p["mu"] and q["var"] == pytest.approx(p["var"], rel=RTOL, abs=0)


def test_cli_bad_scheduler(capsys, monkeypatch):
    monkeypatch.setattr(ccd_dist, "CONNECT_TIMEOUT", 1)
    assert main(["ptc", str(HEALEY), "--scheduler", "tcp://127.0.0.1:1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("ccdcore ptc: error: tcp://127.0.0.1:1: ")
    assert "Dask scheduler" in err
    monkeypatch.setenv(ccd_dist.SCHEDULER_ENV, "tcp://127.0.0.1:1")
    assert main(["calibrate", str(HEALEY), "-o", "unused"]) == 2
    assert capsys.readouterr().err.startswith("ccdcore calibrate: error: tcp://127.0.0.1:1: ")
    assert not Path("unused").exists()


def test_import_stays_light():
    code = ("import sys, ccdcore, ccdcore.product.make, ccdcore.distributed.client, "
            "ccdcore.cli.command; "
            "print(any(m.split('.')[0] in ('dask', 'distributed') for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.strip() == "False"
