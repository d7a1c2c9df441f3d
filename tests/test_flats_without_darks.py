"""Flats without darks: de Lasarte's zero-dark form (DL_0 = 0), its note in the product and the
report, the held-out check on colour flats of two aperture groups, and the command-line role
(``--role flat``) for a folder of camera files.  Never reads /work/shared."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from ccdcore.cli.command import main
from ccdcore.errors import CcdError
from ccdcore.flatfield.check import held_out_figures
from ccdcore.flatfield.fit import flat_field, flat_field_from_session
from ccdcore.io.frames import write_image
from ccdcore.product.make import calibrate
from ccdcore.session import open_session
from ccdcore.simulate.ccdlab import simulate


def _rgb_flats(folder, seed=0, n=5, shape=(48, 64)):
    """Two exposure groups of colour flats (8-bit, as a DSLR's JPEGs), differing in
    vignetting as two apertures do, named as a camera names its files (no role in them)."""
    rng = np.random.default_rng(seed)
    h, w = shape
    y, x = np.mgrid[0:h, 0:w]
    r2 = ((x - w / 2) ** 2 + (y - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    prnu = 1 + 0.01 * rng.standard_normal((h, w, 3))
    folder.mkdir(parents=True)
    k = 0
    for t, corner in ((1 / 320, 0.80), (1 / 350, 0.90)):
        F = (1 - (1 - corner) * r2)[..., None] * prnu
        for _ in range(n):
            level = np.array([120.0, 130.0, 190.0]) * F
            frame = level + rng.normal(0, 1, level.shape) * np.sqrt(level / 50.0)
            write_image(folder / f"DSC_{k:04d}.tif", np.clip(np.rint(frame), 0, 255)
                        .astype(np.uint8), exposure=t)
            k += 1


def test_zero_dark_flat_field_is_noted_in_product_and_summary(tmp_path):
    root = tmp_path / "nodark"
    simulate(root, seed=2, size=(48, 32), darks=False, n_flats=6)
    product = calibrate(root)
    ff = product.estimates.flat_field
    assert ff.dark_source == "zero" and ff.n_dark == 0
    assert any("zero-dark form, DL_0 = 0" in n for n in ff.notes)
    rows = {r.label: r for r in ff.rows()}
    assert rows["dark image"].shown == "zero (DL_0 = 0)"
    assert "zero-dark" in rows["dark image"].meaning
    # the maps: DL_0 = 0, so O = 0 and G = k / DL_B
    assert not product.maps["flat_dark"].any() and not product.maps["flat_O"].any()
    assert ff.held_out is not None and ff.held_out.n_fit == 5


def test_held_out_check_on_colour_flats_within_one_aperture_group(tmp_path):
    root = tmp_path / "dslr"
    _rgb_flats(root)
    session = open_session(root, role="flat")
    assert session.roles() == {"flat": 10}
    ff = flat_field_from_session(session, base=(None, 1 / 320), held_out=True)
    assert ff.dark_source == "zero" and ff.layout == "rgb"
    check = ff.held_out
    assert check.verdict == "pass" and [c.name for c in check.channels] == ["R", "G", "B"]
    assert check.n_fit == 4 and check.dark == "zero dark (DL_0 = 0)"
    # a flat of the other aperture corrected with these maps: its vignetting differs, the
    # check warns (the reason to hold out within one group)
    groups = session.flat_groups()
    recs = list(groups[(None, 1 / 320)])[:4]
    ff4 = flat_field([np.zeros((48, 64, 3))] * 2, session.iter_frames(recs))
    other = groups[(None, 1 / 350)][0]
    bad = held_out_figures(ff4, session.read(other), n_fit=4, held_out=other.relpath)
    assert bad.verdict == "warn" and bad.worst_ratio > 1.5


def test_role_flag_calibrates_a_folder_of_camera_files(tmp_path, capsys):
    root = tmp_path / "dslr"
    _rgb_flats(root)
    # named as the camera named them, the files are not flats (here: a bracket with repeated
    # exposures, refused)
    assert main(["calibrate", str(root), "-o", str(tmp_path / "none")]) == 2
    capsys.readouterr()
    out = tmp_path / "prod"
    assert main(["calibrate", str(root), "--role", "flat", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "zero (DL_0 = 0)" in printed and "held-out check" in printed
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["estimates"]["flat_field"]["dark_source"] == "zero"
    assert len(doc["frames"]["flat_G"]) == 5
    applied = tmp_path / "applied"
    assert main(["apply", str(out), str(root / "DSC_0000.tif"), "-o", str(applied)]) == 0


def test_role_flag_writes_a_draft_manifest(tmp_path, capsys):
    root = tmp_path / "dslr"
    _rgb_flats(root, n=3)
    assert main(["session", str(root), "--draft", "--role", "flat"]) == 0
    draft = (root / "session.toml.draft").read_text()
    assert draft.count('role = "flat"') == 6 and "scene" not in draft
    shutil.move(root / "session.toml.draft", root / "session.toml")
    assert open_session(root).roles() == {"flat": 6}
    # with a manifest the roles are its own: --role is refused, in one line
    with pytest.raises(CcdError, match="plain folder"):
        open_session(root, role="flat")
    capsys.readouterr()
    assert main(["session", str(root), "--role", "flat"]) == 2
    assert "plain folder" in capsys.readouterr().err


def test_the_base_images_note_is_in_words(tmp_path):
    """The recommended base's note names its group as the summary does ("level –, exposure
    0.003125 s"), never a raw key with None or 16 digits, and never says "inside the linear
    range" of a group it could not show linear."""
    from ccdcore.flatfield.fit import recommend_base

    folder = tmp_path / "card"
    _rgb_flats(folder)
    session = open_session(folder, role="flat")
    rec = recommend_base(session)
    assert rec.reason.startswith("flat group level –, exposure 0.00")
    assert "None" not in rec.reason and "0.0028571428" not in rec.reason
    assert "0.0031250000" not in rec.reason
    linear = "inside the linear range" in rec.reason
    assert linear != ("no group could be shown linear" in rec.reason)
