"""Plain folders of images without a manifest: roles from folder names, metadata from headers.

``dark/``, ``darks/``, ``bias/`` ... hold dark frames, ``ptc/`` photon-transfer pairs (a level per
sub-folder ``ptc/L03/`` or per file name number ``ptc/L03_a.tif``), ``flats/`` flat fields and so on
(:data:`ROLE_SYNONYMS`); images at the top level are scenes.  Exposures, gains and temperatures come
from EXIF/FITS headers.  The session carries a warning saying what was inferred, and
:meth:`~ccdcore.session.Session.to_toml` writes it out as a manifest draft to review.
"""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path, PurePosixPath
from typing import Any

from ..channels import LAYOUTS
from ..io import IMAGE_EXTENSIONS
from .assemble import Candidate, assemble
from .records import MANIFEST_NAME, ROLES, Camera, Problem, Session

__all__ = ["ROLE_SYNONYMS", "open_folder"]

#: folder name (lower case) -> role, for plain folders without a manifest
ROLE_SYNONYMS: dict[str, str] = {
    **{r: r for r in ROLES},
    "darks": "dark", "bias": "dark", "biases": "dark", "black": "dark", "offset": "dark",
    "ptcs": "ptc", "pairs": "ptc", "photon_transfer": "ptc", "photon-transfer": "ptc",
    "fixed-pattern": "fixed_pattern", "fixedpattern": "fixed_pattern", "fpn": "fixed_pattern",
    "prnu": "fixed_pattern",
    "flats": "flat", "flatfield": "flat", "flatfields": "flat", "flat_field": "flat",
    "flat-field": "flat", "flat_fields": "flat", "white": "flat",
    "brackets": "bracket", "hdr": "bracket", "exposures": "bracket",
    "scenes": "scene", "images": "scene",
    "references": "reference", "ref": "reference", "background": "reference",
    "targets": "target", "test": "target",
}

#: the id key a plain folder's frames of a role get from their sub-folder or file name
_ID_KEYS = {"ptc": "level", "fixed_pattern": "config"}


def _subfolder_ids(names: list[str]) -> dict[str, int]:
    """Number sub-folders: by the integer in each name when those are distinct, else 1, 2, ..."""
    nums = {}
    for name in names:
        found = re.findall(r"\d+", name)
        nums[name] = int(found[-1]) if found else None
    if None not in nums.values() and len(set(nums.values())) == len(names):
        return nums  # type: ignore[return-value]
    return {name: i for i, name in enumerate(sorted(names), start=1)}


def _folder_images(root: Path) -> list[str]:
    out = []
    for p in root.rglob("*"):
        rel = p.relative_to(root)
        if (p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()
                and not any(part.startswith(".") for part in rel.parts)):
            out.append(rel.as_posix())
    return sorted(out)


def open_folder(folder: Path) -> Session:
    root = folder.resolve()
    problems: list[Problem] = []
    candidates: list[Candidate] = []
    relpaths = _folder_images(root)
    # role from the first path component; ptc level / fixed_pattern config from the sub-folder
    # (ptc/L03/a.tif) or else from the first number of the file name (ptc/L03_a.tif)
    sub: dict[str, list[str]] = {}
    roles: dict[str, str] = {}
    for rel in relpaths:
        parts = rel.split("/")
        roles[rel] = ROLE_SYNONYMS.get(parts[0].lower(), "scene") if len(parts) > 1 else "scene"
        if roles[rel] in _ID_KEYS and len(parts) > 2:
            sub.setdefault(roles[rel], []).append(parts[1])
    ids = {role: _subfolder_ids(sorted(set(names))) for role, names in sub.items()}
    for rel in relpaths:
        role, parts = roles[rel], rel.split("/")
        meta: dict[str, Any] = {}
        inferred = ["role"]
        if role in _ID_KEYS:
            number = re.search(r"\d+", PurePosixPath(rel).stem)
            value = ids[role][parts[1]] if len(parts) > 2 else (
                int(number.group()) if number else None)
            if value is not None:
                meta[_ID_KEYS[role]] = value
                inferred.append(_ID_KEYS[role])
        candidates.append(Candidate(rel, rel, role, meta, tuple(inferred)))

    session = assemble(root, None, "folder", Camera(name=root.name), candidates, problems)
    headers = [session.header_or_none(r) for r in session.frames]
    headers = [h for h in headers if h is not None]
    bits = max((h.bits for h in headers if h.dtype.kind in "ui"), default=None)
    layouts = {h.layout for h in headers}
    layout = layouts.pop() if len(layouts) == 1 else "mono"
    if layout not in LAYOUTS:
        layout = "rgb" if layout == "rgba" else "mono"
    camera = Camera(name=root.name, bits=bits, layout=layout)

    n_exp = sum("exposure" in r.inferred for r in session.frames)
    summary = ", ".join(f"{role}: {n}" for role, n in session.roles().items())
    if relpaths:
        note = (f"no {MANIFEST_NAME}: roles inferred from folder names ({summary}), exposures "
                f"from file headers for {n_exp} of {len(relpaths)} frames, camera bits = {bits}, "
                f"layout = {layout}; check them, write a manifest draft with `ccdcore session FOLDER --draft` and save it as "
                f"{MANIFEST_NAME}")
        extra = [Problem(str(root), note, "warning", code="folder-inferred")]
    else:
        extra = [Problem(str(root), f"no image files found (looked for "
                                    f"{', '.join(sorted(IMAGE_EXTENSIONS))})", code="no-frames")]
    return dataclasses.replace(session, camera=camera,
                               problems=tuple(extra) + session.problems)
