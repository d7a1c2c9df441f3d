"""Calibration products: every estimate a session allows, saved as a folder that loads back exactly.

Public objects
--------------
:class:`CalibrationProduct`
    Float32 maps (dark reference, its variance, K̂, n'_1, hot/dead flags ...) plus the JSON
    summaries of each estimate (noise model, dark reference, fixed pattern, acquisition plan, scene
    variation) and the provenance (which step, which parameters, which session).
:func:`calibrate`
    Runs every estimate the session's frames allow and returns the product.
:func:`load_product`, :meth:`CalibrationProduct.save`
    The folder format: ``calibration.json`` + ``maps/<name>.exr`` (float32, bit-exact round trip).
:func:`apply_product`
    Corrects images: D_C = (D − D̂_D)/K̂ (eq. 51 of Healey & Kondepudy 1994), or D − D̂_D when the
    product has no K̂.

The folder is written atomically: into a temporary sibling folder first, then renamed over the
target (an existing product is replaced only once the new one is complete).
"""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from . import __version__
from .errors import CcdError
from .io import (FITS_EXTENSIONS, atomic_write_text, read_frame, read_header, read_image,
                 write_image, write_map)
from .session import Session, open_session

__all__ = ["CalibrationProduct", "Estimates", "estimate_all", "scene_error_terms", "calibrate",
           "load_product", "apply_product", "PRODUCT_FILE"]

PRODUCT_FILE = "calibration.json"
PRODUCT_SCHEMA = 1

Progress = Callable[[str, float], None]


def _no_progress(step: str, fraction: float) -> None:
    return None


@dataclass(frozen=True, eq=False)
class CalibrationProduct:
    """The calibration of one camera set-up (see the module docstring).

    Attributes
    ----------
    maps
        Name -> float32 map. Names in use: ``dark`` (D̂_D), ``dark_var`` (its per-pixel
        temporal variance), ``hot``, ``dead`` (0/1 flags), ``K`` (K̂, eq. 49), ``K_var`` (its
        per-pixel error variance), ``n1_used`` (n'_1); flat field (frame-shaped, colour or
        mosaic): ``flat_G``, ``flat_O``, ``flat_flags``, ``flat_dark`` (DL_0), ``flat_base`` (DL_B).
    estimates
        Name -> JSON summary of each estimate: ``noise`` (photon transfer), ``dark``,
        ``fixed_pattern``, ``plan``, ``scene``.
    camera
        The session's camera table.
    provenance
        ``ccdcore`` version, the session, and per step its parameters.
    notes
        Why an estimate was skipped, and warnings (e.g. fewer configurations than planned).
    """

    maps: dict[str, np.ndarray]
    estimates: dict[str, Any]
    camera: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    # -------------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The content of ``calibration.json`` (maps by file name)."""
        return {"schema": PRODUCT_SCHEMA, "camera": self.camera,
                "maps": {name: f"maps/{name}.exr" for name in sorted(self.maps)},
                "estimates": self.estimates, "provenance": self.provenance,
                "notes": list(self.notes)}

    def save(self, folder: str | os.PathLike) -> Path:
        """Write ``calibration.json`` and the maps into ``folder`` atomically; return the folder."""
        folder = Path(folder)
        if folder.exists() and not (folder / PRODUCT_FILE).exists() and any(folder.iterdir()):
            raise CcdError(folder, "exists and is not a calibration product; "
                                   "choose an empty or new folder")
        folder.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
        try:
            for name, m in self.maps.items():
                write_map(tmp / "maps" / f"{name}.exr", m)
            text = json.dumps(self.to_dict(), indent=2, allow_nan=False, default=_json_default)
            atomic_write_text(tmp / PRODUCT_FILE, text + "\n")
            os.chmod(tmp, 0o755)
            if folder.exists():
                old = folder.with_name(f".{folder.name}.old-{os.getpid()}")
                os.replace(folder, old)
                os.replace(tmp, folder)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(tmp, folder)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return folder

    # -------------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, ...] | None:
        """Shape of the frames the product corrects."""
        for name in ("flat_G", "dark"):
            if name in self.maps:
                return self.maps[name].shape
        return None

    @property
    def method(self) -> str:
        """How :meth:`correct` corrects: ``"flat_field"``, ``"fixed_pattern"`` or ``"dark"``."""
        if "flat_G" in self.maps:
            return "flat_field"
        return "fixed_pattern" if "K" in self.maps else "dark"

    def correct(self, frame: np.ndarray, *, name: str | None = None) -> np.ndarray:
        """Correct one frame, float32.

        With flat-field maps: DL_c = O + G·DL (de Lasarte et al. 2007), which removes the dark
        image, the PRNU and the vignetting. Otherwise (D − D̂_D)/K̂ (eq. 51 of Healey & Kondepudy
        1994), or D − D̂_D without ``K``; without any of them a :class:`CcdError` says so.
        """
        if "flat_G" in self.maps:
            from .flatfield import correct as flat_correct

            return flat_correct(frame, self.maps["flat_G"], self.maps["flat_O"], where=name)
        if "dark" not in self.maps:
            raise CcdError(name, "the calibration product has no dark reference to correct with")
        d = np.asarray(frame)
        if d.shape != self.maps["dark"].shape:
            raise CcdError(name, f"image shape {d.shape} differs from the calibration maps' "
                                 f"{self.maps['dark'].shape}")
        out = d.astype(np.float64) - self.maps["dark"]
        if "K" in self.maps:
            out /= self.maps["K"]
        return out.astype(np.float32)


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _clean(obj: Any) -> Any:
    """Replace NaN/inf by None so calibration.json is strict JSON."""
    if isinstance(obj, dict):
        return {k: _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def load_product(folder: str | os.PathLike) -> CalibrationProduct:
    """Load a product folder written by :meth:`CalibrationProduct.save` (maps bit-exact)."""
    folder = Path(folder)
    manifest = folder / PRODUCT_FILE if folder.is_dir() else folder
    if not manifest.exists():
        raise CcdError(folder, f"not a calibration product (no {PRODUCT_FILE})")
    root = manifest.parent
    try:
        doc = json.loads(manifest.read_text())
    except (OSError, ValueError) as exc:
        raise CcdError(manifest, f"cannot read the product description: {exc}") from None
    if doc.get("schema") != PRODUCT_SCHEMA:
        raise CcdError(manifest, f"unsupported product schema {doc.get('schema')!r}")
    maps: dict[str, np.ndarray] = {}
    for name, rel in doc.get("maps", {}).items():
        path = (root / rel).resolve()
        if root.resolve() not in path.parents:
            raise CcdError(manifest, f"map '{name}' points outside the product folder: {rel}")
        maps[name] = read_image(path)
    return CalibrationProduct(maps=maps, estimates=doc.get("estimates", {}),
                              camera=doc.get("camera", {}), provenance=doc.get("provenance", {}),
                              notes=tuple(doc.get("notes", ())))


# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Estimates:
    """The result objects of :func:`estimate_all` (``None`` where the session lacks the frames).

    ``notes`` say why an estimate is missing; ``plan_warnings`` list what the session lacks
    compared with the acquisition plan (sec. V-B).
    """

    noise: Any = None
    dark: Any = None
    fixed_pattern: Any = None
    plan: Any = None
    plan_warnings: tuple[str, ...] = ()
    scene: dict[str, Any] | None = None
    correction_check: Any = None
    flat: Any = None
    notes: tuple[str, ...] = ()


def scene_error_terms(dark: Any, fixed_pattern: Any) -> dict[str, Any]:
    """The calibration maps' own errors for :func:`ccdcore.scene.scene_variations`.

    D̂_D's error variance σ²_N/s per pixel (sec. V-A), K̂'s measured error variance
    (:attr:`FixedPattern.K_var`) and the level at which K̂ was measured (harmonic mean of the
    configurations' levels), through which K̂ absorbed the D̂_D error (eq. 46).
    """
    levels = np.asarray(fixed_pattern.config_levels, dtype=np.float64)
    return {"dark_var": dark.var_map / dark.s, "K_var": float(np.mean(fixed_pattern.K_var)),
            "fp_level": float(1.0 / np.mean(1.0 / levels))}


def estimate_all(session: Session, *, roi: tuple[int, int, int, int] | None = None,
                 window: int = 9, p: float = 1.5, noise: Any = None,
                 progress: Progress | None = None) -> Estimates:
    """Every Healey–Kondepudy estimate the session's frames allow (see :func:`calibrate`).

    ``noise`` may pass an already computed photon-transfer result (e.g. with levels the user
    excluded in the app) instead of computing it here.
    """
    from .darkframe import dark_reference
    from .fixedpattern import correction_check, fixed_pattern_map
    from .flatfield import flat_field_from_session
    from .noise import photon_transfer
    from .planning import check_session_plan, plan_acquisition
    from .scene import scene_variations

    report = progress or _no_progress
    notes: list[str] = []
    roles = session.roles()
    dark = fp = plan = scene = None
    warnings: list[str] = []

    report("photon transfer", 0.0)
    if noise is None and roles.get("ptc"):
        noise = photon_transfer(session, roi=roi)
    elif noise is None:
        notes.append("no ptc frames: noise model not estimated")

    report("dark reference", 0.25)
    mono = session.camera.layout == "mono"
    if roles.get("dark") and not mono and not roles.get("fixed_pattern"):
        notes.append(f"{session.camera.layout} camera: the dark reference D̂_D of sec. V-A is "
                     "made for mono frames; the flat-field DL_0 serves instead")
    elif roles.get("dark"):
        fp_exposures = {r.exposure for r in session.by_role("fixed_pattern")} - {None}
        dark_exp = next(iter(fp_exposures)) if len(fp_exposures) == 1 else None
        dark_exposures = {r.exposure for r in session.dark_frames()}
        dark = dark_reference(session, exposure=dark_exp if len(dark_exposures) > 1 else None)
    else:
        notes.append("no dark frames: dark reference not estimated")

    report("fixed pattern", 0.5)
    if roles.get("fixed_pattern"):
        if dark is None:
            raise CcdError(session.root, "fixed_pattern frames need dark frames for D̂_D (eq. 46); "
                                         "add dark frames to the session")
        fp = fixed_pattern_map(session, dark, window=window, p=p)
    else:
        notes.append("no fixed_pattern frames: K map not estimated")

    report("planning", 0.75)
    if noise is not None and session.camera.bits and fp is not None:
        try:
            plan = plan_acquisition(noise, bits=session.camera.bits, fixed_pattern=fp)
        except CcdError as err:
            notes.append(f"acquisition plan not computed: {err}")
        else:
            warnings = list(check_session_plan(session, plan))
    elif noise is not None:
        notes.append("acquisition plan needs the fixed-pattern slope spread σ̂ (fixed_pattern "
                     "frames) and the camera bit depth")

    if roles.get("scene") and noise is not None and fp is not None and dark is not None:
        report("scene variation", 0.85)
        try:
            scene = scene_variations(session, dark, fp, noise, **scene_error_terms(dark, fp))
        except CcdError as err:
            notes.append(f"scene variation not estimated: {err}")
    flat = None
    if roles.get("flat"):
        report("flat field", 0.9)
        if not roles.get("dark"):
            raise CcdError(session.root, "flat frames need dark frames for DL_0 (de Lasarte et "
                                         "al. 2007); add dark frames to the session")
        flat = flat_field_from_session(session, base="auto")

    check = None
    brightest = [r for r in session.scenes() if (r.note or "").strip() == "max-intensity"]
    if brightest and dark is not None and fp is not None:
        # the paper's check of eq. 51 on a maximum-intensity image (sec. VII-A)
        check = correction_check(session.read(brightest[0]), dark, fp)
    elif fp is not None:
        notes.append("no scene frame with note = \"max-intensity\": the correction check of "
                     "sec. VII-A (pixels changed by more than 1 and 2 quantisation steps) skipped")
    report("done", 1.0)
    return Estimates(noise=noise, dark=dark, fixed_pattern=fp, plan=plan,
                     plan_warnings=tuple(warnings), scene=scene, correction_check=check,
                     flat=flat, notes=tuple(notes))


def calibrate(session_or_path: Session | str | os.PathLike, *,
              roi: tuple[int, int, int, int] | None = None, window: int = 9, p: float = 1.5,
              progress: Progress | None = None) -> CalibrationProduct:
    """Run every estimate the session's frames allow.

    - ``ptc`` levels: photon transfer (eqs. 37–42, 59–67), over ``roi`` when given;
    - ``dark`` frames: dark reference D̂_D with hot/dead flags (sec. V-A);
    - ``fixed_pattern`` configurations and darks: K̂ (eqs. 45–50, ``window``, ``p``);
    - noise model: acquisition plan n1, n2 (sec. V-B), with warnings if the session has fewer;
    - ``scene`` frames with patches/ROIs, K̂ and the noise model: scene variation V_S (sec. VI).

    An estimate whose frames are absent is skipped with a note; an estimate whose frames are there
    but bad raises :class:`CcdError` (naming the file or level), so nothing is silently dropped.
    """
    session = session_or_path if isinstance(session_or_path, Session) \
        else open_session(session_or_path)
    session.raise_if_invalid()
    if not session.frames:
        raise CcdError(session.root, "the session has no frames")
    e = estimate_all(session, roi=roi, window=window, p=p, progress=progress)
    maps: dict[str, np.ndarray] = {}
    est: dict[str, Any] = {}
    steps: dict[str, Any] = {}
    notes = list(e.notes) + list(e.plan_warnings)
    if e.noise is not None:
        est["noise"] = e.noise.to_dict()
        steps["noise"] = {"method": "photon transfer, Healey & Kondepudy 1994 eqs. 37-42, 59-67",
                          "roi": list(roi) if roi else None}
    if e.dark is not None:
        dark = e.dark
        maps["dark"] = dark.mean_map.astype(np.float32)
        maps["dark_var"] = dark.var_map.astype(np.float32)
        maps["hot"] = dark.hot_mask.astype(np.float32)
        maps["dead"] = dark.dead_mask.astype(np.float32)
        est["dark"] = dark.to_dict()
        steps["dark"] = {"method": "streamed average, sec. V-A", "s": dark.s,
                         "hot_rule": dark.hot_rule, "dead_rule": dark.dead_rule}
    if e.fixed_pattern is not None:
        fp = e.fixed_pattern
        maps["K"] = fp.K.astype(np.float32)
        maps["K_var"] = fp.K_var.astype(np.float32)
        maps["n1_used"] = fp.n1_used.astype(np.float32)
        est["fixed_pattern"] = fp.to_dict()
        steps["fixed_pattern"] = {"method": "eqs. 45-50, sec. V-B", "window": window, "p": p}
    if e.plan is not None:
        est["plan"] = e.plan.to_dict()
        est["plan"]["warnings"] = list(e.plan_warnings)
    if e.correction_check is not None:
        est["correction_check"] = e.correction_check.to_dict()
    if e.flat is not None:
        maps.update(e.flat.maps())
        est["flat_field"] = e.flat.to_dict()
        steps["flat_field"] = {"method": "gain/offset maps, de Lasarte et al. 2007",
                               "base": est["flat_field"]["base"],
                               "flag_rule": e.flat.flag_rule}
    if e.scene is not None:
        est["scene"] = {name: v.to_dict() for name, v in e.scene.items()}
        steps["scene"] = {"method": "eqs. 53-58, sec. VI, with the calibration maps' errors"}
    provenance = {"ccdcore": __version__, "session": str(session.manifest_path or session.root),
                  "source": session.source, "n_frames": len(session.frames), "steps": steps}
    return CalibrationProduct(maps=maps, estimates=_clean(est), camera=session.camera.to_dict(),
                              provenance=provenance, notes=tuple(notes))


# ---------------------------------------------------------------------------------------------
def _output_name(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in FITS_EXTENSIONS or suffix in (".tif", ".tiff", ".exr"):
        return path.name
    return path.stem + ".tif"


def apply_product(product: CalibrationProduct | str | os.PathLike,
                  images: Iterable[str | os.PathLike], out_dir: str | os.PathLike) -> list[Path]:
    """Correct each image with the product (eq. 51) into ``out_dir`` as float32.

    Output keeps the base name; TIFF, EXR and FITS keep their format, others become ``.tif``
    (float32 cannot be stored in PNG/PNM). Inputs are never modified; an output that would
    overwrite an input is refused.
    """
    if not isinstance(product, CalibrationProduct):
        product = load_product(product)
    out_dir = Path(out_dir)
    images = [Path(p) for p in images]
    if not images:
        raise CcdError("images", "no images given")
    targets = [out_dir / _output_name(p) for p in images]
    seen: dict[Path, Path] = {}
    for src, dst in zip(images, targets):
        if dst.resolve() == src.resolve():
            raise CcdError(src, "the output would overwrite the input; choose another -o folder")
        if dst in seen:
            raise CcdError(src, f"has the same output name as {seen[dst]}")
        seen[dst] = src
    shape = product.shape
    for src in images:  # check every header before writing anything
        header = read_header(src)
        if shape is not None and header.shape != shape:
            raise CcdError(src, f"image shape {header.shape} differs from the calibration "
                                f"maps' {shape}")
    written = []
    for src, dst in zip(images, targets):
        data, header = read_frame(src)
        written.append(write_image(dst, product.correct(data, name=str(src)),
                                   exposure=header.exposure))
    return written
