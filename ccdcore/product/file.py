"""The calibration product as a file: :class:`CalibrationProduct` (its maps, estimates, camera
and provenance), its folder format (``calibration.json`` + ``maps/<name>.exr``), written
atomically by :meth:`CalibrationProduct.save` and read back, checked, by :func:`load_product`.

Every name here is re-exported by :mod:`ccdcore.product.make`, its usual address, which makes the
products (:func:`ccdcore.product.make.calibrate`) and applies them.

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
from typing import TYPE_CHECKING, Any, Iterable, Mapping, Union

import numpy as np

from ..errors import CcdError
from ..io.frames import (atomic_write_text, output_set, read_image, remove_stale_temporaries,
                         write_map)
from ..emva.results import EmvaSummary
from ..map_names import MapName
from .records import ProductEstimates, Provenance
from ..session import Camera

if TYPE_CHECKING:
    from ..response.hdr import ResponseModel

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
        The summary record of each estimate made (:class:`ProductEstimates`): ``noise``
        (photon transfer), ``dark``, ``fixed_pattern``, ``plan``, ``correction_check``,
        ``flat_field``, ``response``, ``scene``; ``None`` where not made.
    camera
        The session's camera.
    provenance
        :class:`Provenance`: the ``ccdcore`` version, the session (its label, ``source``,
        ``n_frames`` and ``session_hash``, the SHA-256 of
        :meth:`~ccdcore.session.Session.content_hash`), the ``date`` of the calibration (UTC,
        ISO 8601), the ``scheduler``, and per step its parameters (:class:`ProductSteps`).  Products
        of earlier releases have no ``session_hash`` nor ``date``.
    skipped
        Every estimate that was not made, with its reason.
    warnings
        What the session lacks against the acquisition plan (fewer configurations or frames).
    notes
        Remarks on the product as a whole; each estimate keeps its own notes (products of the
        first release kept their skip reasons and plan warnings here).
    emva1288
        The EMVA 1288 figures (:class:`ccdcore.emva.results.EmvaSummary`, the top-level key
        ``"emva1288"`` of ``calibration.json``), or ``None`` when the session has no photon
        counts (the key is then absent).
    frames
        Map name -> the relative paths of the session frames it was made from (the top-level
        key ``"frames"`` of ``calibration.json``, one list per map; absent in products of
        earlier releases).

    Every field is typed: JSON happens only in :meth:`to_dict` and :func:`load_product`.
    """

    maps: dict[MapName, np.ndarray]
    estimates: ProductEstimates = field(default_factory=ProductEstimates)
    camera: Camera = field(default_factory=Camera)
    provenance: Provenance = field(default_factory=Provenance)
    skipped: tuple[Skipped, ...] = ()
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    emva1288: EmvaSummary | None = None
    frames: dict[str, tuple[str, ...]] = field(default_factory=dict)

    # -------------------------------------------------------------------------------------
    def to_dict(self) -> JsonDict:
        """The content of ``calibration.json`` (maps by file name; ``emva1288`` when made)."""
        out: JsonDict = {"schema": PRODUCT_SCHEMA, "camera": self.camera.to_dict(),
                         "maps": {name: f"maps/{name}.exr" for name in sorted(self.maps)},
                         "estimates": self.estimates.to_dict()}
        if self.emva1288 is not None:
            out["emva1288"] = self.emva1288.to_dict()
        if self.frames:
            out["frames"] = {name: list(self.frames[name]) for name in sorted(self.frames)}
        out.update({"skipped": [s.to_dict() for s in self.skipped],
                    "provenance": self.provenance.to_dict(), "warnings": list(self.warnings),
                    "notes": list(self.notes)})
        return out

    def save(self, folder: str | os.PathLike, *,
             inputs: Iterable[str | os.PathLike] = ()) -> Path:
        """Write ``calibration.json`` and the maps into ``folder`` atomically; return the folder.

        Everything is written into a temporary folder first (:func:`ccdcore.io.frames.output_set`),
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
        doc = self.to_dict()
        text = json.dumps(doc, indent=2, allow_nan=False)
        _records_of(json.loads(text), folder / PRODUCT_FILE)     # nor a description it refuses
        with output_set(folder, inputs=inputs, last=PRODUCT_FILE,
                        replaces=(PRODUCT_FILE, "maps")) as tmp:
            for name, m in self.maps.items():
                write_map(tmp / "maps" / f"{name}.exr", m)
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

    def response_models(self, where: Any = PRODUCT_FILE) -> dict[str, ResponseModel]:
        """Channel -> :class:`ccdcore.response.hdr.ResponseModel` from the ``response``
        estimate (g per code, nominal a_k, b_k, noise terms), checked: a clear error names
        ``where`` when the product has no response or a damaged one."""
        if self.estimates.response is None:
            raise CcdError(where, "the calibration product has no response curve: calibrate "
                                  "a session with an exposure bracket (role = bracket)")
        return self.estimates.response.models(where)

    def linearise(self, frame: np.ndarray, *, name: str | None = None) -> np.ndarray:
        """Codes mapped through the inverse response g of each channel (float32, on g's
        reported scale: linear in exposure, 0.9 at the code 90 % up the range)."""
        from ..channels import channel_slices

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
            from ..flatfield.fit import correct as flat_correct

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
# the folder: validation on load (writing goes through ccdcore.io.frames.output_set)
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


def _records_of(doc: Mapping[str, Any], manifest: Path
                ) -> tuple[ProductEstimates, Provenance, EmvaSummary | None]:
    """The estimates, the provenance and the EMVA 1288 figures of a product description,
    every value checked against its record's types (one error naming ``manifest`` and the
    key's path)."""
    estimates = doc.get("estimates", {})
    if not all(isinstance(v, dict) for v in estimates.values()):
        raise CcdError(manifest, "every entry of 'estimates' must be an object")
    emva = doc.get("emva1288")
    if emva is not None and not isinstance(emva, dict):
        raise CcdError(manifest, "'emva1288' must be a JSON object")
    return (ProductEstimates.from_dict(estimates, manifest, "estimates"),
            Provenance.from_dict(doc.get("provenance", {}), manifest, "provenance"),
            None if emva is None else EmvaSummary.from_dict(emva, manifest, "emva1288"))


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

    Parameters
    ----------
    folder : str or os.PathLike
        The product folder, or its description file (``calibration.json``) itself.

    Returns
    -------
    CalibrationProduct
        The product as saved: its maps, the summaries of its estimates, the camera, the
        provenance, the estimates skipped, its warnings and notes, the EMVA 1288 figures and the
        frames of each map.

    Raises
    ------
    CcdError
        Not a product, or a damaged one (the message names the file and the problem).

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> from ccdcore.product import calibrate
    >>> _ = simulate("healey94", tmp.name, seed=1, size=(64, 48))
    >>> folder = calibrate(tmp.name).save(tmp.name + "/calib")
    >>> product = load_product(folder)
    >>> product.camera.bits, product.shape
    (8, (48, 64))
    >>> tmp.cleanup()
    """
    folder = Path(folder)
    manifest = folder / PRODUCT_FILE if folder.is_dir() else folder
    if not manifest.is_file():
        raise CcdError(folder, f"not a calibration product (no {PRODUCT_FILE})")
    root = manifest.parent
    def not_json(constant: str) -> None:
        # a product writes a figure it cannot state as null, never as NaN or Infinity
        raise ValueError(f"{constant} is not a number a product holds (a value it cannot "
                         "state is null): a damaged or hand-edited product")

    try:
        doc = json.loads(manifest.read_bytes().decode("utf-8-sig"), parse_constant=not_json)
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
    made, provenance, figures = _records_of(doc, manifest)
    frames = doc.get("frames", {})
    if not (isinstance(frames, dict) and all(
            isinstance(v, list) and all(isinstance(x, str) for x in v) for v in frames.values())):
        raise CcdError(manifest, "'frames' must map each map name to a list of relative paths")
    try:
        skipped = tuple(Skipped.from_dict(d) for d in doc.get("skipped", ()))
    except (KeyError, TypeError, AttributeError):
        raise CcdError(manifest, "'skipped' entries need 'estimate' and 'reason'") from None
    maps: dict[MapName, np.ndarray] = {}
    for raw_name, rel in doc.get("maps", {}).items():
        name = _map_name(raw_name, manifest)
        if not isinstance(rel, str):
            raise CcdError(manifest, f"map '{name}' must be a relative path, got {rel!r}")
        path = (root / rel).resolve()
        if root.resolve() not in path.parents:
            raise CcdError(manifest, f"map '{name}' points outside the product folder: {rel}")
        maps[name] = read_image(path)
    _check_maps(maps, manifest)
    return CalibrationProduct(maps=maps, estimates=made,
                              camera=_camera_from(doc.get("camera", {}), manifest),
                              provenance=provenance, skipped=skipped,
                              warnings=tuple(str(n) for n in doc.get("warnings", ())),
                              notes=tuple(str(n) for n in doc.get("notes", ())),
                              emva1288=figures,
                              frames={str(k): tuple(v) for k, v in frames.items()})
