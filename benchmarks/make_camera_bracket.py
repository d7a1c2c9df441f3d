"""A camera-resolution exposure bracket for benchmarks, made from a real one.

Every frame of a bracket folder (a session with ``session.toml`` listing ``role = "bracket"``
frames and their ``exposure``) is upsampled by ``--factor`` (bicubic, Pillow) and saved as a
JPEG (quality 95) carrying its exposure time as EXIF ``ExposureTime`` (a rational), with no
manifest: the output folder reads as a camera card (``ccdcore`` takes the times from EXIF).

    .venv/bin/python benchmarks/make_camera_bracket.py ../shared/data/brackets/living_room1 \\
        /tmp/camera_bracket --factor 5

Write the output under /tmp: generated data is never committed.
"""
from __future__ import annotations

import argparse
import sys
import tomllib
from fractions import Fraction
from pathlib import Path

from PIL import Image, TiffImagePlugin

EXIF_IFD = 0x8769
EXPOSURE_TIME = 0x829A


def bracket_frames(folder: Path) -> list[tuple[Path, float]]:
    """``(path, exposure)`` of the bracket frames of a session folder, in manifest order."""
    manifest = tomllib.loads((folder / "session.toml").read_text())
    return [(folder / f["path"], float(f["exposure"])) for f in manifest.get("frames", [])
            if f.get("role", "bracket") == "bracket" and f.get("exposure") is not None]


def exposure_rational(t: float) -> TiffImagePlugin.IFDRational:
    """The exposure time as an EXIF rational (1/16 s, 4 s, ...)."""
    f = Fraction(t).limit_denominator(1_000_000)
    return TiffImagePlugin.IFDRational(f.numerator, f.denominator)


def make(src: Path, dst: Path, factor: float, quality: int = 95) -> list[Path]:
    frames = bracket_frames(src)
    if not frames:
        raise SystemExit(f"{src}: no bracket frames with an exposure in session.toml")
    dst.mkdir(parents=True, exist_ok=True)
    out = []
    for path, t in frames:
        with Image.open(path) as im:
            img = im.convert("RGB")
        size = (round(img.width * factor), round(img.height * factor))
        big = img.resize(size, Image.BICUBIC)
        ex = big.getexif()
        ex.get_ifd(EXIF_IFD)[EXPOSURE_TIME] = exposure_rational(t)
        target = dst / (path.stem + ".jpg")
        big.save(target, quality=quality, exif=ex)
        out.append(target)
        print(f"{target}  {size[0]}x{size[1]}  {t:g} s", flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path, help="a bracket session folder (session.toml)")
    ap.add_argument("out", type=Path, help="output folder (use /tmp)")
    ap.add_argument("--factor", type=float, default=5.0, help="upsampling factor (default 5)")
    ap.add_argument("--quality", type=int, default=95, help="JPEG quality (default 95)")
    args = ap.parse_args(argv)
    if not (args.source / "session.toml").is_file():
        print(f"{args.source}: no session.toml (the real brackets live in ../shared/data)")
        return 0
    make(args.source, args.out, args.factor, args.quality)
    return 0


if __name__ == "__main__":
    sys.exit(main())
