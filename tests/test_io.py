"""Round trips of every format and dtype, header metadata, atomic writes and bad files."""
from __future__ import annotations

import os

import numpy as np
import pytest

from ccdcore.errors import CcdError, ImageReadError, ImageWriteError, MethodNotAvailable
from ccdcore.io.frames import (atomic_path, atomic_write_text, read_frame, read_header, read_image,
                        read_region,
                        write_image, write_map)

RNG = np.random.default_rng(20260)


def _random(shape, dtype):
    dtype = np.dtype(dtype)
    if dtype.kind == "f":
        return (RNG.standard_normal(shape) * 1e3).astype(dtype)
    info = np.iinfo(dtype)
    return RNG.integers(info.min, info.max, size=shape, endpoint=True, dtype=dtype)


ROUND_TRIPS = [
    (".tif", "uint8"), (".tif", "uint16"), (".tif", "uint32"), (".tif", "int16"),
    (".tif", "float32"), (".fits", "uint8"), (".fits", "uint16"), (".fits", "int16"),
    (".fits", "uint32"), (".fits", "float32"), (".png", "uint8"), (".png", "uint16"),
    (".pgm", "uint8"), (".pgm", "uint16"), (".exr", "float32"), (".exr", "float16"),
]


@pytest.mark.parametrize("ext,dtype", ROUND_TRIPS)
@pytest.mark.parametrize("channels", [1, 3])
def test_round_trip_keeps_values_and_dtype(tmp_path, ext, dtype, channels):
    if ext == ".pgm" and channels == 3:
        ext = ".ppm"
    shape = (13, 17) if channels == 1 else (13, 17, channels)
    a = _random(shape, dtype)
    path = write_image(tmp_path / f"frame{ext}", a, exposure=0.02)
    b, header = read_frame(path)
    assert b.dtype == a.dtype
    assert b.shape == a.shape == header.shape
    np.testing.assert_array_equal(b, a)
    assert header.layout == ("mono" if channels == 1 else "rgb")
    assert (header.width, header.height, header.channels) == (17, 13, channels)
    if ext not in (".pgm", ".ppm"):  # PNM has no metadata
        assert header.exposure == pytest.approx(0.02, rel=1e-4)


def test_integer_frames_are_not_rescaled(tmp_path):
    a = np.array([[0, 1, 4095], [65535, 2, 3]], dtype=np.uint16)
    for ext in (".tif", ".png", ".fits"):
        b = read_image(write_image(tmp_path / f"a{ext}", a))
        assert b.dtype == np.uint16 and b.max() == 65535 and b.min() == 0


def test_exposure_is_read_back_as_written(tmp_path):
    # EXIF stores a float32; the header gives back the decimal the camera wrote
    write_image(tmp_path / "e.tif", np.zeros((4, 4), np.uint16), exposure=0.033)
    assert read_header(tmp_path / "e.tif").exposure == 0.033
    write_image(tmp_path / "e.fits", np.zeros((4, 4), np.uint16), exposure=1 / 3, bits=12)
    h = read_header(tmp_path / "e.fits")
    assert h.exposure == 1 / 3 and h.bits == 12


def test_fits_header_keywords(tmp_path):
    from astropy.io import fits

    data = np.arange(20, dtype=np.uint16).reshape(4, 5) + 40000
    hdu = fits.PrimaryHDU(data)
    hdu.header["EXPOSURE"] = 2.5
    hdu.header["CCD-TEMP"] = -10.0
    hdu.header["GAIN"] = 1.6
    hdu.writeto(tmp_path / "cam.fits")
    b, h = read_frame(tmp_path / "cam.fits")
    np.testing.assert_array_equal(b, data)
    assert (h.exposure, h.temperature, h.gain) == (2.5, -10.0, 1.6)
    assert h.dtype == np.uint16


@pytest.mark.parametrize("ext", [".exr", ".fits"])
def test_maps_read_back_bit_exact(tmp_path, ext):
    m = RNG.standard_normal((31, 29)).astype(np.float32)
    m[0, 0], m[1, 1], m[2, 2] = np.nan, np.inf, -0.0
    b = read_image(write_map(tmp_path / f"map{ext}", m))
    assert b.dtype == np.float32
    assert b.tobytes() == m.tobytes()


def test_same_pixels_give_same_bytes(tmp_path):
    a = _random((8, 8), "uint16")
    for ext in (".tif", ".exr", ".fits", ".png"):
        p1 = write_image(tmp_path / f"one{ext}", a, exposure=0.01)
        p2 = write_image(tmp_path / f"two{ext}", a, exposure=0.01)
        assert p1.read_bytes() == p2.read_bytes(), ext


def test_missing_empty_truncated_and_junk_files_name_the_file(tmp_path):
    good = write_image(tmp_path / "good.tif", _random((64, 64), "uint16"))
    data = good.read_bytes()
    (tmp_path / "empty.tif").write_bytes(b"")
    (tmp_path / "trunc.tif").write_bytes(data[: len(data) - 500])
    (tmp_path / "junk.png").write_bytes(b"not a png at all")
    fits_good = write_image(tmp_path / "good.fits", _random((64, 64), "uint16"))
    (tmp_path / "trunc.fits").write_bytes(fits_good.read_bytes()[:4000])
    cases = {"missing.tif": "not found", "empty.tif": "empty", "trunc.tif": "truncated",
             "junk.png": "cannot read", "trunc.fits": "truncated", "notes.txt": "unsupported"}
    (tmp_path / "notes.txt").write_text("hello")
    for name, words in cases.items():
        with pytest.raises(ImageReadError) as info:
            read_image(tmp_path / name)
        assert str(tmp_path / name) in str(info.value)
        assert words in str(info.value)


@pytest.mark.parametrize("ext", [".tif", ".exr", ".png", ".pgm", ".fits"])
@pytest.mark.parametrize("keep", [0.9, 0.5, 0.1])
def test_truncated_files_of_every_format_name_the_file(tmp_path, capfd, ext, keep):
    a = _random((64, 64), "float32" if ext == ".exr" else "uint16")
    data = write_image(tmp_path / f"good{ext}", a).read_bytes()
    cut = tmp_path / f"cut{ext}"
    cut.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ImageReadError) as info:
        read_image(cut)
    message = str(info.value)
    assert message.startswith(f"{cut}: ") and "\n" not in message
    assert "truncated" in message or "cannot read" in message
    assert capfd.readouterr().err == ""             # no libpng / OpenImageIO chatter


def test_raw_file_errors_are_clear(tmp_path, monkeypatch):
    bogus = tmp_path / "shot.dng"
    bogus.write_bytes(b"II*\x00 this is not a raw file")
    with pytest.raises(ImageReadError) as info:          # rawpy is in the test extra
        read_image(bogus)
    assert "shot.dng" in str(info.value)
    # without the optional 'raw' extra: one message naming the file and how to install it
    import builtins

    real_import = builtins.__import__

    def no_rawpy(name, *args, **kwargs):
        if name == "rawpy":
            raise ImportError("No module named 'rawpy'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_rawpy)
    with pytest.raises(MethodNotAvailable) as info:
        read_image(bogus)
    assert "shot.dng" in str(info.value) and "ccdcore[raw]" in str(info.value)


def test_bad_writes(tmp_path):
    with pytest.raises(ImageWriteError):
        write_image(tmp_path / "a.png", np.zeros((4, 4), np.float32))
    with pytest.raises(ImageWriteError):
        write_image(tmp_path / "a.tif", np.zeros((4,), np.uint8))
    with pytest.raises(ImageWriteError):
        write_map(tmp_path / "a.tif", np.zeros((4, 4)))
    assert not any(tmp_path.iterdir())


def test_atomic_write_leaves_old_file_on_failure(tmp_path):
    target = tmp_path / "out.txt"
    atomic_write_text(target, "old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half written")
            raise RuntimeError("interrupted")
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["out.txt"]


def test_errors_are_value_errors_with_where():
    err = CcdError("frames[2]", "unknown role 'drak'")
    assert isinstance(err, ValueError)
    assert str(err) == "frames[2]: unknown role 'drak'"


@pytest.mark.parametrize("bitpix_data, bzero, bscale, expected, dtype", [
    (np.array([[44, 10]], np.uint8), 256, 1, [[300.0, 266.0]], "float32"),
    (np.array([[1, 2]], np.uint8), 1e300, 1, [[1e300, 1e300]], "float64"),
    (np.array([[0, 255]], np.uint8), -128, 1, [[-128, 127]], "int8"),
    (np.array([[0, 255]], np.uint8), 0, 1, [[0, 255]], "uint8"),
    (np.array([[-32768, 32767]], np.int16), 32768, 1, [[0, 65535]], "uint16"),
    (np.array([[2, 4]], np.int16), 10.0, 0.5, [[11.0, 12.0]], "float32"),
    (np.array([[-2 ** 31, 2 ** 31 - 1]], np.int32), 2 ** 31, 1, [[0, 2 ** 32 - 1]], "uint32")])
def test_fits_physical_values_follow_bzero_and_bscale(tmp_path, bitpix_data, bzero, bscale,
                                                      expected, dtype):
    """FITS 4.0 sec. 4.4.2: the value is BZERO + BSCALE x stored, for every BITPIX (an 8-bit
    physical 300 was read as 44, a BZERO of 1e300 as zeros); whole frames and regions alike."""
    from astropy.io import fits

    hdu = fits.PrimaryHDU()
    hdu.data = bitpix_data
    hdu.header["BZERO"], hdu.header["BSCALE"] = bzero, bscale
    path = tmp_path / "f.fits"
    hdu.writeto(path, output_verify="silentfix")
    assert fits.getdata(path, do_not_scale_image_data=True).tolist() == bitpix_data.tolist()
    got = read_image(path)
    assert got.dtype == np.dtype(dtype) and read_header(path).dtype == np.dtype(dtype)
    np.testing.assert_array_equal(got, np.asarray(expected, dtype))
    np.testing.assert_array_equal(read_region(path, 1, 0, 1, 1), got[:, 1:])


def test_fits_scaling_that_is_no_scaling_is_refused(tmp_path):
    from astropy.io import fits

    hdu = fits.PrimaryHDU()
    hdu.data = np.zeros((2, 2), np.int16)
    hdu.header["BSCALE"] = 0.0
    path = tmp_path / "z.fits"
    hdu.writeto(path, output_verify="silentfix")
    with pytest.raises(CcdError, match="BSCALE"):
        read_image(path)
