"""The disk cache of finished results (ccdcore_app.cache.store, AppState.cached_compute) and its
use by the Photon transfer and Maps pages: round trips, reopening without computing, what makes a
miss (a changed frame, another ROI, a corrupt entry) and the size bound."""
from __future__ import annotations

import dataclasses
import io
import json
import math
import os
import pickle
import shutil
import threading
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import ccdcore_app.main  # noqa: F401  (loads the Panel extensions, as serving does)
import ccdcore_app.pages.maps.page
import ccdcore_app.pages.photon_transfer
from ccdcore_app.cache import store as cache_mod
from ccdcore_app.cache.store import (ResultCache, cache_folder, default_cache, estimates_entry,
                                     fingerprint, photon_transfer_entry)
from ccdcore_app.pages.maps.page import MapsPage
from ccdcore_app.pages.photon_transfer import PhotonTransferPage
from ccdcore_app.state import AppState
from ccdcore.io.frames import read_header, read_image, write_image
from ccdcore.noise import PhotonTransfer, photon_transfer
from ccdcore.product.make import Estimates, estimate_all
from ccdcore.session import Session, open_session
from _coro import run


# ------------------------------------------------------------------------------ helpers ------
def assert_same(a: Any, b: Any, where: str = "result") -> None:
    """``a`` and ``b`` hold the same values: dataclass fields, dict items, sequence items and
    arrays compared one by one (NaN equal to NaN)."""
    assert type(a) is type(b), f"{where}: {type(a).__name__} != {type(b).__name__}"
    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            assert_same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            assert_same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), where
    else:
        assert a == b, where


class Failing:
    """Wraps an estimator: counts its calls and fails from call ``fail_from`` on."""

    def __init__(self, func: Any, fail_from: int = 1):
        self.func, self.calls, self.fail_from = func, 0, fail_from

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        self.calls += 1
        if self.calls > self.fail_from:
            raise AssertionError(f"{self.func.__name__} computed again")
        return self.func(*args, **kwargs)


@pytest.fixture
def cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """An empty cache folder named by CCDCORE_CACHE (the app's default cache)."""
    folder = tmp_path / "cache"
    monkeypatch.setenv(cache_mod.CACHE_ENV, str(folder))
    monkeypatch.delenv(cache_mod.CACHE_SIZE_ENV, raising=False)
    return folder


@pytest.fixture
def demo(tmp_path: Path, assets: Path) -> Path:
    """A copy of the healey94 demo (its files may be rewritten)."""
    return Path(shutil.copytree(assets / "healey94", tmp_path / "healey94"))


@pytest.fixture(scope="module")
def demo_results(assets: Path) -> tuple[PhotonTransfer, Estimates]:
    session = open_session(assets / "healey94")
    return photon_transfer(session), estimate_all(session, emva1288=False)


def _state(path: Path) -> AppState:
    state = AppState(allowed_roots=[path.parent.resolve()])
    assert state.load(path), state.error
    return state


def _npz(entry: Any) -> bytes:
    """An .npz holding ``entry`` as the JSON description of a cache entry."""
    buf = io.BytesIO()
    np.savez(buf, __entry__=np.frombuffer(json.dumps(entry).encode(), dtype=np.uint8))
    return buf.getvalue()


def _touch_frame(session_root: Path, relpath: str) -> None:
    """Rewrite a frame with one pixel changed and a later modification time."""
    path = session_root / relpath
    pixels, header = read_image(path), read_header(path)
    pixels.flat[0] = pixels.flat[0] + 1
    stat = path.stat()
    write_image(path, pixels, exposure=header.exposure, bits=header.bits)
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10_000_000_000))


# ------------------------------------------------------------------------------ the folder ---
def test_folder_from_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("CCDCORE_CACHE", str(tmp_path / "c"))
    monkeypatch.setenv("CCDCORE_CACHE_MAX_BYTES", "3M")
    cache = default_cache()
    assert cache is not None and cache.folder == tmp_path / "c"
    assert cache.max_bytes == 3 * 1024 ** 2
    monkeypatch.setenv("CCDCORE_CACHE_MAX_BYTES", "1.5GiB")
    assert default_cache().max_bytes == int(1.5 * 1024 ** 3)
    monkeypatch.setenv("CCDCORE_CACHE_MAX_BYTES", "lots")
    assert default_cache().max_bytes == cache_mod.DEFAULT_MAX_BYTES
    monkeypatch.setenv("CCDCORE_CACHE", "off")
    assert cache_folder() is None and default_cache() is None
    assert AppState().cache is None
    # without CCDCORE_CACHE: XDG_CACHE_HOME/ccdcore, else ~/.cache/ccdcore
    monkeypatch.delenv("CCDCORE_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_folder() == tmp_path / "xdg" / "ccdcore"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert cache_folder() == Path.home() / ".cache" / "ccdcore"


# ------------------------------------------------------------------------------ round trip ---
def test_round_trip_of_a_photon_transfer_and_estimates(cache_dir, demo_results):
    pt, est = demo_results
    cache = ResultCache(cache_dir)
    k_pt = cache.key("0" * 64, *photon_transfer_entry(None))
    k_est = cache.key("0" * 64, *estimates_entry(None, emva1288=False))
    assert k_pt != k_est
    assert cache.get(k_pt) is None
    assert cache.put(k_pt, pt) and cache.put(k_est, est)
    back_pt, back_est = cache.get(k_pt), cache.get(k_est)
    assert back_pt is not pt and back_est is not est
    assert_same(back_pt, pt)
    assert_same(back_est, est)
    assert est.fixed_pattern is not None and est.dark is not None   # arrays were compared
    assert fingerprint(back_pt) == fingerprint(pt) == fingerprint(est.noise)


def test_key_holds_the_version_the_name_and_the_parameters(monkeypatch):
    key = ResultCache.key("a" * 64, "photon_transfer", {"roi": [1, 2, 3, 4]})
    assert key == ResultCache.key("a" * 64, "photon_transfer", {"roi": (1, 2, 3, 4)})
    assert key != ResultCache.key("b" * 64, "photon_transfer", {"roi": [1, 2, 3, 4]})
    assert key != ResultCache.key("a" * 64, "ptc_points", {"roi": [1, 2, 3, 4]})
    assert key != ResultCache.key("a" * 64, "photon_transfer", {"roi": [1, 2, 3, 5]})
    monkeypatch.setattr(cache_mod.ccdcore, "__version__", "999")
    assert key != ResultCache.key("a" * 64, "photon_transfer", {"roi": [1, 2, 3, 4]})
    with pytest.raises(TypeError):
        ResultCache.key("a" * 64, "x", {"f": object()})


# ------------------------------------------------------------------------------ reopening ----
def test_another_state_shows_both_pages_without_computing(cache_dir, demo, monkeypatch):
    first = _state(demo)
    maps = MapsPage(first, auto_compute=False)
    run(maps.compute())
    est = first.results.estimates
    assert est is not None and first.status.startswith("Computed")

    for module, name in ((ccdcore_app.pages.maps.page, "estimate_all"),
                         (ccdcore_app.pages.photon_transfer, "photon_transfer"),
                         (ccdcore_app.pages.photon_transfer, "ptc_points")):
        monkeypatch.setattr(module, name, Failing(getattr(module, name), fail_from=0))
    # the stat index gives the content hash: no frame is read to recognise the session
    monkeypatch.setattr(Session, "content_hash", Failing(Session.content_hash, fail_from=0))
    monkeypatch.setattr(cache_mod, "content_hash", Failing(cache_mod.content_hash, fail_from=0))

    second = _state(demo)          # another browser session (or the server restarted)
    ptc = PhotonTransferPage(second, auto=False)
    run(ptc.refresh())             # photon_transfer's full frame, learnt from estimate_all
    assert "from the cache" in second.status, second.status
    assert second.error == "" and ptc.result is not None
    assert_same(ptc.result, est.noise)
    maps2 = MapsPage(second, auto_compute=False)
    run(maps2.compute())           # given the Photon transfer page's fit: the same estimates
    assert "from the cache" in second.status, second.status
    assert_same(second.results.estimates, est)

    third = _state(demo)           # the Maps page first, with no noise model yet
    run(MapsPage(third, auto_compute=False).compute())
    assert "from the cache" in third.status and third.error == ""
    assert_same(third.results.estimates, est)


def test_a_changed_frame_misses(cache_dir, demo, monkeypatch):
    counted = Failing(photon_transfer, fail_from=2)
    monkeypatch.setattr(ccdcore_app.pages.photon_transfer, "photon_transfer", counted)
    run(PhotonTransferPage(_state(demo), auto=False).refresh())
    run(PhotonTransferPage(_state(demo), auto=False).refresh())
    assert counted.calls == 1
    session = open_session(demo)
    _touch_frame(demo, session.by_role("ptc")[0].relpath)
    state = _state(demo)
    page = PhotonTransferPage(state, auto=False)
    run(page.refresh())
    assert counted.calls == 2 and state.status == "Computed photon transfer."
    assert page.result is not None
    index = ResultCache(cache_dir)._read_index()
    assert len(index) == 2 and len(set(e["hash"] for e in index.values())) == 2


def test_another_roi_misses_and_its_own_result_is_kept(cache_dir, demo, monkeypatch):
    counted = Failing(photon_transfer, fail_from=3)
    monkeypatch.setattr(ccdcore_app.pages.photon_transfer, "photon_transfer", counted)
    state = _state(demo)
    page = PhotonTransferPage(state, auto=False)
    run(page.refresh())
    page.x_input.value, page.y_input.value, page.w_input.value, page.h_input.value = 4, 4, 20, 20
    assert run(page.apply_roi())
    assert counted.calls == 2 and page.result.roi == (4, 4, 20, 20)
    fit = page.result
    page2 = PhotonTransferPage(_state(demo), auto=False)
    run(page2.refresh())
    page2.x_input.value, page2.y_input.value, page2.w_input.value, page2.h_input.value = \
        4, 4, 20, 20
    assert run(page2.apply_roi())
    assert counted.calls == 2
    assert_same(page2.result, fit)


def test_a_corrupt_entry_is_computed_again(cache_dir, demo, monkeypatch):
    counted = Failing(photon_transfer, fail_from=2)
    monkeypatch.setattr(ccdcore_app.pages.photon_transfer, "photon_transfer", counted)
    run(PhotonTransferPage(_state(demo), auto=False).refresh())
    (entry,) = ResultCache(cache_dir).entries()
    data = entry.read_bytes()
    entry.write_bytes(data[: len(data) // 2])           # a partial write
    state = _state(demo)
    page = PhotonTransferPage(state, auto=False)
    run(page.refresh())
    assert counted.calls == 2 and state.error == "" and page.result is not None
    assert ResultCache(cache_dir).get(entry.stem) is not None      # written again
    other = entry.with_name("f" * 64 + ".npz")     # a whole entry under another key's name
    other.write_bytes(entry.read_bytes())
    assert ResultCache(cache_dir).get(other.stem) is None and not other.exists()
    for bad in (b"not an npz", _npz({"format": -1, "key": entry.stem, "value": 1}),
                _npz([1, 2]), pickle.dumps({"format": cache_mod.FORMAT})):
        entry.write_bytes(bad)
        assert ResultCache(cache_dir).get(entry.stem) is None
        assert not entry.exists()


def test_a_link_gives_its_target_and_dies_with_it(cache_dir):
    cache = ResultCache(cache_dir)
    target, link = "1" * 64, "2" * 64
    assert cache.link(link, target) and cache.get(link) is None
    cache.put(target, np.arange(3))
    np.testing.assert_array_equal(cache.get(link), np.arange(3))
    (cache_dir / "results" / f"{target}.npz").unlink()
    assert cache.get(link) is None


def test_eviction_keeps_the_bound_and_the_recently_used(cache_dir):
    rng = np.random.default_rng(5)
    arrays = [rng.normal(size=1000) for _ in range(4)]      # 8 kB each
    cache = ResultCache(cache_dir, max_bytes=20_000)        # room for two
    keys = [f"{i:064x}" for i in range(4)]
    cache.put(keys[0], arrays[0])
    cache.put(keys[1], arrays[1])
    past = 1_600_000_000_000_000_000
    for i, key in enumerate(keys[:2]):
        os.utime(cache_dir / "results" / f"{key}.npz", ns=(past + i, past + i))
    np.testing.assert_array_equal(cache.get(keys[0]), arrays[0])   # keys[0] used last
    cache.put(keys[2], arrays[2])
    assert cache.get(keys[1]) is None
    np.testing.assert_array_equal(cache.get(keys[0]), arrays[0])
    np.testing.assert_array_equal(cache.get(keys[2]), arrays[2])
    assert cache.size() <= cache.max_bytes
    small = ResultCache(cache_dir / "small", max_bytes=100)      # an entry above the bound
    assert small.put(keys[3], arrays[3]) and small.entries() == [] and small.size() == 0
    cache.clear()
    assert cache.entries() == [] and not cache.index_path.exists()


def test_an_unpicklable_result_is_not_cached_and_no_error_shows(cache_dir, demo):
    state = _state(demo)
    value = run(state.cached_compute("lambda", {}, lambda: (lambda: 1), label="a function"))
    assert callable(value) and state.error == ""
    assert ResultCache(cache_dir).entries() == []
    assert not list((cache_dir / "results").glob("*.tmp"))


def test_an_unreadable_frame_computes_without_the_cache(cache_dir, demo):
    state = _state(demo)
    session = state.session
    (demo / session.frames[0].relpath).unlink()
    value = run(state.cached_compute("count", {}, lambda: 7, label="seven"))
    assert value == 7 and state.status == "Computed seven."
    assert ResultCache(cache_dir).entries() == []


def test_a_new_session_is_computed_while_it_is_hashed(cache_dir, demo, monkeypatch):
    """The content hash (every byte read) does not hold the computation back: the estimator
    runs while the hash is made; the result is stored under the hash afterwards."""
    started = threading.Event()
    seen: list[bool] = []
    real_hash = cache_mod.content_hash

    def slow_hash(session: Session) -> str:
        seen.append(started.wait(timeout=20))   # the estimator starts meanwhile
        return real_hash(session)

    def estimator() -> int:
        started.set()
        return 42

    monkeypatch.setattr(cache_mod, "content_hash", slow_hash)
    state = _state(demo)
    assert run(state.cached_compute("answer", {}, estimator, label="the answer")) == 42
    assert seen == [True] and state.status == "Computed the answer."
    second = _state(demo)
    assert run(second.cached_compute("answer", {}, lambda: pytest.fail("computed again"),
                                      label="the answer")) == 42
    assert "from the cache" in second.status and seen == [True]


def test_cancelled_and_failed_computations_are_not_cached(cache_dir, demo):
    from ccdcore.errors import CcdError
    from ccdcore.progress import Cancelled

    def cancelled() -> int:
        raise Cancelled()

    def failing() -> int:
        raise CcdError("frames", "too few")

    for known in (False, True):   # a new session, then one the stat index knows
        state = _state(demo)
        if known:   # (the hashing a cancelled computation leaves running may not be done)
            ResultCache(cache_dir).session_hash(state.session)
        assert (ResultCache(cache_dir).known_hash(state.session) is not None) == known
        assert run(state.cached_compute("x", {}, cancelled, label="x")) is None
        assert state.status == "Cancelled x." and state.error == ""
        assert run(state.cached_compute("x", {}, failing, label="x")) is None
        assert "too few" in state.error
        assert ResultCache(cache_dir).entries() == []


# ------------------------------------------------------------------- entries run no code ---
class _Payload:
    """Unpickled, it would create ``marker``."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self) -> tuple:
        return (Path.touch, (self.marker,))


def test_a_planted_pickle_entry_is_never_executed(cache_dir, demo, tmp_path):
    marker = tmp_path / "pwned"
    state = _state(demo)
    name, params = photon_transfer_entry(None)
    key = run(state.cache_key(name, params))
    results = cache_dir / "results"
    results.mkdir(parents=True, mode=0o700, exist_ok=True)
    entry = {"format": 1, "key": key, "value": _Payload(marker)}
    (results / f"{key}.pkl").write_bytes(pickle.dumps(entry))        # the old format's name
    (results / f"{key}.npz").write_bytes(pickle.dumps(entry))        # and the new one's
    assert ResultCache(cache_dir).get(key) is None
    page = PhotonTransferPage(_state(demo), auto=False)
    run(page.refresh())                                               # computed, not loaded
    assert page.result is not None and not marker.exists()
    assert not (results / f"{key}.pkl").exists()                     # old entries removed
    # an .npz whose array holds pickled objects is refused by np.load(allow_pickle=False)
    buf = io.BytesIO()
    np.savez(buf, __entry__=np.frombuffer(json.dumps(
        {"format": cache_mod.FORMAT, "key": key,
         "value": {"__ndarray__": "a0", "scalar": False}}).encode(), dtype=np.uint8),
             a0=np.array([_Payload(marker)], dtype=object))
    (results / f"{key}.npz").write_bytes(buf.getvalue())
    assert ResultCache(cache_dir).get(key) is None and not marker.exists()


@pytest.mark.parametrize("name", ["os:system", "subprocess:Popen", "builtins:eval",
                                  "ccdcore.io.frames:read_image", "ccdcore.io.frames:os.system",
                                  "ccdcore.noise:PhotonTransfer.__init__.__globals__",
                                  "ccdcore_app.cache.store:Shared", "pathlib:Path"])
def test_an_entry_naming_another_class_is_refused(cache_dir, name, tmp_path):
    marker = tmp_path / "pwned"
    key = "3" * 64
    cache = ResultCache(cache_dir)
    assert cache.put(key, np.arange(2))
    values = [{"__dataclass__": name, "fields": fields} for fields in
              ({"command": f"touch {marker}"}, {"args": ["touch", str(marker)]},
               {"source": f"open({str(marker)!r}, 'w')"}, {"path": str(marker)})]
    values += [{"__enum__": name, "value": f"touch {marker}"},
               {"__namedtuple__": name, "items": [f"touch {marker}"]},
               {"__namedtuple__": name, "items": [["touch", str(marker)]]}]
    for value in values:
        (cache_dir / "results" / f"{key}.npz").write_bytes(
            _npz({"format": cache_mod.FORMAT, "key": key, "value": value}))
        assert cache.get(key) is None and not marker.exists()
        with pytest.raises(ValueError, match="ccdcore|class name"):
            cache_mod.decode(value, {})
        assert not marker.exists()


# --------------------------------------------------------------------------- the folder ---
def test_a_folder_others_may_write_is_refused(cache_dir, caplog):
    key = "4" * 64
    cache = ResultCache(cache_dir)
    assert cache.put(key, np.arange(3))
    assert (cache_dir / "results").stat().st_mode & 0o777 == 0o700
    os.chmod(cache_dir, 0o777)
    with caplog.at_level("WARNING", logger="ccdcore_app.cache.store"):
        assert cache.get(key) is None
        assert not cache.put("5" * 64, np.arange(3))
        assert cache.get(key) is None
    warnings = [r for r in caplog.records if "not using the result cache" in r.getMessage()]
    assert len(warnings) == 1 and "writable by its group or by others" in warnings[0].getMessage()
    assert not (cache_dir / "results" / f"{'5' * 64}.npz").exists()
    os.chmod(cache_dir, 0o700)
    os.chmod(cache_dir / "results", 0o770)                            # a sub-folder too
    assert ResultCache(cache_dir).get(key) is None
    os.chmod(cache_dir / "results", 0o700)
    np.testing.assert_array_equal(ResultCache(cache_dir).get(key), np.arange(3))


def test_a_folder_owned_by_another_user_is_refused(cache_dir, monkeypatch, demo):
    key = "6" * 64
    assert ResultCache(cache_dir).put(key, np.arange(3))
    real = os.getuid()
    monkeypatch.setattr(os, "getuid", lambda: real + 1)              # the folder is not ours
    cache = ResultCache(cache_dir)
    assert cache.get(key) is None and not cache.put("7" * 64, np.arange(3))
    assert "owned by uid" in (cache._refused or "")
    state = _state(demo)                                               # the app goes on
    assert run(state.cached_compute("seven", {}, lambda: 7, label="seven")) == 7
    assert state.error == ""
    monkeypatch.setattr(os, "getuid", lambda: real)
    np.testing.assert_array_equal(ResultCache(cache_dir).get(key), np.arange(3))


# ------------------------------------------------------------------------ content keys ---
def test_a_frame_rewritten_with_its_mtime_restored_misses(cache_dir, demo):
    calls = []

    def count() -> int:
        calls.append(1)
        return len(calls)

    assert run(_state(demo).cached_compute("count", {}, count, label="count")) == 1
    assert run(_state(demo).cached_compute("count", {}, count, label="count")) == 1
    session = open_session(demo)
    path = session.by_role("ptc")[0].path
    before = path.stat()
    _touch_frame(demo, session.by_role("ptc")[0].relpath)           # other bytes ...
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))       # ... the old mtime
    after = path.stat()
    assert (after.st_size, after.st_mtime_ns) == (before.st_size, before.st_mtime_ns)
    state = _state(demo)
    assert run(state.cached_compute("count", {}, count, label="count")) == 2
    assert state.status == "Computed count."
    # the same bytes elsewhere (another folder, other mtimes) give the same key
    copy = Path(shutil.copytree(demo, demo.parent / "copy"))
    assert ResultCache(cache_dir).session_hash(open_session(copy)) == \
        ResultCache(cache_dir).session_hash(open_session(demo))


def test_content_hash_reads_each_unchanged_file_once(demo, monkeypatch):
    session = open_session(demo)
    first = cache_mod.content_hash(session)
    monkeypatch.setattr(cache_mod, "open", lambda *a, **k: pytest.fail("read again"),
                        raising=False)
    assert cache_mod.content_hash(session) == first


# ------------------------------------------------------------ round trips of each type ---
def test_round_trip_of_every_cached_result_type(cache_dir, assets, demo_results):
    from ccdcore.common import Roi
    from ccdcore.noise import ptc_points
    from ccdcore_app.pages.response_hdr import compute_hdr, compute_responses

    cache = ResultCache(cache_dir)
    pt, est = demo_results
    tsin = open_session(assets / "tsin01")
    responses = compute_responses(tsin)
    values = {
        "photon_transfer": pt, "estimate_all": est,
        "ptc_points": ptc_points(open_session(assets / "healey94")),
        "responses": responses,
        "hdr": compute_hdr(tsin, next(iter(responses.values()))),
        "plain": {"roi": Roi(1, 2, 3, 4), (1, "a"): [None, True, 2, 2.5, float("nan"), "s"],
                  "scalar": np.float32(1.5), "int": np.int64(3), "path": Path("a/b"),
                  "empty": (), "nested": ((np.zeros((2, 0)),),)},
    }
    for i, (name, value) in enumerate(values.items()):
        key = f"{i + 10:064x}"
        assert cache.put(key, value), name
        assert_same(cache.get(key), value, name)


# ------------------------------------------------------------------------- bounded entries ---
def _bomb(key: str, arrays: dict[str, np.ndarray], compressed: bool) -> bytes:
    buf = io.BytesIO()
    entry = {"format": cache_mod.FORMAT, "key": key,
             "value": {"__ndarray__": "big"} if "big" in arrays else None}
    save = np.savez_compressed if compressed else np.savez
    save(buf, __entry__=np.frombuffer(json.dumps(entry).encode(), dtype=np.uint8), **arrays)
    return buf.getvalue()


def test_an_entry_that_inflates_is_refused_before_it_is_read(cache_dir, monkeypatch):
    """A small entry whose member inflates (a deflated array of zeros: 64 MB from about 65 kB)
    or whose array header declares more bytes than its member holds is a miss, deleted, and
    nothing of it is loaded; the cache's own entries still load."""
    key = "4" * 64
    cache = ResultCache(cache_dir)
    assert cache.put(key, np.arange(5.0))
    assert cache_mod.entry_size_problem(cache_dir / "results" / f"{key}.npz") is None
    np.testing.assert_array_equal(cache.get(key), np.arange(5.0))
    loads = []
    monkeypatch.setattr(cache_mod.np, "load", lambda *a, **k: loads.append(a) or 1 / 0)
    path = cache_dir / "results" / f"{key}.npz"
    path.write_bytes(_bomb(key, {"big": np.zeros(2 ** 23)}, compressed=True))
    assert path.stat().st_size < 2 ** 20
    assert "compressed" in cache_mod.entry_size_problem(path)
    assert cache.get(key) is None and not path.exists() and not loads
    # an array header declaring 99 999 999 999 elements in a member of 160 bytes (the header's padding
    # shortened by as much, so the member's size is unchanged)
    raw = io.BytesIO()
    np.save(raw, np.zeros(4))
    raw = raw.getvalue()
    at = raw.index(b"(4,), }")
    end = raw.index(b"\n", at)
    assert raw[end - 11:end] == b" " * 11
    hacked = raw[:at] + b"(99999999999,), }" + raw[at + 7:end - 10] + raw[end:]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        zf.writestr("big.npy", hacked)
    assert "declares 799999999992 bytes" in cache_mod.entry_size_problem(path)
    assert cache.get(key) is None and not loads


def test_a_deeply_nested_index_is_ignored(cache_dir, caplog):
    """hashes.json nested 100 000 deep (RecursionError in json) is ignored with a warning."""
    cache = ResultCache(cache_dir)
    assert cache.usable(create=True)
    cache.index_path.write_text("[" * 100_000 + "]" * 100_000)
    assert cache._read_index() == {}
    assert any("ignoring the cache index" in r.message for r in caplog.records)
