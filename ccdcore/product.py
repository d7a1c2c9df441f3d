"""Calibration products: every estimate a session allows, saved as a folder that loads back exactly.

Public objects
--------------
:class:`CalibrationProduct`
    Float32 maps (dark reference, its variance, K̂, n'_1, hot/dead flags ...) plus the JSON
    summaries of each estimate (noise model, dark reference, fixed pattern, acquisition plan, scene
    variation), the EMVA 1288 figures when the session has photon counts, and the provenance
    (which step, which parameters, which session: its content hash, and when).
:func:`calibrate`
    Runs every estimate the session's frames allow and returns the product.
:class:`MapName`
    The names of the maps (a ``str`` enum; its home is :mod:`ccdcore.map_names`).
:func:`load_product`, :meth:`CalibrationProduct.save`
    The folder format: ``calibration.json`` + ``maps/<name>.exr`` (float32, bit-exact round trip;
    a map whose name is not a :class:`MapName` is refused).
:func:`apply_product`
    Corrects images: D_C = (D − D̂_D)/K̂ (eq. 51 of Healey & Kondepudy 1994), or D − D̂_D when the
    product has no K̂.

The folder is written atomically: into a temporary sibling folder first, then renamed over the
target (an existing product is replaced only once the new one is complete).
"""
from __future__ import annotations

import contextlib
import datetime
import json
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Mapping, Union

import numpy as np

from . import __version__
from .channels import Layout
from .common import json_safe
from .darkframe import DarkReference
from .datasheet import EmvaFigures
from .errors import CcdError
from .fixedpattern import CorrectionCheck, FixedPattern
from .flatfield import FlatField
from .io import (FITS_EXTENSIONS, atomic_write_text, check_outputs, output_set,
                 read_frame, read_header, read_image, remove_stale_temporaries, write_image,
                 write_map)
from .map_names import MapName
from .noise import PhotonTransfer
from .planning import AcquisitionPlan
from .progress import Progress, Steps
from .reduce import STREAMED, Reducer
from .scene import SceneVariation
from .session import MAX_INTENSITY, Camera, Session, open_session

if TYPE_CHECKING:      # imported where a response is estimated (numba's kernels load then)
    from .response.methods import ResponseResult

__all__ = ["CalibrationProduct", "Estimates", "Skipped", "Requirement", "REQUIREMENTS",
           "requirement", "missing_frames", "estimate_all", "scene_error_terms", "budget_inputs",
           "calibrate", "load_product", "apply_product", "COMPRESSIONS", "PRODUCT_FILE",
           "ESTIMATE_STEPS", "session_inputs", "map_problem", "MapName"]

PRODUCT_FILE = "calibration.json"
PRODUCT_SCHEMA = 1

#: a value of ``calibration.json`` (strict JSON: no NaN)
JsonValue = Union[None, bool, int, float, str, list["JsonValue"], dict[str, "JsonValue"]]
JsonDict = dict[str, JsonValue]

#: maps whose values must be finite and > 0 (they divide)
_POSITIVE_MAPS = (MapName.K,)
#: maps that must be finite everywhere
_FINITE_MAPS = (MapName.DARK, MapName.DARK_VAR, MapName.K_VAR, MapName.FLAT_G,
                MapName.FLAT_O)


#: the steps of :func:`estimate_all` in order, with the overall fraction at which each starts
#: (its ``progress`` receives ``progress(start, name)`` at each, :class:`ccdcore.progress.Steps`;
#: :class:`ccdcore.progress.Tracker` takes them)
ESTIMATE_STEPS: tuple[tuple[str, float], ...] = (
    ("photon transfer", 0.0), ("EMVA 1288 figures", 0.08), ("dark reference", 0.15),
    ("fixed pattern", 0.3), ("planning", 0.55), ("correction check", 0.6),
    ("scene variation", 0.65), ("flat field", 0.8), ("response", 0.9), ("done", 1.0))


@dataclass(frozen=True, eq=False)
class CalibrationProduct:
    """The calibration of one camera set-up (see the module docstring).

    Attributes
    ----------
    maps
        Name -> float32 map; the names are the members of :class:`MapName` (a plain string
        of a member's value reads a map too): ``dark`` (D̂_D), ``dark_var`` (its per-pixel
        temporal variance), ``hot``, ``dead`` (0/1 flags), ``K`` (K̂, eq. 49), ``K_var`` (its
        per-pixel error variance), ``n1_used`` (n'_1); flat field (frame-shaped, colour or
        mosaic): ``flat_G``, ``flat_O``, ``flat_flags``, ``flat_dark`` (DL_0), ``flat_base`` (DL_B).
    estimates
        Name -> JSON summary of each estimate made: ``noise`` (photon transfer), ``dark``,
        ``fixed_pattern``, ``plan``, ``correction_check``, ``scene``, ``flat_field``.
    camera
        The session's camera.
    provenance
        ``ccdcore`` version, the session (its label, ``source``, ``n_frames`` and
        ``session_hash``, the SHA-256 of :meth:`~ccdcore.session.Session.content_hash`), the
        ``date`` of the calibration (UTC, ISO 8601), and per step its parameters.  Products of
        earlier releases have no ``session_hash`` nor ``date``.
    skipped
        Every estimate that was not made, with its reason.
    warnings
        What the session lacks against the acquisition plan (fewer configurations or frames).
    notes
        Remarks on the product as a whole; each estimate keeps its own notes (products of the
        first release kept their skip reasons and plan warnings here).
    emva1288
        The EMVA 1288 figures (:meth:`ccdcore.datasheet.EmvaFigures.to_dict`, the top-level key
        ``"emva1288"`` of ``calibration.json``), or ``None`` when the session has no photon
        counts (the key is then absent).
    """

    maps: dict[str, np.ndarray]
    estimates: dict[str, JsonDict]
    camera: Camera = field(default_factory=Camera)
    provenance: JsonDict = field(default_factory=dict)
    skipped: tuple[Skipped, ...] = ()
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    emva1288: JsonDict | None = None

    # -------------------------------------------------------------------------------------
    def to_dict(self) -> JsonDict:
        """The content of ``calibration.json`` (maps by file name; ``emva1288`` when made)."""
        out: JsonDict = {"schema": PRODUCT_SCHEMA, "camera": self.camera.to_dict(),
                         "maps": {name: f"maps/{name}.exr" for name in sorted(self.maps)},
                         "estimates": self.estimates}
        if self.emva1288 is not None:
            out["emva1288"] = self.emva1288
        out.update({"skipped": [s.to_dict() for s in self.skipped],
                    "provenance": self.provenance, "warnings": list(self.warnings),
                    "notes": list(self.notes)})
        return out

    def save(self, folder: str | os.PathLike, *,
             inputs: Iterable[str | os.PathLike] = ()) -> Path:
        """Write ``calibration.json`` and the maps into ``folder`` atomically; return the folder.

        Everything is written into a temporary folder first (:func:`ccdcore.io.output_set`),
        which becomes ``folder``, or replaces the earlier product in it, only once complete: the
        earlier description goes first and the new one comes last, so the folder is never a mix
        of two products (it can be the current directory). An earlier product is replaced
        whole: its maps this product does not have are removed; other files of the folder are
        left alone. A failure, Ctrl+C or SIGTERM removes the temporary folder, and leftovers of
        a killed save are removed by the next save. ``inputs`` (the session's files) must not
        be overwritten.
        """
        folder = Path(os.path.abspath(folder))
        if folder.exists() and not folder.is_dir():
            raise CcdError(folder, "exists and is not a folder; choose a new or empty folder")
        if folder.is_dir():
            remove_stale_temporaries(folder)
        if folder.exists() and not (folder / PRODUCT_FILE).exists() and any(folder.iterdir()):
            raise CcdError(folder, "exists and is not a calibration product; "
                                   "choose an empty or new folder")
        _check_maps(self.maps, folder / PRODUCT_FILE)   # never write what load_product refuses
        with output_set(folder, inputs=inputs, last=PRODUCT_FILE,
                        replaces=(PRODUCT_FILE, "maps")) as tmp:
            for name, m in self.maps.items():
                write_map(tmp / "maps" / f"{name}.exr", m)
            text = json.dumps(self.to_dict(), indent=2, allow_nan=False)
            atomic_write_text(tmp / PRODUCT_FILE, text + "\n")
        return folder

    # -------------------------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, ...] | None:
        """Shape of the frames the product corrects."""
        for name in (MapName.FLAT_G, MapName.DARK):
            if name in self.maps:
                return self.maps[name].shape
        return None

    @property
    def method(self) -> str:
        """How :meth:`correct` corrects: ``"flat_field"``, ``"fixed_pattern"`` or ``"dark"``."""
        if MapName.FLAT_G in self.maps:
            return "flat_field"
        return "fixed_pattern" if MapName.K in self.maps else "dark"

    def response_models(self, where: Any = PRODUCT_FILE) -> dict[str, Any]:
        """Channel -> :class:`ccdcore.response.hdr.ResponseModel` from the ``response``
        estimate (g per code, nominal a_k, b_k, noise terms), checked: a clear error names
        ``where`` when the product has no response or a damaged one."""
        from .response.hdr import ResponseModel

        r = self.estimates.get("response")
        if not isinstance(r, dict):
            raise CcdError(where, "the calibration product has no response curve: calibrate "
                                  "a session with an exposure bracket (role = bracket)")
        try:
            names = [str(c) for c in r["channels"]]
            out = {}
            for i, c in enumerate(names):
                g = np.asarray(r["g"][i], np.float64)
                a = np.asarray(r["a"][i], np.float64)
                b = np.asarray(r["b"][i], np.float64)
                if g.ndim != 1 or g.size < 2 or not np.all(np.isfinite(g)) \
                        or np.any(np.diff(g) < 0):
                    raise ValueError(f"g of channel {c} is not a finite non-decreasing curve")
                if a.shape != b.shape or not np.all(a > 0):
                    raise ValueError(f"a, b of channel {c} do not match or a is not positive")
                out[c] = ResponseModel(g, a, b, float(r["sigma_s"][i] or 0.0),
                                       float(r["sigma_c1"][i] or 0.0),
                                       float(r["sigma_c2"][i] or 0.0))
        except (KeyError, IndexError, TypeError, ValueError) as exc:
            raise CcdError(where, f"damaged response estimate: {exc}") from None
        return out

    def linearise(self, frame: np.ndarray, *, name: str | None = None) -> np.ndarray:
        """Codes mapped through the inverse response g of each channel (float32, on g's
        reported scale: linear in exposure, 0.9 at the code 90 % up the range)."""
        from .channels import channel_slices

        models = self.response_models()
        d = np.asarray(frame)
        if not np.issubdtype(d.dtype, np.integer):
            raise CcdError(name, f"linearising needs the camera's integer codes, got {d.dtype}")
        layout = self.camera.layout if self.camera.layout else None
        out = np.empty(d.shape, np.float32)
        for ch, idx in channel_slices(d.shape, layout).items():
            if ch not in models:
                raise CcdError(name, f"the product has no response for channel {ch}")
            g = models[ch].g
            plane = d[idx]
            if plane.size and (int(plane.min()) < 0 or int(plane.max()) >= g.size):
                raise CcdError(name, f"codes beyond the response's {g.size} levels (another "
                                     "camera or bit depth?)")
            out[idx] = g[plane].astype(np.float32)
        return out

    def correct(self, frame: np.ndarray, *, name: str | None = None) -> np.ndarray:
        """Correct one frame, float32.

        With flat-field maps: DL_c = O + G·DL (de Lasarte et al. 2007), which removes the dark
        image, the PRNU and the vignetting. Otherwise (D − D̂_D)/K̂ (eq. 51 of Healey & Kondepudy
        1994), or D − D̂_D without ``K``; without any of them a :class:`CcdError` says so.
        """
        if MapName.FLAT_G in self.maps:
            from .flatfield import correct as flat_correct

            return flat_correct(frame, self.maps[MapName.FLAT_G], self.maps[MapName.FLAT_O],
                                where=name)
        if MapName.DARK not in self.maps:
            raise CcdError(name, "the calibration product has no dark reference or flat field "
                                 "to correct with")
        d = np.asarray(frame)
        dark = self.maps[MapName.DARK]
        if d.shape != dark.shape:
            raise CcdError(name, f"image shape {d.shape} differs from the calibration maps' "
                                 f"{dark.shape}")
        out = d.astype(np.float64) - dark
        if MapName.K in self.maps:
            out /= self.maps[MapName.K]
        return out.astype(np.float32)


# ---------------------------------------------------------------------------------------------
# the folder: validation on load (writing goes through ccdcore.io.output_set)
# ---------------------------------------------------------------------------------------------
def map_problem(name: str, m: np.ndarray) -> str | None:
    """Why map ``name`` would make a damaged product (``None``: it is fine): not a numeric
    image, ``K`` not finite and > 0 everywhere (it divides), the other checked maps not finite.
    The one check of :func:`load_product`, of :meth:`CalibrationProduct.save` and of
    :func:`estimate_all` (a map that fails it makes its estimate skipped)."""
    m = np.asarray(m)
    if m.dtype.kind not in "fiub" or m.ndim not in (2, 3):
        return f"map '{name}' is not a numeric image (shape {m.shape}, {m.dtype})"
    if name in _POSITIVE_MAPS:
        bad = int(np.count_nonzero(~(np.isfinite(m) & (m > 0))))
        if bad:
            return f"map '{name}' has {bad} pixel(s) that are not finite and > 0 (it divides)"
    elif name in _FINITE_MAPS:
        bad = int(np.count_nonzero(~np.isfinite(m)))
        if bad:
            return f"map '{name}' has {bad} non-finite pixel(s)"
    return None


def _map_name(name: Any, manifest: Path) -> MapName:
    """``name`` as its :class:`MapName`; a clear error naming ``manifest`` when it is none."""
    try:
        return MapName(name)
    except ValueError:
        known = ", ".join(m.value for m in MapName)
        raise CcdError(manifest, f"unknown map {name!r} (the maps of a product are {known}); "
                                 "the product is damaged or from another program") from None


def _check_maps(maps: Mapping[str, np.ndarray], manifest: Path) -> None:
    """Every map has a :class:`MapName` and the frame shape of its family; K is finite and
    > 0; others finite."""
    for name in maps:
        _map_name(name, manifest)
    frame_maps = {n: m for n, m in maps.items() if not n.startswith("flat_")}
    flat_maps = {n: m for n, m in maps.items() if n.startswith("flat_")}
    for family in (frame_maps, flat_maps):
        shapes = {m.shape for m in family.values()}
        if len(shapes) > 1:
            listing = ", ".join(f"{n} {m.shape}" for n, m in family.items())
            raise CcdError(manifest, f"maps of different shapes ({listing}); the product is "
                                     "damaged: calibrate again")
    for name, m in maps.items():
        problem = map_problem(name, m)
        if problem is not None:
            raise CcdError(manifest, f"{problem}; the product is damaged")


# the types of the estimates' fields that readers (``report``, ``calibrate``'s summary, the
# app, ``apply --linearise``) use, checked on load so a damaged field is one line naming it
# rather than a traceback: "number" is a number or null (NaN is stored as null), "text" a
# string, "flag" a boolean, "list"/"object" any list/object; [spec] a list of spec,
# {key: spec} an object whose keys present match ("*": every key)
_NUMBERS = ["number"]
_CURVES = [_NUMBERS]
_ESTIMATE_FIELDS: dict[str, Any] = {
    "noise": {"A": "number", "A_err": "number", "sigma_c2": "number", "sigma_c2_err": "number",
              "cov": _CURVES, "chi2": "number", "dof": "number", "Q": "number",
              "verdict": "text", "black_level_dn": "number", "black_level_source": "text",
              "conversion_gain_e_per_dn": "number", "read_noise_e": "number",
              "read_noise_dn": "number", "quantisation_dn2": "number", "bits": "number",
              "robust_dropped": _NUMBERS, "notes": ["text"], "source": "text",
              "points": [{"level": "number", "mu": "number", "var": "number",
                          "var_err": "number", "used": "flag", "exposure": "number",
                          "n_pairs": "number", "n_pixels": "number"}]},
    "dark": {"s": "number", "shape": _NUMBERS, "mean": "number", "mean_sem": "number",
             "spatial_std": "number", "spatial_std_signal": "number", "noise_var": "number",
             "n_hot": "number", "n_dead": "number", "hot_rule": "text", "dead_rule": "text",
             "exposure": "number", "notes": ["text"]},
    "fixed_pattern": {"n1": "number", "n2": "number", "window": "number", "p": "number",
                      "shape": _NUMBERS, "mean": "number", "spatial_std": "number",
                      "sigma_hat": "number", "var_bound": "number", "sd_bound": "number",
                      "K_var_mean": "number", "config_ids": "list",
                      "config_levels": _NUMBERS, "notes": ["text"]},
    "plan": {"n1_required": "number", "n2_required": "number", "n1_hat": "number",
             "n2_exact": "number", "n1_formula": "text", "n2_formula": "text",
             "n2_reading": "text", "n2_alternatives": {"*": "number"},
             "inputs": {"*": "number"}, "notes": ["text"], "warnings": ["text"]},
    "correction_check": {"*": "number"},
    "scene": {"*": {"name": "text", "V_S": "number", "V_S_err": "number", "chi2": "number",
                    "dof": "number", "Q": "number", "measurements": ["object"],
                    "excluded": "list", "notes": ["text"]}},
    "flat_field": {"layout": "text", "shape": _NUMBERS, "n_dark": "number",
                   "n_base": "number", "n_flagged": "number", "noise_limit": "number",
                   "window": "number", "flag_rule": "text", "base": _NUMBERS,
                   "setting": "text", "dark_exposure": "number", "notes": ["text"],
                   "channels": [{"name": "text", "k": "number", "dark_level": "number",
                                 "base_level": "number", "n_flagged": "number",
                                 "n_pixels": "number"}]},
    "response": {"method": "text", "channels": ["text"], "levels": "number",
                 "scale": {"fixed_code": "number", "g_at_fixed_code": "number",
                           "offset": "flag"}, "exposure_times": _NUMBERS, "g": _CURVES,
                 "g_err": _CURVES, "a": _CURVES, "b": _CURVES, "a_err": _CURVES,
                 "b_err": _CURVES, "sigma_s": _NUMBERS, "sigma_c1": _NUMBERS,
                 "sigma_c2": _NUMBERS, "sigma_s_err": _NUMBERS, "sigma_c1_err": _NUMBERS,
                 "sigma_c2_err": _NUMBERS, "iterations": _NUMBERS, "converged": ["flag"],
                 "bloom_radius": "number", "white_balance": ["flag"],
                 "notes": {"*": ["text"]}, "warnings": ["text"],
                 "agreement": {"rms": "number", "rms_fitted": "number", "rms_blend": "number",
                               "code_range": _NUMBERS,
                               "channels": [{"channel": "text", "rms": "number",
                                             "rms_fitted": "number", "rms_blend": "number",
                                             "pairs": ["object"]}]}},
}
_PROVENANCE_FIELDS: dict[str, Any] = {
    "ccdcore": "text", "session": "text", "source": "text", "n_frames": "number",
    "session_hash": "text", "date": "text", "scheduler": "text", "steps": {"*": "object"}}


def _type_problem(value: Any, spec: Any, where: str) -> str | None:
    """Where ``value`` does not have the type ``spec`` says (see ``_ESTIMATE_FIELDS``)."""
    if isinstance(spec, str):
        ok = {"number": (value is None or (isinstance(value, (int, float))
                                           and not isinstance(value, bool))),
              "text": isinstance(value, str), "flag": isinstance(value, bool),
              "list": isinstance(value, list), "object": isinstance(value, dict)}[spec]
        word = {"number": "a number", "text": "a string", "flag": "true or false",
                "list": "a list", "object": "an object"}[spec]
        return None if ok else f"'{where}' must be {word}, got {_json_kind(value)}"
    if isinstance(spec, list):
        if not isinstance(value, list):
            return f"'{where}' must be a list, got {_json_kind(value)}"
        for i, item in enumerate(value):
            problem = _type_problem(item, spec[0], f"{where}[{i}]")
            if problem:
                return problem
        return None
    if not isinstance(value, dict):
        return f"'{where}' must be an object, got {_json_kind(value)}"
    for key, item in value.items():
        sub = spec.get(key, spec.get("*"))
        problem = None if sub is None else _type_problem(item, sub, f"{where}.{key}")
        if problem:
            return problem
    return None


def _json_kind(value: Any) -> str:
    if value is None:
        return "null"
    name = {bool: "true/false", int: "a number", float: "a number", str: "a string",
            list: "a list", dict: "an object"}.get(type(value), type(value).__name__)
    return f"{name} ({json.dumps(value)[:40]})" if isinstance(value, (str, int, float)) \
        and not isinstance(value, bool) else name


def _check_fields(estimates: Mapping[str, Any], provenance: Mapping[str, Any],
                  manifest: Path) -> None:
    """The fields of the estimates and the provenance that readers use have their types."""
    problem = _type_problem(dict(estimates), {k: v for k, v in _ESTIMATE_FIELDS.items()},
                            "estimates") or _type_problem(dict(provenance), _PROVENANCE_FIELDS,
                                                          "provenance")
    if problem:
        raise CcdError(manifest, f"{problem}; the product is damaged: calibrate again")


def _camera_from(doc: Any, manifest: Path) -> Camera:
    if not isinstance(doc, dict):
        raise CcdError(manifest, "'camera' must be an object")
    bits, layout = doc.get("bits"), doc.get("layout", "mono")
    if bits is not None and not (isinstance(bits, int) and 1 <= bits <= 32):
        raise CcdError(manifest, f"camera bits must be an integer from 1 to 32, got {bits!r}")
    black = doc.get("black_level")
    if black is not None and not (isinstance(black, (int, float)) and math.isfinite(black)):
        raise CcdError(manifest, f"camera black_level must be a number, got {black!r}")
    return Camera(name=str(doc.get("name", "")), bits=bits, layout=str(layout),
                  black_level=None if black is None else float(black))


def load_product(folder: str | os.PathLike) -> CalibrationProduct:
    """Load a product folder written by :meth:`CalibrationProduct.save` (maps bit-exact).

    The description is validated before anything is used: its types, that every map is inside
    the folder and readable, that maps of one family share a shape, that K̂ is finite and
    positive and the other maps finite.

    Raises
    ------
    CcdError
        Not a product, or a damaged one (the message names the file and the problem).
    """
    folder = Path(folder)
    manifest = folder / PRODUCT_FILE if folder.is_dir() else folder
    if not manifest.is_file():
        raise CcdError(folder, f"not a calibration product (no {PRODUCT_FILE})")
    root = manifest.parent
    try:
        doc = json.loads(manifest.read_bytes().decode("utf-8-sig"))
    except (OSError, ValueError) as exc:
        raise CcdError(manifest, f"cannot read the product description: {exc}") from None
    except RecursionError:
        raise CcdError(manifest, "objects or lists nested too deeply to read (a damaged "
                                 "product description?)") from None
    if not isinstance(doc, dict):
        raise CcdError(manifest, f"must hold a JSON object, not a {type(doc).__name__}")
    if doc.get("schema") != PRODUCT_SCHEMA:
        raise CcdError(manifest, f"unsupported product schema {doc.get('schema')!r}; this "
                                 f"version reads schema {PRODUCT_SCHEMA}")
    for key, kind in (("maps", dict), ("estimates", dict), ("provenance", dict),
                      ("skipped", list), ("warnings", list), ("notes", list)):
        if not isinstance(doc.get(key, kind()), kind):
            raise CcdError(manifest, f"'{key}' must be a JSON {kind.__name__.replace('dict', 'object')}")
    estimates = doc.get("estimates", {})
    if not all(isinstance(v, dict) for v in estimates.values()):
        raise CcdError(manifest, "every entry of 'estimates' must be an object")
    _check_fields(estimates, doc.get("provenance", {}), manifest)
    emva = doc.get("emva1288")
    if emva is not None and not isinstance(emva, dict):
        raise CcdError(manifest, "'emva1288' must be a JSON object")
    try:
        skipped = tuple(Skipped.from_dict(d) for d in doc.get("skipped", ()))
    except (KeyError, TypeError, AttributeError):
        raise CcdError(manifest, "'skipped' entries need 'estimate' and 'reason'") from None
    maps: dict[str, np.ndarray] = {}
    for raw_name, rel in doc.get("maps", {}).items():
        name = _map_name(raw_name, manifest)
        if not isinstance(rel, str):
            raise CcdError(manifest, f"map '{name}' must be a relative path, got {rel!r}")
        path = (root / rel).resolve()
        if root.resolve() not in path.parents:
            raise CcdError(manifest, f"map '{name}' points outside the product folder: {rel}")
        maps[name] = read_image(path)
    _check_maps(maps, manifest)
    return CalibrationProduct(maps=maps, estimates=estimates,
                              camera=_camera_from(doc.get("camera", {}), manifest),
                              provenance=doc.get("provenance", {}), skipped=skipped,
                              warnings=tuple(str(n) for n in doc.get("warnings", ())),
                              notes=tuple(str(n) for n in doc.get("notes", ())), emva1288=emva)


# ---------------------------------------------------------------------------------------------
# what each estimate needs
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Requirement:
    """What one estimate needs from a session.

    ``roles`` are the frame roles it reads; ``capture`` says, for a person, what to capture when
    they are missing; ``flag`` names a frame flag it needs (``max-intensity``); ``patches``: it
    needs scene frames that name a patch or an ROI.
    """

    estimate: str
    roles: tuple[str, ...]
    purpose: str
    capture: str
    flag: str | None = None
    patches: bool = False


#: every estimate :func:`calibrate` makes, in order, and what it needs
REQUIREMENTS: tuple[Requirement, ...] = (
    Requirement("noise", ("ptc",), "the noise model A, σ²_C (photon transfer, eqs. 37–42)",
                "pairs of frames at several light levels (role = ptc, level = 1, 2, …)"),
    Requirement("emva1288", ("ptc", "dark"),
                "the EMVA 1288 figures (K, QE, σ_d, saturation, dynamic range, linearity, "
                "DSNU, PRNU; release 3.1)",
                "an EMVA1288 descriptor: pairs of bright frames with their photon counts from "
                "dark to saturation, two dark frames at each exposure time, and L frames at "
                "50 % of saturation with as many dark frames (role = ptc with photons, "
                "role = dark)"),
    Requirement("dark", ("dark",), "the dark reference D̂_D with hot/dead flags (sec. V-A)",
                "16 or more lens-capped frames at the exposure of the other frames "
                "(role = dark)"),
    Requirement("fixed_pattern", ("fixed_pattern", "dark"),
                "the fixed-pattern map K̂ (eqs. 45–50)",
                "n1 configurations × n2 frames of a uniform card, moving card and lamp between "
                "configurations (role = fixed_pattern, config = 1 … n1), and dark frames"),
    Requirement("plan", ("ptc", "fixed_pattern"), "the acquisition plan n1, n2 (sec. V-B)",
                "photon-transfer pairs and fixed-pattern frames (with [camera] bits set)"),
    Requirement("correction_check", ("scene", "fixed_pattern", "dark"),
                "the check of eq. 51 on a maximum-intensity image (sec. VII-A)",
                "a scene frame of a card at maximum intensity (role = scene, "
                "flags = [\"max-intensity\"])", flag=MAX_INTENSITY),
    Requirement("scene", ("scene", "ptc", "fixed_pattern", "dark"),
                "the scene variation V_S of uniform patches (sec. VI)",
                "uniform surface patches at several light levels (role = scene, patch = NAME "
                "or an roi)", patches=True),
    Requirement("flat_field", ("flat", "dark"),
                "the flat-field gain/offset maps G, O (de Lasarte et al. 2007)",
                "flat fields of a uniform source (role = flat, level, exposure) and dark frames "
                "at their exposure"),
    Requirement("response", ("bracket",),
                "the inverse response g and the noise terms (Tsin et al. 2001, sec. 3.2)",
                "an exposure bracket of a static scene (role = bracket, one exposure per "
                "frame, e.g. 8 exposures a factor of 1.4 apart)"),
)


def requirement(estimate: str) -> Requirement:
    """The :class:`Requirement` of one estimate name (see :data:`REQUIREMENTS`)."""
    for req in REQUIREMENTS:
        if req.estimate == estimate:
            return req
    raise KeyError(estimate)


def missing_frames(session: Session, estimates: Iterable[str] | None = None
                   ) -> list[tuple[Requirement, tuple[str, ...]]]:
    """The estimates (all, or those named) whose frames the session lacks, each with the roles
    (or the flag) it is missing, in :data:`REQUIREMENTS` order."""
    have = session.roles()
    out = []
    for req in REQUIREMENTS:
        if estimates is not None and req.estimate not in estimates:
            continue
        lacking = tuple(r for r in req.roles if not have.get(r))
        if not lacking and req.flag is not None and not session.flagged(req.flag, req.roles[0]):
            lacking = (f"{req.roles[0]} frame with flags = [\"{req.flag}\"]",)
        if not lacking and req.patches and not session.scene_patches():
            lacking = (f"{req.roles[0]} frames with a patch or an roi",)
        if lacking:
            out.append((req, lacking))
    return out


@dataclass(frozen=True)
class Skipped:
    """An estimate :func:`estimate_all` did not make: ``code`` is ``"missing-frames"`` (the
    session lacks ``roles``), ``"failed"`` (its frames are there but the method refused them,
    ``reason`` says why), ``"needs"`` (an estimate it builds on was not made) or
    ``"not-applicable"`` (the method does not apply to this camera, e.g. D̂_D on colour frames)."""

    estimate: str
    code: str
    reason: str
    roles: tuple[str, ...] = ()

    def to_dict(self) -> JsonDict:
        return {"estimate": self.estimate, "code": self.code, "reason": self.reason,
                "roles": list(self.roles)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Skipped:
        return cls(estimate=str(d["estimate"]), code=str(d.get("code", "failed")),
                   reason=str(d["reason"]), roles=tuple(d.get("roles", ())))


@dataclass(frozen=True, eq=False)
class Estimates:
    """The result objects of :func:`estimate_all` (``None`` where not made; ``skipped`` says why).

    ``plan_warnings`` list what the session lacks compared with the acquisition plan (sec. V-B);
    each result keeps its own notes.
    """

    noise: PhotonTransfer | None = None
    dark: DarkReference | None = None
    fixed_pattern: FixedPattern | None = None
    plan: AcquisitionPlan | None = None
    plan_warnings: tuple[str, ...] = ()
    scene: dict[str, SceneVariation] | None = None
    correction_check: CorrectionCheck | None = None
    flat: FlatField | None = None
    response: ResponseResult | None = None
    skipped: tuple[Skipped, ...] = ()
    emva1288: EmvaFigures | None = None

    @property
    def made(self) -> tuple[str, ...]:
        """The names of the estimates that were made (:data:`REQUIREMENTS` names)."""
        have = {"noise": self.noise, "emva1288": self.emva1288, "dark": self.dark,
                "fixed_pattern": self.fixed_pattern, "plan": self.plan,
                "correction_check": self.correction_check,
                "scene": self.scene, "flat_field": self.flat, "response": self.response}
        return tuple(k for k, v in have.items() if v is not None)


def scene_error_terms(dark: DarkReference, fixed_pattern: FixedPattern) -> dict[str, Any]:
    """The calibration maps' own errors for :func:`ccdcore.scene.scene_variations`.

    D̂_D's error variance σ²_N/s per pixel (sec. V-A), K̂'s measured error variance
    (:attr:`FixedPattern.K_var`) and the level at which K̂ was measured (harmonic mean of the
    configurations' levels), through which K̂ absorbed the D̂_D error (eq. 46).
    """
    levels = np.asarray(fixed_pattern.config_levels, dtype=np.float64)
    return {"dark_var": dark.var_map / dark.s, "K_var": float(np.mean(fixed_pattern.K_var)),
            "fp_level": float(1.0 / np.mean(1.0 / levels))}


def budget_inputs(dark: DarkReference, fp: FixedPattern, noise: PhotonTransfer,
                  variation: SceneVariation, bits: int | None) -> dict[str, Any]:
    """Inputs of :func:`ccdcore.scene.variance_budget` for one patch (Fig. 4 of Healey &
    Kondepudy 1994).

    ``dark_spatial_var``: D̂_D's spatial variance without the averaging noise
    (``DarkReference.spatial_std_signal²``); ``sigma_K2``: K̂'s spatial variance less its mean
    estimation variance (``mean(FixedPattern.K_var)``), clamped at 0; ``V_S``: the patch's fit,
    clamped at 0; black level from the noise model; μ from the dark mean to full scale
    (2^bits − 1, 255 when the bit depth is unknown).
    """
    full = float(2 ** int(bits) - 1) if bits else 255.0
    k_var = float(np.mean(fp.K_var)) if fp.K_var is not None else 0.0
    dark_sig = dark.spatial_std_signal
    b0 = noise.black_level_dn
    b0 = 0.0 if b0 is None or not math.isfinite(b0) else float(b0)
    dbar = max(float(dark.mean), b0)
    return {"mu": np.linspace(dbar, max(full, dbar + 1.0), 200),
            "A": float(noise.A), "sigma_c2": max(float(noise.sigma_c2), 0.0),
            "dark_spatial_var": dark_sig ** 2 if math.isfinite(dark_sig) else 0.0,
            "sigma_K2": max(fp.spatial_std ** 2 - k_var, 0.0),
            "V_S": max(float(variation.V_S), 0.0) if math.isfinite(variation.V_S) else 0.0,
            "black_level": b0, "dark_mean": dbar}


@dataclass(eq=False)
class _Run:
    """One :func:`estimate_all` run: the session, its options, the estimates made so far and
    those skipped; each step :meth:`attempt`\\ s its estimate."""

    session: Session
    roi: tuple[int, int, int, int] | None
    window: int
    p: float
    noise: PhotonTransfer | None
    response: bool
    emva1288: bool
    reducer: Reducer
    dark_exposure: float | None = None
    made: dict[str, Any] = field(default_factory=dict)
    skipped: list[Skipped] = field(default_factory=list)
    lacking: dict[str, tuple[str, ...]] = field(init=False)

    def __post_init__(self) -> None:
        self.lacking = dict((req.estimate, roles) for req, roles in missing_frames(self.session))

    def attempt(self, name: str, needs: tuple[str, ...], run: Callable[[], Any]) -> None:
        """Make estimate ``name`` with ``run``, or skip it: its frames missing, an estimate
        of ``needs`` not made, its frames refused (:class:`CcdError`) or its maps damaged."""
        if name in self.lacking:
            roles = self.lacking[name]
            what = " and no ".join(r if " " in r else f"{r} frames" for r in roles)
            req = requirement(name)
            self.skipped.append(Skipped(name, "missing-frames", f"no {what}: for {req.purpose}, "
                                                                f"capture {req.capture}", roles))
            return
        absent = [n for n in needs if self.made.get(n) is None]
        if absent:
            self.skipped.append(Skipped(name, "needs", f"needs the {', '.join(absent)} estimate"
                                        f"{'s' if len(absent) > 1 else ''}, which was not made"))
            return
        try:
            result = run()
        except CcdError as err:
            self.skipped.append(Skipped(name, "failed", str(err)))
            return
        problem = _damaged_maps(name, result)
        if problem is not None:  # a product holding it would not load: skip it, say why
            self.skipped.append(Skipped(name, "failed", f"{problem}; the estimate was left out "
                                                        "(a product holding it would be damaged)"))
            return
        self.made[name] = result

    def estimates(self) -> Estimates:
        """What was made, with the plan's warnings against the session."""
        from .planning import check_session_plan

        made = self.made
        plan = made.get("plan")
        warnings = tuple(check_session_plan(self.session, plan)) if plan is not None else ()
        return Estimates(noise=made.get("noise"), dark=made.get("dark"),
                         fixed_pattern=made.get("fixed_pattern"), plan=plan,
                         plan_warnings=warnings, scene=made.get("scene"),
                         correction_check=made.get("correction_check"),
                         flat=made.get("flat_field"), response=made.get("response"),
                         skipped=tuple(self.skipped), emva1288=made.get("emva1288"))


def _photon_transfer(run: _Run) -> None:
    """``ptc`` levels: the noise model A, σ²_C (or the one given)."""
    from .noise import photon_transfer

    if run.noise is not None:
        run.made["noise"] = run.noise
    else:
        run.attempt("noise", (), lambda: photon_transfer(run.session, roi=run.roi,
                                                         reducer=run.reducer))


def _emva_figures(run: _Run) -> None:
    """``ptc`` frames with photon counts and darks: the EMVA 1288 figures (not applicable
    without photon counts)."""
    from .datasheet import emva_figures

    if not run.emva1288:
        return
    no_photons = all(r.photons is None for r in run.session.by_role("ptc"))
    if "emva1288" not in run.lacking and no_photons:
        run.skipped.append(Skipped("emva1288", "not-applicable", "the ptc frames have no photon "
                                   "counts: the EMVA 1288 figures need the photons per pixel of "
                                   "each bright frame (open an EMVA1288 descriptor, or give "
                                   "photons = N in the manifest)", ("ptc",)))
    else:
        run.attempt("emva1288", (), lambda: emva_figures(run.session, noise=run.made.get("noise"),
                                                         with_ptc=False))


def _dark_reference(run: _Run) -> None:
    """``dark`` frames of a mono camera: D̂_D with hot/dead flags, at the fixed-pattern frames'
    exposure when the darks have several."""
    from .darkframe import dark_reference

    session = run.session
    if session.roles().get("dark") and session.camera.layout != Layout.MONO:
        run.skipped.append(Skipped("dark", "not-applicable", f"{session.camera.layout} camera: "
                                   "the dark reference D̂_D of sec. V-A is made for mono frames; "
                                   "the flat-field DL_0 serves instead"))
        return

    def make() -> DarkReference:
        exposure, note = dark_exposure_for(session, run.dark_exposure)
        ref = dark_reference(session, exposure=exposure, reducer=run.reducer)
        return replace(ref, notes=(note, *ref.notes)) if note else ref
    run.attempt("dark", (), make)


#: the roles whose exposure the dark reference is matched to, in order of preference
_DARK_MATCH_ROLES = ("fixed_pattern", "flat", "ptc")


def dark_exposure_for(session: Session, named: float | None = None
                      ) -> tuple[float | None, str | None]:
    """The exposure of the dark frames the dark reference (and its hot and dead pixel maps) is
    made from, and a note saying why: ``named`` when given; with darks at one exposure, that
    one; else the one nearest (in ratio) the median exposure of the fixed-pattern frames, else
    of the flats, else of the ptc frames (an EMVA 1288 set: the bright frames, whose spatial
    set dominates the median); with none of those, the exposure with the most dark frames."""
    from .darkframe import exposures_text, nearest_exposure

    darks = [r.exposure for r in session.dark_frames() if r.exposure is not None]
    have = sorted(set(darks))
    if named is not None:
        return float(named), (f"dark frames at {exposures_text(have)}: the dark reference is "
                              f"made at {named:g} s, as named" if len(have) > 1 else None)
    if len(have) <= 1:
        return None, None
    for role in _DARK_MATCH_ROLES:
        times = [r.exposure for r in session.by_role(role) if r.exposure is not None]
        if times:
            target = float(np.median(times))
            chosen = nearest_exposure(have, target)
            return chosen, (f"dark frames at {exposures_text(have)}: the dark reference is made "
                            f"at {chosen:g} s, the nearest to the {role.replace('_', '-')} "
                            f"frames' median exposure {target:g} s (name another with "
                            "--dark-exposure)")
    counts = {t: darks.count(t) for t in have}
    chosen = max(have, key=lambda t: (counts[t], t))
    return chosen, (f"dark frames at {exposures_text(have)}: the dark reference is made at "
                    f"{chosen:g} s, the exposure with the most dark frames ({counts[chosen]}; "
                    "name another with --dark-exposure)")


def _fixed_pattern(run: _Run) -> None:
    """``fixed_pattern`` configurations and D̂_D: K̂."""
    from .fixedpattern import fixed_pattern_map

    run.attempt("fixed_pattern", ("dark",),
                lambda: fixed_pattern_map(run.session, run.made["dark"], window=run.window,
                                          p=run.p, reducer=run.reducer))


def _plan(run: _Run) -> None:
    """The noise model and K̂: the acquisition plan n1, n2 (needs the camera's bit depth)."""
    from .planning import plan_acquisition

    def make() -> AcquisitionPlan:
        if not run.session.camera.bits:
            raise CcdError("camera.bits", "the plan needs the camera bit depth")
        return plan_acquisition(run.made["noise"], bits=run.session.camera.bits,
                                fixed_pattern=run.made["fixed_pattern"])
    run.attempt("plan", ("noise", "fixed_pattern"), make)


def _correction_check(run: _Run) -> None:
    """A ``max-intensity`` scene frame, D̂_D and K̂: the check of eq. 51."""
    from .fixedpattern import correction_check

    def make() -> CorrectionCheck:
        rec = run.session.max_intensity_frame()
        assert rec is not None  # missing_frames checked the flag
        return correction_check(run.session.read(rec), run.made["dark"],
                                run.made["fixed_pattern"])
    run.attempt("correction_check", ("dark", "fixed_pattern"), make)


def _scene_variation(run: _Run) -> None:
    """``scene`` patches, the noise model, D̂_D and K̂: V_S with the maps' own errors."""
    from .scene import scene_variations

    made = run.made
    run.attempt("scene", ("noise", "dark", "fixed_pattern"),
                lambda: scene_variations(run.session, made["dark"], made["fixed_pattern"],
                                         made["noise"], **scene_error_terms(
                                             made["dark"], made["fixed_pattern"])))


def _flat_field(run: _Run) -> None:
    """``flat`` frames and darks: the G/O maps."""
    from .flatfield import flat_field_from_session

    run.attempt("flat_field", (), lambda: flat_field_from_session(run.session, base="auto",
                                                                  reducer=run.reducer))


def _response(run: _Run) -> None:
    """A ``bracket``: the inverse response g and the noise terms."""
    from .response.methods import session_response

    if run.response:
        run.attempt("response", (), lambda: session_response(run.session))


#: the function of each step of :data:`ESTIMATE_STEPS` (but ``done``), in that order
_STEPS: tuple[tuple[str, Callable[[_Run], None]], ...] = (
    ("photon transfer", _photon_transfer), ("EMVA 1288 figures", _emva_figures),
    ("dark reference", _dark_reference), ("fixed pattern", _fixed_pattern),
    ("planning", _plan), ("correction check", _correction_check),
    ("scene variation", _scene_variation), ("flat field", _flat_field),
    ("response", _response))


def estimate_all(session: Session, *, roi: tuple[int, int, int, int] | None = None,
                 window: int = 9, p: float = 1.5, noise: PhotonTransfer | None = None,
                 progress: Progress | None = None, response: bool = True,
                 emva1288: bool = True, reducer: Reducer | None = None,
                 dark_exposure: float | None = None) -> Estimates:
    """Every estimate the session's frames allow (see :func:`calibrate`).

    An estimate whose frames are missing, or whose frames the method refuses (a
    :class:`CcdError`, e.g. one fixed-pattern configuration where eq. 49 needs several), is
    skipped and listed in :attr:`Estimates.skipped` with its reason; the others are still made.
    ``noise`` may pass an already computed photon-transfer result (e.g. with levels the user
    excluded in the app) instead of computing it here; ``response=False`` leaves the response
    of a bracket out, ``emva1288=False`` the EMVA 1288 figures (their steps are then empty).
    The EMVA 1288 figures need photon counts: a session whose ptc frames have none skips them
    as ``not-applicable``.
    ``progress`` (a :class:`ccdcore.progress.Progress`) gets ``progress(start, name)`` as each
    of :data:`ESTIMATE_STEPS` starts; each step is one function (``_STEPS``).

    ``reducer`` (:mod:`ccdcore.reduce`; default streamed here) runs the reductions over frames
    of the photon transfer, the dark reference, K̂ and the flat field; a
    :class:`ccdcore.distributed.DaskReducer` runs them on a Dask cluster
    (``docs/distributed.md`` says what is not distributed yet).
    """
    run = _Run(session, roi=roi, window=window, p=p, noise=noise, response=response,
               emva1288=emva1288, reducer=reducer or STREAMED, dark_exposure=dark_exposure)
    report = Steps(progress, ESTIMATE_STEPS)
    for step, make in _STEPS:
        report(step)
        make(run)
    result = run.estimates()
    report("done")
    return result


def _damaged_maps(name: str, result: Any) -> str | None:
    """What makes the maps of estimate ``name`` unusable in a product (:func:`map_problem`),
    e.g. all-NaN darks (a non-finite K̂ everywhere) or a single dark frame (no variance)."""
    if name == "dark":
        maps = {MapName.DARK: result.mean_map, MapName.DARK_VAR: result.var_map}
    elif name == "fixed_pattern":
        maps = {MapName.K: result.K, MapName.K_VAR: result.K_var}
    elif name == "flat_field":
        maps = result.maps()
    else:
        return None
    for map_name, m in maps.items():
        if m is not None and (problem := map_problem(map_name, m)) is not None:
            return problem
    return None


def calibrate(session_or_path: Session | str | os.PathLike, *,
              roi: tuple[int, int, int, int] | None = None, window: int = 9, p: float = 1.5,
              progress: Progress | None = None,
              noise: PhotonTransfer | None = None, reducer: Reducer | None = None,
              dark_exposure: float | None = None) -> CalibrationProduct:
    """Run every estimate the session's frames allow.

    - ``ptc`` levels: photon transfer (eqs. 37–42, 59–67), over ``roi`` when given;
    - ``dark`` frames: dark reference D̂_D with hot/dead flags (sec. V-A); with darks at
      several exposures, from those at ``dark_exposure`` or at the one nearest the other
      frames' (:func:`dark_exposure_for`);
    - ``fixed_pattern`` configurations and darks: K̂ (eqs. 45–50, ``window``, ``p``);
    - noise model and K̂: acquisition plan n1, n2 (sec. V-B), with warnings if the session has
      fewer frames;
    - a ``max-intensity`` scene frame: the correction check (sec. VII-A);
    - ``scene`` frames with patches/ROIs, K̂ and the noise model: scene variation V_S (sec. VI);
    - ``flat`` frames and darks: flat-field G/O maps (de Lasarte et al. 2007);
    - a ``bracket``: the inverse response g per channel with its band and the noise terms
      (Tsin et al. 2001, sec. 3.2), for :func:`apply_product` (``linearise``) and the HDR merge.

    ``noise`` passes a photon-transfer result already made (e.g. with levels left out or the
    robust mode, as the app's Walkthrough chooses) instead of estimating it here.

    - ``ptc`` frames with photon counts (an EMVA1288 descriptor) and dark frames: the EMVA 1288
      figures (:func:`ccdcore.datasheet.emva_figures`), in :attr:`CalibrationProduct.emva1288`.

    The product holds every estimate that could be made; each one that could not is listed in
    :attr:`CalibrationProduct.skipped` with its reason (missing frames, or frames the method
    refused).  The provenance records the session's content hash, the date (UTC) and the
    ``scheduler`` the reductions ran on: ``"streamed (this process)"``, or with a Dask
    ``reducer`` (see :func:`estimate_all`) the scheduler's address and its number of workers.

    Raises
    ------
    CcdError
        The session has errors (every error is listed), or no estimate at all could be made
        ("nothing to calibrate", naming the roles that would be needed).
    """
    session = session_or_path if isinstance(session_or_path, Session) \
        else open_session(session_or_path)
    session.raise_if_invalid()
    e = estimate_all(session, roi=roi, window=window, p=p, progress=progress, noise=noise,
                     reducer=reducer, dark_exposure=dark_exposure)
    if not e.made:
        failed = [s for s in e.skipped if s.code == "failed"]
        why = "; ".join(f"{s.estimate}: {s.reason}" for s in failed) if failed else (
            "the session has none of the frames an estimate needs: " + "; ".join(
                f"{req.estimate} needs {'/'.join(req.roles)}" for req in REQUIREMENTS))
        raise CcdError(session.label, f"nothing to calibrate ({why})")
    maps: dict[str, np.ndarray] = {}
    est: dict[str, JsonDict] = {}
    steps: dict[str, JsonDict] = {}
    if e.noise is not None:
        est["noise"] = e.noise.to_dict()
        steps["noise"] = {"method": "photon transfer, Healey & Kondepudy 1994 eqs. 37-42, 59-67",
                          "roi": list(roi) if roi else None}
    if e.dark is not None:
        dark = e.dark
        maps[MapName.DARK] = dark.mean_map.astype(np.float32)
        maps[MapName.DARK_VAR] = dark.var_map.astype(np.float32)
        maps[MapName.HOT] = dark.hot_mask.astype(np.float32)
        maps[MapName.DEAD] = dark.dead_mask.astype(np.float32)
        est["dark"] = dark.to_dict()
        steps["dark"] = {"method": "streamed average, sec. V-A", "s": dark.s,
                         "hot_rule": dark.hot_rule, "dead_rule": dark.dead_rule}
    if e.fixed_pattern is not None:
        fp = e.fixed_pattern
        maps[MapName.K] = fp.K.astype(np.float32)
        maps[MapName.K_VAR] = fp.K_var.astype(np.float32)
        maps[MapName.N1_USED] = fp.n1_used.astype(np.float32)
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
    if e.response is not None:
        est["response"] = {k: v for k, v in e.response.to_dict().items() if k != "files"}
        steps["response"] = {"method": "Tsin, Ramesh & Kanade 2001 sec. 3.2 (instrumented "
                                       "pools), nominal exposures",
                             "bloom_radius": e.response.bloom_radius,
                             "files": list(e.response.files)}
    if e.scene is not None:
        est["scene"] = {name: v.to_dict() for name, v in e.scene.items()}
        steps["scene"] = {"method": "eqs. 53-58, sec. VI, with the calibration maps' errors"}
    emva = None
    if e.emva1288 is not None:
        from .datasheet import LINEARITY_RANGE, SENSITIVITY_FRACTION, SIGMA2_Y_DARK_FLOOR

        emva = json_safe(e.emva1288.to_dict())
        steps["emva1288"] = {"method": "EMVA 1288 release 3.1 as the emva1288 1.0.2 package "
                                       "computes it (Results1288); errors and sigma_d_ptc by "
                                       "ccdcore", "sensitivity_fraction": SENSITIVITY_FRACTION,
                             "linearity_range": list(LINEARITY_RANGE),
                             "sigma2_y_dark_floor": SIGMA2_Y_DARK_FLOOR}
    provenance = {"ccdcore": __version__, "session": session.label,
                  "source": session.source, "n_frames": len(session.frames),
                  "session_hash": session.content_hash(),
                  "date": datetime.datetime.now(datetime.timezone.utc).isoformat(
                      timespec="seconds"),
                  "scheduler": (reducer or STREAMED).description, "steps": steps}
    return CalibrationProduct(maps=maps, estimates=json_safe(est), camera=session.camera,
                              provenance=json_safe(provenance), skipped=e.skipped,
                              warnings=e.plan_warnings, emva1288=emva)


def session_inputs(session: Session) -> list[Path]:
    """The files a run over ``session`` reads, which no output of the run may overwrite: its
    frames, its manifest, and a simulation's ``truth.json`` with the true maps it names."""
    files = [Path(r.path) for r in session.frames]
    if session.manifest_path is not None:
        files.append(Path(session.manifest_path))
    truth = Path(session.root) / "truth.json"
    if truth.is_file():
        files.append(truth)
        with contextlib.suppress(OSError, ValueError, AttributeError, TypeError):
            maps = json.loads(truth.read_text(encoding="utf-8")).get("maps") or {}
            files += [Path(session.root) / str(rel) for rel in maps.values()]
    return files


# ---------------------------------------------------------------------------------------------
def _output_name(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in FITS_EXTENSIONS or suffix in (".tif", ".tiff", ".exr"):
        return path.name
    return path.stem + ".tif"


#: compressions :func:`apply_product` offers for TIFF and EXR outputs (OpenImageIO names)
COMPRESSIONS = ("none", "zip")


def apply_product(product: CalibrationProduct | str | os.PathLike,
                  images: Iterable[str | os.PathLike], out_dir: str | os.PathLike, *,
                  compression: str = "none", linearise: bool = False) -> list[Path]:
    """Correct each image with the product (eq. 51) into ``out_dir`` as float32.

    Output keeps the base name; TIFF, EXR and FITS keep their format, others become ``.tif``
    (float32 cannot be stored in PNG/PNM). Inputs are never modified; an output that would
    overwrite an input is refused, and so is one inside the product folder or over a FIFO or a
    device. The images are written as one set (:func:`ccdcore.io.output_set`): a failure or
    SIGTERM leaves the earlier outputs of ``out_dir`` as they were.

    ``compression`` (one of :data:`COMPRESSIONS`) applies to TIFF and EXR outputs: ``"none"`` by
    default, because deflating float32 noise saves about a quarter of the size at ten times the
    write time (6x on 2048² frames, benchmarks/bench_apply.py); ``"zip"`` when disk space
    matters more.

    ``linearise`` maps each image's codes through the product's inverse response g instead
    (:meth:`CalibrationProduct.linearise`): values linear in exposure.
    """
    inputs = [Path(p) for p in images]
    if not isinstance(product, CalibrationProduct):
        given = Path(product)
        inputs.append(given if given.is_dir() else given.parent)
        product = load_product(product)
    if linearise:
        product.response_models()          # a clear error before anything is read
    out_dir = Path(out_dir)
    images = [Path(p) for p in images]
    if not images:
        raise CcdError("images", "no images given")
    if compression not in COMPRESSIONS:
        raise CcdError("compression", f"unknown compression {compression!r}; choose one of "
                                      f"{', '.join(COMPRESSIONS)}")
    targets = [out_dir / _output_name(p) for p in images]
    seen: dict[Path, Path] = {}
    for src, dst in zip(images, targets):
        if dst.resolve() == src.resolve():
            raise CcdError(src, "the output would overwrite the input; choose another -o folder")
        if dst in seen:
            raise CcdError(src, f"has the same output name as {seen[dst]}")
        seen[dst] = src
    check_outputs(out_dir, [t.name for t in targets], inputs)   # before anything is read
    shape = None if linearise else product.shape
    for src in images:  # check every header before writing anything
        header = read_header(src)
        if shape is not None and header.shape != shape:
            raise CcdError(src, f"image shape {header.shape} differs from the calibration "
                                f"maps' {shape}")
    with output_set(out_dir, inputs=inputs) as tmp:   # all images as one set, or none
        for src, dst in zip(images, targets):
            attrs = ({"compression": compression}
                     if dst.suffix.lower() in (".tif", ".tiff", ".exr") else None)
            data, header = read_frame(src)
            fix = product.linearise if linearise else product.correct
            write_image(tmp / dst.name, fix(data, name=str(src)), attributes=attrs,
                        exposure=header.exposure)
    return targets
