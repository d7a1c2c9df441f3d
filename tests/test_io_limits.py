"""The file boundary of ccdcore.io.frames: pixel limit, region reads, failed writes, quiet bad
input."""
from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

from ccdcore.io import frames as ccd_io
from ccdcore.errors import CcdError, ImageReadError, ImageWriteError
from ccdcore.io.frames import (MAX_PIXELS, atomic_write_text, pixel_limit, read_frame, read_header,
                        read_image, read_region, write_image, write_map)
from imagefiles import bomb_tiff

RNG = np.random.default_rng(20261)
ROOT = Path(__file__).resolve().parents[1]


def _frame(shape=(40, 56), dtype=np.uint16):
    return RNG.integers(0, 4000, size=shape).astype(dtype)




# --------------------------------------------------------------------------------------------
# the pixel limit
# --------------------------------------------------------------------------------------------
def test_default_limit_admits_real_sensors_and_refuses_bombs(monkeypatch):
    monkeypatch.delenv("CCDCORE_MAX_PIXELS", raising=False)
    assert pixel_limit() == MAX_PIXELS
    assert 14204 * 10652 * 4 <= MAX_PIXELS        # 151 MP medium format, even as RGBA
    assert 16384 * 16384 * 4 <= MAX_PIXELS        # 16k x 16k scientific frame
    assert 40000 * 40000 > MAX_PIXELS             # the decompression bomb


@pytest.mark.parametrize("ext", [".tif", ".exr", ".png", ".fits"])
def test_image_over_the_limit_is_refused_before_decoding(tmp_path, monkeypatch, ext):
    a = _frame((64, 64)).astype(np.float32 if ext == ".exr" else np.uint16)
    path = write_image(tmp_path / f"big{ext}", a)

    def no_decoding(*args, **kwargs):
        raise AssertionError("pixels were decoded")

    monkeypatch.setattr(ccd_io, "_read_pixels", no_decoding)
    with pytest.raises(ImageReadError) as info:
        read_image(path, max_pixels=1000)
    message = str(info.value)
    assert message.startswith(str(path)) and "64x64" in message
    assert "max_pixels=4096" in message and "CCDCORE_MAX_PIXELS=4096" in message
    assert "\n" not in message
    assert read_header(path).shape == (64, 64)    # the header still reads
    monkeypatch.undo()
    np.testing.assert_array_equal(read_image(path, max_pixels=64 * 64), a)   # the limit itself


def test_channels_count_towards_the_limit(tmp_path):
    path = write_image(tmp_path / "rgb.tif", _frame((20, 10, 3)))
    with pytest.raises(ImageReadError, match="3 channel"):
        read_frame(path, max_pixels=20 * 10 * 3 - 1)
    assert read_frame(path, max_pixels=20 * 10 * 3)[0].shape == (20, 10, 3)


def test_environment_variable_sets_the_limit(tmp_path, monkeypatch):
    path = write_image(tmp_path / "f.tif", _frame((32, 32)))
    monkeypatch.setenv("CCDCORE_MAX_PIXELS", "1000")
    assert pixel_limit() == 1000
    with pytest.raises(ImageReadError, match="over the limit of 1,000"):
        read_image(path)
    assert read_image(path, max_pixels=10**6).shape == (32, 32)   # the argument wins
    monkeypatch.setenv("CCDCORE_MAX_PIXELS", "1e6")
    assert read_image(path).shape == (32, 32)


@pytest.mark.parametrize("value", ["lots", "0", "-5", "2.5", ""])
def test_bad_environment_values_are_named(tmp_path, monkeypatch, value):
    path = write_image(tmp_path / "f.tif", _frame((8, 8)))
    monkeypatch.setenv("CCDCORE_MAX_PIXELS", value)
    if value == "":  # unset in effect
        assert read_image(path).shape == (8, 8)
        return
    with pytest.raises(CcdError) as info:
        read_image(path)
    assert str(info.value).startswith("CCDCORE_MAX_PIXELS:") and repr(value) in str(info.value)


@pytest.mark.parametrize("value", [0, -1, 2.5, True, "many"])
def test_bad_max_pixels_arguments_are_named(tmp_path, value):
    path = write_image(tmp_path / "f.tif", _frame((8, 8)))
    with pytest.raises(CcdError, match="^max_pixels:"):
        read_image(path, max_pixels=value)


def test_decompression_bomb_lists_but_does_not_load(tmp_path, monkeypatch):
    monkeypatch.delenv("CCDCORE_MAX_PIXELS", raising=False)
    bomb = bomb_tiff(tmp_path / "bomb.tif", 40000, 40000)
    assert bomb.stat().st_size < 2_000_000
    header = read_header(bomb)                      # a session can still list it
    assert (header.width, header.height, header.channels) == (40000, 40000, 1)
    with pytest.raises(ImageReadError) as info:
        read_frame(bomb)
    assert str(bomb) in str(info.value) and "40000x40000" in str(info.value)
    assert "CCDCORE_MAX_PIXELS" in str(info.value)
    # a small part of it can be read: only the strips holding it are decoded
    corner = read_region(bomb, 39950, 39900, 50, 100)
    assert corner.shape == (100, 50) and corner.dtype == np.uint8 and not corner.any()
    with pytest.raises(ImageReadError, match="rows holding this region"):
        read_region(bomb, 0, 0, 10, 10, max_pixels=100_000)   # one 256-row strip is 10 M values


def test_huge_fits_header_lists_but_does_not_load(tmp_path, monkeypatch):
    from astropy.io import fits

    monkeypatch.delenv("CCDCORE_MAX_PIXELS", raising=False)
    header = fits.Header([("SIMPLE", True), ("BITPIX", 16), ("NAXIS", 2), ("NAXIS1", 40000),
                          ("NAXIS2", 40000), ("BZERO", 32768), ("BSCALE", 1)])
    path = tmp_path / "huge.fits"
    path.write_bytes(header.tostring().encode("ascii") + bytes(2880))
    assert read_header(path).shape == (40000, 40000)
    with pytest.raises(ImageReadError, match="40000x40000"):
        read_image(path)


# --------------------------------------------------------------------------------------------
# read_region
# --------------------------------------------------------------------------------------------
def _tiled_tiff(path: Path, a: np.ndarray) -> Path:
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], "uint16")
    spec.tile_width = spec.tile_height = 16
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(a) and out.close(), out.geterror()
    return path


BOXES = [(0, 0, 70, 50), (3, 5, 10, 7), (69, 49, 1, 1), (20, 0, 1, 50), (15, 15, 17, 18),
         (0, 33, 70, 17)]


@pytest.mark.parametrize("kind", ["tif", "tif-tiled", "exr", "fits", "png", "pgm"])
@pytest.mark.parametrize("channels", [1, 3])
def test_read_region_equals_the_crop_of_the_full_read(tmp_path, kind, channels):
    a = _frame((50, 70, channels))
    if kind == "tif-tiled":
        path = _tiled_tiff(tmp_path / "tiled.tif", a)
    else:
        ext = {"pgm": ".pgm" if channels == 1 else ".ppm"}.get(kind, f".{kind}")
        path = write_image(tmp_path / f"r{ext}", a.astype(np.float32) if kind == "exr" else a)
    full = read_image(path)
    for x, y, w, h in BOXES:
        region = read_region(path, x, y, w, h)
        assert region.dtype == full.dtype
        np.testing.assert_array_equal(region, full[y:y + h, x:x + w], err_msg=f"{kind} {x},{y}")


@pytest.mark.parametrize("box", [(-1, 0, 2, 2), (0, 0, 71, 2), (0, 49, 1, 2), (0, 0, 0, 1),
                                 (1.5, 0, 1, 1), ("a", 0, 1, 1)])
def test_read_region_outside_the_image_is_refused(tmp_path, box):
    path = write_image(tmp_path / "r.tif", _frame((50, 70)))
    with pytest.raises(ImageReadError) as info:
        read_region(path, *box)
    assert str(info.value).startswith(str(path)) and "70x50" in str(info.value)


def test_read_region_of_a_truncated_file_names_it(tmp_path):
    good = write_image(tmp_path / "good.tif", _frame((64, 64)))
    cut = tmp_path / "cut.tif"
    cut.write_bytes(good.read_bytes()[:3000])      # the header is at the end: unreadable
    bad = tmp_path / "bad.fits"
    bad.write_bytes(write_image(tmp_path / "g.fits", _frame((64, 64))).read_bytes()[:4000])
    for path in (cut, bad):
        with pytest.raises(ImageReadError) as info:
            read_region(path, 0, 60, 4, 4)
        assert str(path) in str(info.value)


# --------------------------------------------------------------------------------------------
# failed writes keep the previous file
# --------------------------------------------------------------------------------------------
def _listing(folder: Path) -> list[str]:
    return sorted(os.listdir(folder))


def _assert_kept(target: Path, old: bytes, listing: list[str], err: Exception):
    assert target.read_bytes() == old
    assert _listing(target.parent) == listing, "a temporary file was left behind"
    message = str(err)
    assert message.startswith(f"{target}: ") and ".tmp" not in message and "\n" not in message


class _FailingOutput:
    """An OpenImageIO ImageOutput whose ``step`` fails the way OpenImageIO reports failures."""

    def __init__(self, real, step: str, returns: bool, calls: list[str]):
        self.real, self.step, self.returns, self.calls = real, step, returns, calls
        self.pending = ""

    def _result(self, step: str, ok: bool) -> bool:
        self.calls.append(step)
        if step != self.step:
            return ok
        self.pending = "No space left on device"
        return self.returns

    def open(self, *args):
        return self._result("open", self.real.open(*args))

    def write_image(self, *args):
        return self._result("write_image", self.real.write_image(*args))

    def close(self):
        return self._result("close", self.real.close())

    def geterror(self):
        message, self.pending = self.pending or self.real.geterror(), ""
        return message


@pytest.mark.parametrize("step,returns", [("open", False), ("write_image", False),
                                          ("close", False), ("close", True),
                                          ("write_image", True)])
@pytest.mark.parametrize("ext", [".tif", ".exr", ".png"])
def test_failing_openimageio_call_keeps_the_old_file(tmp_path, monkeypatch, step, returns, ext):
    import OpenImageIO as oiio

    a = _frame((16, 16)).astype(np.float32 if ext == ".exr" else np.uint16)
    target = write_image(tmp_path / f"frame{ext}", a)
    old, listing, calls = target.read_bytes(), _listing(tmp_path), []
    real = oiio.ImageOutput

    class Factory:
        @staticmethod
        def create(name):
            return _FailingOutput(real.create(name), step, returns, calls)

    monkeypatch.setattr(oiio, "ImageOutput", Factory)
    with pytest.raises(ImageWriteError) as info:
        write_image(target, a + 1, exposure=0.01)
    _assert_kept(target, old, listing, info.value)
    assert "No space left on device" in str(info.value)
    if step == "open":
        assert "write_image" not in calls      # OpenImageIO crashes writing to a file not open
    assert calls[-1] == "close"                # the writer is always closed


SYSTEM_FAILURES = ([(writer, call) for writer in ("tif", "fits", "map-exr", "text")
                    for call in ("replace", "fsync")]
                   + [("fits", "write"), ("text", "write")])


def _enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


class _FailingWriteFile:
    """A binary file whose ``write`` fails like a full disk."""

    def __init__(self, f):
        self.f = f

    def write(self, data):
        _enospc()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


def _fits_cut_short(self, name, **kwargs):
    Path(name).write_bytes(b"SIMPLE  =                    T")
    _enospc()


@pytest.mark.parametrize("writer,call", SYSTEM_FAILURES)
def test_failing_system_call_keeps_the_old_file(tmp_path, monkeypatch, writer, call):
    from astropy.io import fits

    a = _frame((16, 16))
    write = {"tif": lambda p, v: write_image(p, a + v),
             "fits": lambda p, v: write_image(p, a + v),
             "map-exr": lambda p, v: write_map(p, a.astype(np.float32) + v),
             "text": lambda p, v: atomic_write_text(p, f"value {v}\n")}[writer]
    target = tmp_path / {"tif": "out.tif", "fits": "out.fits", "map-exr": "out.exr",
                         "text": "out.json"}[writer]
    write(target, 0)
    old, listing = target.read_bytes(), _listing(tmp_path)
    if call != "write":
        monkeypatch.setattr(os, call, _enospc)
    elif writer == "fits":
        monkeypatch.setattr(fits.PrimaryHDU, "writeto", _fits_cut_short)
    else:
        monkeypatch.setattr(ccd_io, "open", lambda path, mode: _FailingWriteFile(open(path, mode)),
                            raising=False)
    with pytest.raises(ImageWriteError) as info:
        write(target, 1)
    monkeypatch.undo()
    _assert_kept(target, old, listing, info.value)
    assert "No space left on device" in str(info.value)


class _StatVfs:
    """A file system with ``free_blocks`` free, none of them reserved for root."""

    def __init__(self, free_blocks):
        self.f_bavail = self.f_bfree = free_blocks
        self.f_frsize = 4096


def test_root_may_write_into_the_blocks_reserved_for_it(tmp_path, monkeypatch):
    """Blocks free only to root (f_bavail = 0, f_bfree > 0) do not make root's write fail."""
    class Reserved(_StatVfs):
        def __init__(self):
            super().__init__(10**6)
            self.f_bavail = 0

    monkeypatch.setattr(os, "statvfs", lambda folder: Reserved())
    monkeypatch.setattr(os, "geteuid", lambda: 0)
    target = write_image(tmp_path / "frame.tif", _frame((8, 8)))
    assert target.is_file()
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    with pytest.raises(ImageWriteError, match="disk is full"):
        write_image(tmp_path / "other.tif", _frame((8, 8)))


def test_a_full_disk_is_refused_before_writing(tmp_path, monkeypatch):
    target = write_image(tmp_path / "frame.tif", _frame((8, 8)))
    old, listing = target.read_bytes(), _listing(tmp_path)
    monkeypatch.setattr(os, "statvfs", lambda folder: _StatVfs(0))
    for write in (lambda: write_image(target, _frame((8, 8))),
                  lambda: atomic_write_text(target, "x")):
        with pytest.raises(ImageWriteError, match="disk is full") as info:
            write()
        _assert_kept(target, old, listing, info.value)


def test_a_disk_filling_up_during_the_write_keeps_the_old_file(tmp_path, monkeypatch):
    target = write_image(tmp_path / "frame.exr", _frame((8, 8)).astype(np.float32))
    old, listing = target.read_bytes(), _listing(tmp_path)
    answers = iter([_StatVfs(10**6), _StatVfs(0)])   # free before the write, none after it
    monkeypatch.setattr(os, "statvfs", lambda folder: next(answers))
    with pytest.raises(ImageWriteError) as info:
        write_image(target, _frame((8, 8)).astype(np.float32))
    _assert_kept(target, old, listing, info.value)
    assert "disk became full" in str(info.value)


@pytest.mark.parametrize("ext,exposure", [(".tif", 0.01), (".tif", None), (".exr", 0.01),
                                          (".png", 0.01), (".pgm", None), (".fits", 0.01)])
def test_real_short_writes_never_replace_the_file(tmp_path, ext, exposure):
    """A file-size limit makes the system refuse writes past a byte, as a full disk does.

    OpenImageIO reports some of these only through ``geterror()`` and some not at all (an OpenEXR
    or PNG file, the end of a TIFF file): reading the file back catches those.
    """
    import resource

    a = _frame((96, 96)).astype(np.float32 if ext == ".exr" else np.uint16)
    size = write_image(tmp_path / f"size{ext}", a, exposure=exposure).stat().st_size
    target = write_image(tmp_path / f"frame{ext}", a[:8, :8], exposure=exposure)
    old, listing = target.read_bytes(), _listing(tmp_path)
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        for limit in (size // 2, size - 1):
            resource.setrlimit(resource.RLIMIT_FSIZE, (limit, hard))
            try:
                with pytest.raises(ImageWriteError) as info:
                    write_image(target, a, exposure=exposure)
            finally:
                resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
            _assert_kept(target, old, listing, info.value)
    finally:
        signal.signal(signal.SIGXFSZ, handler)


def test_bad_fits_keyword_is_a_write_error(tmp_path):
    target = tmp_path / "k.fits"
    with pytest.raises(ImageWriteError) as info:
        write_image(target, _frame((4, 4)), attributes={"OBJECT": {"not": "a card"}})
    assert str(info.value).startswith(str(target)) and not any(tmp_path.iterdir())


def test_writing_onto_a_folder_is_a_write_error(tmp_path):
    (tmp_path / "taken.tif").mkdir()
    with pytest.raises(ImageWriteError, match="is a folder"):
        write_image(tmp_path / "taken.tif", _frame((4, 4)))
    assert _listing(tmp_path) == ["taken.tif"]


# --------------------------------------------------------------------------------------------
# bad input stays off stderr
# --------------------------------------------------------------------------------------------
def test_numpy_warnings_do_not_escape(tmp_path):
    from astropy.io import fits

    hdu = fits.PrimaryHDU(np.array([[1e300, 1.0], [np.nan, -1e300]]))
    hdu.header["BSCALE"] = 2.0                     # scaled: its physical values need float64
    hdu.writeto(tmp_path / "scaled.fits")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        write_map(tmp_path / "m.exr", np.array([[1e300, np.nan], [-np.inf, 1.0]]))
        write_map(tmp_path / "m.fits", np.array([[1e300, 1.0]]))
        assert np.isinf(read_image(tmp_path / "m.exr")[0, 0])
        data = read_image(tmp_path / "scaled.fits")
        assert data.dtype == np.float64 and data[0, 0] == 2e300 and data[1, 1] == -2e300


QUIET_SCRIPT = textwrap.dedent("""
    import sys
    from pathlib import Path
    import numpy as np
    from ccdcore.errors import ImageReadError, ImageWriteError
    from ccdcore.io.frames import read_header, read_image, read_region, write_image, write_map

    folder = Path(sys.argv[1])
    a = (np.arange(64 * 64, dtype=np.uint16).reshape(64, 64) * 7) % 4096
    errors = 0
    for ext in (".tif", ".exr", ".png", ".pgm", ".fits", ".jpg", ".bmp", ".hdr"):
        pixels = a.astype(np.float32) if ext in (".exr", ".hdr") else a
        if ext in (".jpg", ".bmp"):
            pixels = (a % 256).astype(np.uint8)
        if ext == ".hdr":
            pixels = np.dstack([pixels] * 3)
        data = write_image(folder / f"good{ext}", pixels).read_bytes()
        for cut in (len(data) - 300, len(data) // 2, 200, 30):
            bad = folder / f"cut{cut}{ext}"
            bad.write_bytes(data[:cut])
            for read in (read_header, read_image, lambda p: read_region(p, 60, 60, 4, 4)):
                try:
                    read(bad)
                except ImageReadError:
                    errors += 1
        junk = folder / f"junk{ext}"
        junk.write_bytes(b"\\x00junk" * 40)
        try:
            read_image(junk)
        except ImageReadError:
            errors += 1
    try:
        write_image(folder / "bad.tif", np.zeros((4, 4), dtype=bool))
    except ImageWriteError:
        errors += 1
    write_map(folder / "overflow.exr", np.full((4, 4), 1e300))
    print(errors)
""")


def test_bad_input_leaves_stderr_empty(tmp_path):
    """Truncated and junk files of every format: errors only, nothing on stderr.

    Run in a fresh interpreter, so that libpng's own messages and OpenImageIO's report of
    errors never retrieved (printed at exit) would show.
    """
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH",
                                                                                   "")])}
    env.pop("CCDCORE_MAX_PIXELS", None)
    done = subprocess.run([sys.executable, "-c", QUIET_SCRIPT, str(tmp_path)], env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    assert int(done.stdout) > 50
