"""Capture sessions: the ``session.toml`` manifest, plain folders, EMVA1288 descriptors.

A session is a folder of image files plus a manifest saying what each frame is for (its *role*:
dark frames, photon-transfer pairs, fixed-pattern configurations, flat fields, exposure brackets,
scenes, change-detection reference/target brackets) and its capture metadata (exposure, gain,
level, configuration, offset setting, scene patch, temperature ...).  ``docs/session.md`` gives
the manifest format.  Opening a session never reads pixels: it reads every file's header once
(cached) to validate the session and to fill in metadata the manifest leaves out (EXIF
``ExposureTime``, FITS ``EXPTIME``/``GAIN``/``CCD-TEMP``).  Pixels are read one frame at a time by
:meth:`Session.read` and :meth:`Session.iter_frames`, so a thousand-frame session never sits in
memory.

Validation reports every problem at once in :attr:`Session.problems` (each naming the file or the
manifest entry, with a ``code`` and the ``roles`` it touches) instead of stopping at the first;
:meth:`Session.raise_if_invalid` turns the errors into one :class:`~ccdcore.errors.SessionError`.

Modules
-------
:mod:`~ccdcore.session.records`
    :class:`Camera`, :class:`FrameRecord`, :class:`Problem`, :class:`Session` and its frame
    queries (levels, configurations, flat/dark groups by setting and gain, patches, flags).
:mod:`~ccdcore.session.assemble`
    Candidates from any source -> checked records (paths, headers, cross-frame checks).
:mod:`~ccdcore.session.manifest`, :mod:`~ccdcore.session.folder`, :mod:`~ccdcore.session.emva`
    The three sources: ``session.toml``, a plain folder of images, an EMVA1288 descriptor.

Public objects
--------------
ROLES, LAYOUTS, FLAGS, MAX_INTENSITY, ROLE_SYNONYMS
    Frame roles, camera colour layouts, frame flags, folder names recognised as roles.
Camera, FrameRecord, Problem, Session
    The records (see :mod:`~ccdcore.session.records`).
ProblemCode
    The codes of validation problems (a ``str`` enum), each with its fix (``.fix``).
open_session(path)
    Open a session folder, a ``session.toml``, a plain folder of images or an EMVA1288 descriptor.
draft_manifest(session, path=None)
    Write a manifest draft (``session.toml.draft``) for a session, e.g. one opened from a folder.
"""
from __future__ import annotations

from pathlib import Path

from ..errors import CcdError
from ..io.frames import atomic_write_text
from .emva import open_emva_descriptor
from .folder import ROLE_SYNONYMS, open_folder
from .manifest import open_manifest
from .records import (DRAFT_NAME, FLAGS, LAYOUTS, MANIFEST_NAME, MAX_INTENSITY, ROLES, SCHEMA,
                      Camera, FrameRecord, Problem, ProblemCode, Session)

__all__ = ["ROLES", "LAYOUTS", "FLAGS", "MAX_INTENSITY", "ROLE_SYNONYMS", "Camera", "FrameRecord",
           "Problem", "ProblemCode", "Session", "open_session", "open_emva_descriptor",
           "draft_manifest", "MANIFEST_NAME", "DRAFT_NAME", "SCHEMA"]


def _is_emva_descriptor(path: Path) -> bool:
    """True when the first non-comment, non-blank line of ``path`` starts with ``v`` (read line
    by line: a descriptor may open with any amount of comments; at most
    :data:`ccdcore.session.emva.MAX_DESCRIPTOR_BYTES` are read looking for it)."""
    from .emva import MAX_DESCRIPTOR_BYTES

    try:
        with path.open("r", encoding="utf-8", errors="replace") as f:
            read = 0
            for line in f:
                read += len(line)
                if read > MAX_DESCRIPTOR_BYTES:
                    return False
                line = line.strip()
                if line and not line.startswith("#"):
                    return line.split()[0] == "v"
    except OSError:
        return False
    return False


def open_session(path: str | Path, *, check_pixels: bool = False,
                 role: str | None = None) -> Session:
    """Open a capture session.

    Parameters
    ----------
    path : str or Path
        A session folder holding ``session.toml``; a manifest file (``*.toml``); a plain folder of
        images (no manifest: roles from folder names, metadata from headers); or an EMVA1288
        descriptor file (``v``/``n``/``b``/``d``/``i`` lines, see :mod:`ccdcore.session.emva`).
    check_pixels : bool, optional
        Also decode every frame once (streamed) to find truncated or corrupt pixel data, see
        :meth:`Session.verify_pixels`.  By default only headers are read.
    role : str or None, optional
        For a plain folder of images only: every image takes this role (e.g. ``"flat"`` for a
        camera's flat fields named as the camera named them), see
        :func:`~ccdcore.session.folder.open_folder`.  Refused for a manifest or a descriptor,
        whose roles are written in them.

    Returns
    -------
    Session
        The session: its camera and its frame records by role.  Validation problems are in
        :attr:`Session.problems`; nothing is raised for them.

    Raises
    ------
    CcdError
        The path does not exist, is not a folder, manifest or descriptor (a FIFO or another
        special file included); the manifest or descriptor cannot be read, or the manifest is
        not valid TOML (the message gives the line); ``role`` is given for a manifest or a
        descriptor, or is not a known role.

    Examples
    --------
    >>> import tempfile
    >>> from ccdcore.simulate import simulate
    >>> tmp = tempfile.TemporaryDirectory()
    >>> _ = simulate("healey94", tmp.name, seed=1, size=(64, 48))
    >>> session = open_session(tmp.name)
    >>> session.ok, session.roles()
    (True, {'dark': 16, 'ptc': 16, 'fixed_pattern': 48, 'scene': 16})
    >>> session.camera.bits, session.camera.layout
    (8, 'mono')
    >>> tmp.cleanup()
    """
    p = Path(path)
    if not p.exists():
        raise CcdError(p, "does not exist")
    if not p.is_dir() and not p.is_file():  # opening a FIFO to sniff it would block forever
        raise CcdError(p, "is a FIFO/special file, not a folder, session.toml or descriptor")
    if role is not None and not (p.is_dir() and not (p / MANIFEST_NAME).exists()):
        raise CcdError(p, f"--role {role} applies to a plain folder of images; this session's "
                          "roles are written in its manifest or descriptor")
    if p.is_dir():
        manifest = p / MANIFEST_NAME
        session = open_manifest(manifest) if manifest.exists() else open_folder(p, role)
    elif p.suffix.lower() == ".toml":
        session = open_manifest(p)
    elif _is_emva_descriptor(p):
        session = open_emva_descriptor(p)
    else:
        raise CcdError(p, "not a session: give a session folder, its session.toml, a folder "
                          "of images or an EMVA1288 descriptor file")
    return session.verify_pixels() if check_pixels else session


def draft_manifest(session: Session, path: str | Path | None = None) -> Path:
    """Write :meth:`Session.to_toml` as a manifest draft and return its path.

    Parameters
    ----------
    session
        The session (typically opened from a plain folder).
    path
        Where to write; default ``<session root>/session.toml.draft``.  It must be inside the
        session folder (manifest paths are relative to it).  An existing ``session.toml`` is never
        overwritten: rename the draft once you have checked it.

    Raises
    ------
    CcdError
        ``path`` is an existing ``session.toml`` or lies outside the session folder.
    """
    target = session.root / DRAFT_NAME if path is None else Path(path)
    if target.parent.resolve() != session.root:
        raise CcdError(target, "a manifest must be written in the session folder "
                               f"{session.root} (its paths are relative to it)")
    if target.name == MANIFEST_NAME and target.exists():
        raise CcdError(target, f"already exists; the draft never overwrites a {MANIFEST_NAME} "
                               f"(write {DRAFT_NAME} instead)")
    return atomic_write_text(target, session.to_toml())
