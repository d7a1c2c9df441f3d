"""Tests of ccdcore.session.emva: EMVA1288 descriptors, checked against the reference implementation."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

# emva1288 1.0.2 calls np.asfarray, removed in NumPy 2 (see docs/notes.md)
np.asfarray = lambda a, dtype=np.float64: np.asarray(a, dtype=dtype)  # noqa: E731

from emva1288.camera.dataset_generator import DatasetGenerator  # noqa: E402
from emva1288.process.parser import ParseEmvaDescriptorFile  # noqa: E402
from PIL import Image  # noqa: E402  (Pillow wrote the images; read them back with it)

from ccdcore.session import open_emva_descriptor  # noqa: E402
from ccdcore.io.frames import write_image  # noqa: E402
from ccdcore.session import draft_manifest, open_session  # noqa: E402

W, H, STEPS, L = 16, 12, 4, 4


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> DatasetGenerator:
    """A 12-bit exposure-time series: STEPS temporal bright/dark point pairs of 2 images each and
    one spatial bright/dark pair of L images each (the reference generator's protocol)."""
    out = tmp_path_factory.mktemp("emva") / "data"
    return DatasetGenerator(steps=STEPS, L=L, image_format="tif", outdir=str(out), width=W,
                            height=H, bit_depth=12, seed=7)


def test_descriptor_import_matches_the_reference_parser(dataset: DatasetGenerator) -> None:
    s = open_emva_descriptor(dataset.descriptor_path)
    assert s.problems == () and s.ok
    assert s.source == "emva1288" and s.manifest_path == Path(dataset.descriptor_path)
    assert (s.camera.bits, s.camera.layout) == (12, "mono")
    assert s.roles() == {"dark": 2 * STEPS + L, "ptc": 2 * STEPS + L}

    # the reference parser's view: kind -> exposure [ns] -> photons -> image paths
    ref = ParseEmvaDescriptorFile(dataset.descriptor_path)
    expected = {(Path(f).resolve(), exp, photons)
                for kind in ref.images.values() for exp, points in kind.items()
                for photons, files in points.items() for f in files}
    ours = {(r.path, r.exposure, r.photons) for r in s.frames}
    # exposures: ns / 1e9 is the correctly rounded quotient, so equality within 1 ulp-ish
    assert len(ours) == len(expected) == len(s.frames)
    by_path = {p: (e, ph) for p, e, ph in expected}
    for path, exposure, photons in ours:
        exp_ns, ref_photons = by_path[path]
        assert exposure == pytest.approx(exp_ns * 1e-9, rel=1e-12)
        assert photons == ref_photons
    assert all((r.photons == 0.0) == (r.role == "dark") for r in s.frames)

    # levels: the k-th bright point of the file is level k (4 temporal points, then 1 spatial)
    levels = s.ptc_levels()
    assert list(levels) == [1, 2, 3, 4, 5]
    assert [len(v) for v in levels.values()] == [2, 2, 2, 2, L]
    temporal_ns = [float(t) for t in dataset.points["temporal"]]
    spatial_ns = [float(t) for t in dataset.points["spatial"]]
    assert [v[0].exposure for v in levels.values()] == pytest.approx(
        [t * 1e-9 for t in temporal_ns + spatial_ns], rel=1e-12)
    assert {r.exposure for r in s.dark_frames()} == {r.exposure for r in s.by_role("ptc")}
    assert all(len({r.exposure for r in v}) == 1 for v in levels.values())

    # shapes, dtype and pixels exactly as the generator wrote them
    for rec, data in s.iter_frames():
        assert s.header(rec).shape == (H, W) and data.shape == (H, W)
        np.testing.assert_array_equal(data, np.asarray(Image.open(rec.path)))
        assert data.max() < 2**12


def test_open_session_dispatches_on_the_v_line(dataset: DatasetGenerator) -> None:
    direct = open_emva_descriptor(dataset.descriptor_path)
    via = open_session(dataset.descriptor_path)
    assert via.source == "emva1288" and via.frames == direct.frames


def test_emva_session_round_trips_through_a_manifest(dataset: DatasetGenerator) -> None:
    s = open_emva_descriptor(dataset.descriptor_path)
    draft = draft_manifest(s)  # beside the descriptor: manifest paths are relative to it
    manifest = draft.with_name("roundtrip.toml")  # any *.toml opens as a manifest
    try:
        assert draft.read_text().count("[[frames]]") == len(s.frames)
        draft.rename(manifest)
        back = open_session(manifest)
        assert back.ok and back.source == "manifest" and back.camera == s.camera
        assert back.frames == s.frames  # photons included (nothing inferred on either side)
    finally:
        draft.unlink(missing_ok=True)
        manifest.unlink(missing_ok=True)


def test_eight_bit_png_dataset(tmp_path: Path) -> None:
    gen = DatasetGenerator(steps=2, L=3, outdir=str(tmp_path / "d8"), width=W, height=H,
                           bit_depth=8, seed=3)  # default image_format: png
    s = open_session(gen.descriptor_path)
    assert s.ok and s.camera.bits == 8
    assert {str(s.header(r).dtype) for r in s.frames} == {"uint8"}
    assert [len(v) for v in s.ptc_levels().values()] == [2, 2, 3]


def test_descriptor_problems_are_reported(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    for name, shape in (("a.tif", (H, W)), ("b.tif", (H, W)), ("small.tif", (8, 10)),
                        ("d0.tif", (H, W)), ("d1.tif", (H, W))):
        write_image(tmp_path / "img" / name, rng.integers(0, 4096, shape).astype(np.uint16))
    desc = tmp_path / "emva.txt"
    desc.write_text(
        "# written by hand\n"
        "\n"
        "v 3.1\n"
        f"n 12 {W} {H}\n"
        "i img\\a.tif\n"                 # line 5: before any point
        "b 1000000,0 250.5\n"            # decimal comma, as the reference parser accepts
        "i img\\a.tif\n"
        "i img\\b.tif\n"
        "i img\\small.tif\n"             # line 9: wrong size
        "d 1000000.0\n"
        "i img\\d0.tif\n"
        "i img/missing.tif\n"            # line 12
        "b 2000000.0\n"                  # line 13: no photons
        "x what\n"                       # line 14
        "b 3000000.0 oops\n"             # line 15
        "b 4000000.0 10.0\n"             # line 16: a single image (level 2 of 1 frame)
        "i img\\d1.tif\n"
        "d 5000000.0\n")                 # line 18: no images
    s = open_session(desc)
    assert s.source == "emva1288" and s.camera.bits == 12
    assert [(p.where, p.message) for p in s.problems] == [
        ("emva.txt line 5", "image line before any 'b' or 'd' point"),
        ("emva.txt line 13", "should be 'b <exposure_ns> <photons>'"),
        ("emva.txt line 14", "unknown line type 'x' (expected v, n, b, d or i)"),
        ("emva.txt line 15", "photons per pixel 'oops' is not a number"),
        ("emva.txt line 18", "point has no 'i' image lines"),
        ("img/missing.tif", "file not found"),
        ("img/small.tif", "size 10 × 8 differs from 16 × 12 of the other ptc frames (3 frames)"),
        ("ptc level 2", "only one frame (img/d1.tif); a photon-transfer level needs at least two"),
        ("img/small.tif", "image is 10x8 but the descriptor's n line says 16x12"),
    ]
    level1 = s.ptc_levels()[1]
    assert [r.relpath for r in level1] == ["img/a.tif", "img/b.tif", "img/small.tif"]
    assert level1[0].exposure == 1e-3 and level1[0].photons == 250.5
    (dark,) = s.dark_frames()
    assert (dark.relpath, dark.exposure, dark.photons) == ("img/d0.tif", 1e-3, 0.0)
