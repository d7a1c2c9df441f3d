"""The calibration product as a file: :class:`CalibrationProduct` (its maps, estimates, camera
and provenance), its folder format (``calibration.json`` + ``maps/<name>.exr``), written
atomically by :meth:`CalibrationProduct.save` and read back, checked, by :func:`load_product`.

Every name here is re-exported by :mod:`ccdcore.product`, its usual address, which makes the
products (:func:`ccdcore.product.calibrate`) and applies them.

Public objects
--------------
CalibrationProduct, Skipped
    The product and an estimate it could not make, with the reason.
load_product(folder), map_problem(name, map)
    A product folder read back and checked; what is wrong with a map, if anything.
PRODUCT_FILE, PRODUCT_SCHEMA, JsonDict, JsonValue
    The description's file name and schema; the JSON types of its values.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Union

import numpy as np

from .errors import CcdError
from .io import atomic_write_text, output_set, read_image, remove_stale_temporaries, write_map
from .map_names import MapName
from .session import Camera

__all__ = ["CalibrationProduct", "Skipped", "load_product", "map_problem", "PRODUCT_FILE",
           "PRODUCT_SCHEMA", "JsonDict", "JsonValue"]


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
