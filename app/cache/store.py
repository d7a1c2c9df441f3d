"""Finished results kept on disk, keyed by the session's content, so that reopening is instant.

A result (a frozen ccdcore dataclass holding numpy arrays) is written into a cache folder as an
``.npz`` (its arrays, and a JSON description of the structure around them: :func:`encode`),
under a key made of the session's content hash (:func:`content_hash`: BLAKE2b of every byte of
the manifest and of every frame), the ccdcore version (with a digest of its source,
:func:`code_version`), the computation's name and its parameters. Each file's digest is
remembered in this process under its stat (path, size, modification and change times, inode),
so an unchanged file is read once; a small persistent index maps the same stats of a session's
files to its content hash, so that a session whose files did not change is recognised without
reading them. A changed stat hashes again: a file rewritten with its modification time set back
still has a new change time (which ``os.utime`` cannot set), so it is read again.

Public objects
--------------
ResultCache
    The cache folder (refused when unsafe, :meth:`~ResultCache.usable`):
    :meth:`~ResultCache.get`, :meth:`~ResultCache.put` (atomic),
    :meth:`~ResultCache.key`, :meth:`~ResultCache.session_hash` (through the stat index),
    :meth:`~ResultCache.known_hash` (the index alone), least-recently-used eviction beyond
    ``max_bytes``, :meth:`~ResultCache.clear`.
cache_folder()
    The folder named by ``CCDCORE_CACHE`` (default ``~/.cache/ccdcore``), or None when disabled.
default_cache(), max_bytes()
    A :class:`ResultCache` on :func:`cache_folder` with the size bound of
    ``CCDCORE_CACHE_MAX_BYTES`` (default 2 GiB), or None when disabled; that bound (the tiled
    previews of :mod:`ccdcore_app.tiles` keep their own pyramids within it too).
code_version()
    The ccdcore version and a digest of its source files, part of every key.
content_hash(session), file_digest(path)
    The session's content hash; one file's BLAKE2b digest (memoised per stat in the process).
encode(value, arrays), decode(data, arrays), Unserialisable
    A result as JSON data and named arrays, and back (ccdcore dataclasses and enums only).
unsafe_folder(folder, root)
    Why a cache folder may not be used (another owner, writable by group or others), or None.
fingerprint(result)
    A short digest of a result's ``to_dict()``, for a result passed as a parameter (the noise
    model handed to ``estimate_all``).
photon_transfer_entry(roi), estimates_entry(noise, **options)
    The name and parameters the pages cache ``photon_transfer`` and ``estimate_all`` under.
SharedResults, shared_results()
    Results in this process's memory, shared by every browser session of the server: a
    computation running for one session is waited for by the others (never started twice);
    the process-wide store (:meth:`ccdcore_app.state.AppState.shared_compute` uses it).

Notes
-----
Entries cannot run code when read: ``np.load(allow_pickle=False)`` and :func:`decode`, which
makes plain data, arrays and the dataclasses and enums of ccdcore's own modules only (looked up
by name, checked, never anything else called). A result holding anything else is not cached
(computed again next time). Older pickle entries (``*.pkl``) are never read; they are deleted.
The folder is used only when it and its sub-folders are owned by the user and not writable by
group or others (:func:`unsafe_folder`; folders are made with mode 0o700): otherwise one
warning is logged and nothing is cached. A corrupt, truncated or
incompatible entry (another format, a class that changed or vanished) is a miss: it is deleted
and the result computed again; no error reaches the user. The bound is kept after every write by
deleting the least recently used entries (a hit touches its entry's modification time).
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import enum
import functools
import hashlib
import importlib
import json
import logging
import os
import stat as stat_mod
import tempfile
import threading
import time
import weakref
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

import ccdcore
from ccdcore.session import Session

from .limits import MAX_INDEX_BYTES, entry_size_problem

__all__ = ["ResultCache", "cache_folder", "code_version", "default_cache", "max_bytes",
           "entry_size_problem", "MAX_INDEX_BYTES",
           "fingerprint",
           "photon_transfer_entry", "estimates_entry", "SharedResults", "Shared",
           "shared_results", "CACHE_ENV", "content_hash", "file_digest", "encode", "decode",
           "Unserialisable", "unsafe_folder",
           "CACHE_SIZE_ENV", "DEFAULT_MAX_BYTES"]

log = logging.getLogger(__name__)

#: environment variable naming the cache folder ("off" disables the cache)
CACHE_ENV = "CCDCORE_CACHE"
#: environment variable bounding the cache's size in bytes (suffixes K, M, G allowed)
CACHE_SIZE_ENV = "CCDCORE_CACHE_MAX_BYTES"
#: the default bound of the results' total size
DEFAULT_MAX_BYTES = 2 * 1024 ** 3
#: the version of the entries' layout (a change makes every older entry a miss); 2: ``.npz``
#: entries (arrays and a JSON description, nothing that runs code when read)
FORMAT = 2
#: the entries' file suffix (older ``.pkl`` entries are never read, only deleted)
SUFFIX = ".npz"
#: bytes read at a time while hashing a file
CHUNK = 1024 ** 2
#: the modules whose dataclasses and enums an entry may name
TRUSTED_PREFIX = "ccdcore."
#: how many sessions the stat -> content hash index remembers
INDEX_SIZE = 512

_OFF = {"off", "0", "none", "false", "no"}
_SUFFIXES = {"k": 1024, "m": 1024 ** 2, "g": 1024 ** 3, "t": 1024 ** 4}


def cache_folder() -> Path | None:
    """The cache folder: ``$CCDCORE_CACHE``, else ``$XDG_CACHE_HOME/ccdcore`` or
    ``~/.cache/ccdcore``; None when ``CCDCORE_CACHE`` is ``off`` (or empty).

    (The app's tests set ``CCDCORE_CACHE=off`` for every test, in ``tests/app/conftest.py``: a
    test run neither reads nor fills the user's cache; a test that wants one names its folder.)
    """
    value = os.environ.get(CACHE_ENV)
    if value is not None:
        if value.strip().lower() in _OFF or not value.strip():
            return None
        return Path(value).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "ccdcore"


def max_bytes() -> int:
    """The bound of the cache's size: ``CCDCORE_CACHE_MAX_BYTES`` (a number of bytes, with an
    optional K, M, G or T suffix), else :data:`DEFAULT_MAX_BYTES`."""
    text = os.environ.get(CACHE_SIZE_ENV, "").strip().lower()
    if not text:
        return DEFAULT_MAX_BYTES
    text = text.removesuffix("ib").removesuffix("b")
    scale = _SUFFIXES.get(text[-1:], 1)
    digits = text[:-1] if text[-1:] in _SUFFIXES else text
    try:
        return max(int(float(digits) * scale), 0)
    except ValueError:
        log.warning("%s=%r is not a size; using %d bytes", CACHE_SIZE_ENV, text,
                    DEFAULT_MAX_BYTES)
        return DEFAULT_MAX_BYTES


def default_cache() -> ResultCache | None:
    """The cache the app uses (:func:`cache_folder`, ``CCDCORE_CACHE_MAX_BYTES``), or None."""
    folder = cache_folder()
    return None if folder is None else ResultCache(folder, max_bytes=max_bytes())


@functools.lru_cache(maxsize=None)
def _source_digest(package: str) -> str:
    digest = hashlib.sha256()
    for path in sorted(Path(package).rglob("*.py")):
        digest.update(str(path.relative_to(package)).encode("utf-8") + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def code_version() -> str:
    """``ccdcore.__version__`` and a digest of ccdcore's source files (read once): results
    computed by other estimator code, even under the same version number, are misses."""
    return f"{ccdcore.__version__}+{_source_digest(str(Path(ccdcore.__file__).parent))}"


def _canonical(value: Any) -> Any:
    """``value`` as plain JSON types (tuples -> lists, numpy scalars -> numbers, paths -> str)."""
    if isinstance(value, dict):
        return {str(k): _canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if hasattr(value, "item") and callable(value.item):   # numpy scalar
        return _canonical(value.item())
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"a cache key parameter must be plain data, not {type(value).__name__}")


def _digest(value: Any) -> str:
    text = json.dumps(_canonical(value), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def fingerprint(result: Any) -> str | None:
    """A digest of ``result.to_dict()`` (None for None): equal results give equal digests."""
    if result is None:
        return None
    text = json.dumps(result.to_dict(), sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _is_key(text: Any) -> bool:
    return isinstance(text, str) and len(text) == 64 and all(c in "0123456789abcdef"
                                                             for c in text)


def photon_transfer_entry(roi: Iterable[int] | None) -> tuple[str, dict[str, Any]]:
    """The entry of :func:`ccdcore.noise.photon_transfer` over ``roi`` (the levels excluded and
    the robust mode only refit its points: ``PhotonTransfer.refit``, not cached)."""
    return "photon_transfer", {"roi": None if roi is None else [int(v) for v in roi]}


def estimates_entry(noise: Any, **options: Any) -> tuple[str, dict[str, Any]]:
    """The entry of :func:`ccdcore.product.make.estimate_all` given the noise model ``noise`` (None:
    estimated inside) and its other keyword ``options``."""
    return "estimate_all", {**options, "noise": fingerprint(noise)}


def _stat(path: Path) -> list[Any]:
    return list(_file_stat(path))


# ---------------------------------------------------------------------------------------------
# entries that cannot run code: arrays in an .npz, the structure around them in JSON
# ---------------------------------------------------------------------------------------------
class Unserialisable(TypeError):
    """A result holding something :func:`encode` does not write (it is then not cached)."""


def _class_name(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _trusted(module: str) -> bool:
    return module == "ccdcore" or module.startswith(TRUSTED_PREFIX)


def encode(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    """``value`` as JSON data, its numpy arrays moved to ``arrays`` (named ``a0``, ``a1`` ...).

    Written: None, bool, int, float, str, :class:`~pathlib.Path`, lists, tuples, dicts,
    numpy arrays and scalars of plain dtypes (not ``object``), and the dataclasses, named
    tuples and enums of ccdcore's own modules (by class name and fields, items or value). Raises
    :class:`Unserialisable` for anything else (a function, another library's object).
    """
    if value is None or isinstance(value, bool) or type(value) is str:
        return value                            # a str enum (channels.Layout) is an enum below
    if isinstance(value, (int, float)) and type(value) in (int, float):
        return value
    if isinstance(value, np.ndarray) or isinstance(value, np.generic):
        arr = np.asarray(value)
        if arr.dtype.hasobject or arr.dtype.kind not in "biufcSUMm":
            raise Unserialisable(f"an array of dtype {arr.dtype}")
        name = f"a{len(arrays)}"
        arrays[name] = arr
        return {"__ndarray__": name, "scalar": isinstance(value, np.generic)}
    if isinstance(value, enum.Enum):
        cls = type(value)
        if not _trusted(cls.__module__):
            raise Unserialisable(f"the enum {_class_name(cls)}")
        return {"__enum__": _class_name(cls), "value": encode(value.value, arrays)}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        cls = type(value)
        if not _trusted(cls.__module__) or "<locals>" in cls.__qualname__:
            raise Unserialisable(f"the class {_class_name(cls)}")
        return {"__dataclass__": _class_name(cls),
                "fields": {f.name: encode(getattr(value, f.name), arrays)
                           for f in dataclasses.fields(value)}}
    if isinstance(value, Path):
        return {"__path__": str(value)}
    if isinstance(value, tuple) and type(value) is not tuple and hasattr(value, "_fields"):
        cls = type(value)                                      # a NamedTuple (e.g. Roi)
        if not _trusted(cls.__module__) or "<locals>" in cls.__qualname__:
            raise Unserialisable(f"the named tuple {_class_name(cls)}")
        return {"__namedtuple__": _class_name(cls), "items": [encode(v, arrays) for v in value]}
    if type(value) is tuple:
        return {"__tuple__": [encode(v, arrays) for v in value]}
    if type(value) is list:
        return [encode(v, arrays) for v in value]
    if type(value) is dict:
        return {"__dict__": [[encode(k, arrays), encode(v, arrays)] for k, v in value.items()]}
    raise Unserialisable(f"a {type(value).__module__}.{type(value).__qualname__}")


def _trusted_class(name: Any, kind: str) -> type:
    """The class ``module:QualName`` of a ccdcore module, when it is a dataclass (``kind``
    "dataclass"), a named tuple ("namedtuple") or an enum ("enum"); nothing else is looked up,
    and nothing is called."""
    if not isinstance(name, str) or name.count(":") != 1:
        raise ValueError(f"not a class name: {name!r}")
    module, qualname = name.split(":")
    if not _trusted(module) or not qualname or "<" in qualname \
            or any(not part.isidentifier() or part.startswith("__")
                   for part in qualname.split(".")):
        raise ValueError(f"{name} is not a ccdcore class")
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    if not isinstance(obj, type):
        ok = False
    elif kind == "dataclass":
        ok = dataclasses.is_dataclass(obj)
    elif kind == "namedtuple":
        ok = issubclass(obj, tuple) and isinstance(getattr(obj, "_fields", None), tuple)
    else:
        ok = issubclass(obj, enum.Enum)
    if not ok or not _trusted(obj.__module__):
        raise ValueError(f"{name} is not a ccdcore {kind}")
    return obj


def decode(data: Any, arrays: Any) -> Any:
    """The value :func:`encode` wrote (``arrays``: the entry's arrays by name). Only ccdcore's
    dataclasses and enums are instantiated; raises ValueError (or KeyError, TypeError) for
    anything else."""
    if data is None or isinstance(data, (bool, int, float, str)):
        return data
    if isinstance(data, list):
        return [decode(v, arrays) for v in data]
    if not isinstance(data, dict) or len(data) == 0:
        raise ValueError(f"unexpected {type(data).__name__} in an entry")
    if "__ndarray__" in data:
        name = data["__ndarray__"]
        if not isinstance(name, str) or not name.startswith("a"):
            raise ValueError(f"bad array name {name!r}")
        arr = arrays[name]
        return arr[()] if data.get("scalar") else arr
    if "__tuple__" in data:
        return tuple(decode(v, arrays) for v in data["__tuple__"])
    if "__dict__" in data:
        return {_hashable(decode(k, arrays)): decode(v, arrays) for k, v in data["__dict__"]}
    if "__path__" in data:
        return Path(str(data["__path__"]))
    if "__namedtuple__" in data:
        cls = _trusted_class(data["__namedtuple__"], "namedtuple")
        return cls(*[decode(v, arrays) for v in data["items"]])
    if "__enum__" in data:
        return _trusted_class(data["__enum__"], "enum")(decode(data["value"], arrays))
    if "__dataclass__" in data:
        cls = _trusted_class(data["__dataclass__"], "dataclass")
        fields = data["fields"]
        if not isinstance(fields, dict):
            raise ValueError("bad dataclass fields")
        known = {f.name: f for f in dataclasses.fields(cls)}
        if set(fields) != set(known):
            raise ValueError(f"{data['__dataclass__']} has other fields now")
        values = {k: decode(v, arrays) for k, v in fields.items()}
        obj = cls(**{k: v for k, v in values.items() if known[k].init})
        for k, v in values.items():          # fields the constructor does not take
            if not known[k].init:
                object.__setattr__(obj, k, v)
        return obj
    raise ValueError(f"unexpected keys {sorted(data)[:3]} in an entry")


def _hashable(key: Any) -> Any:
    if isinstance(key, list):
        raise ValueError("a list as a dict key")
    return key


# ---------------------------------------------------------------------------------------------
# the session's content hash
# ---------------------------------------------------------------------------------------------
_FILE_DIGESTS: OrderedDict[tuple, str] = OrderedDict()
_FILE_DIGESTS_LOCK = threading.Lock()
#: (folder, reason) of the refused cache folders already warned about
_REFUSED: set[tuple[str, str]] = set()
#: how many files' digests this process remembers
FILE_MEMO_SIZE = 8192


def _file_stat(path: Path) -> tuple:
    """What identifies a file's version without reading it: path, size, ``st_mtime_ns``,
    ``st_ctime_ns``, inode and device. The change time cannot be set back (``os.utime`` sets
    it to now): a file rewritten with its old size and modification time restored differs."""
    st = os.stat(path)
    return (str(path), int(st.st_size), int(st.st_mtime_ns), int(st.st_ctime_ns),
            int(st.st_ino), int(st.st_dev))


def file_digest(path: str | os.PathLike) -> str:
    """The BLAKE2b digest (hex) of a file's bytes, read in 1 MiB chunks; remembered in this
    process under :func:`_file_stat`, so an unchanged file is not read again (a page does not
    rehash on every widget change). Raises OSError."""
    path = Path(path)
    key = _file_stat(path)
    with _FILE_DIGESTS_LOCK:
        known = _FILE_DIGESTS.get(key)
        if known is not None:
            _FILE_DIGESTS.move_to_end(key)
            return known
    digest = hashlib.blake2b(digest_size=32)
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK):
            digest.update(chunk)
    if _file_stat(path) != key:            # changed while read: not remembered
        return digest.hexdigest()
    with _FILE_DIGESTS_LOCK:
        _FILE_DIGESTS[key] = digest.hexdigest()
        while len(_FILE_DIGESTS) > FILE_MEMO_SIZE:
            _FILE_DIGESTS.popitem(last=False)
    return digest.hexdigest()


def content_hash(session: Session) -> str:
    """The session's content hash (64 hex digits): BLAKE2b over the manifest's bytes and, per
    frame in session order, its path relative to the session root and its bytes' digest
    (:func:`file_digest`; each field length-prefixed). The same files give the same hash
    wherever the folder lies; a changed byte, a renamed, added or reordered frame changes it.
    Raises OSError."""
    digest = hashlib.blake2b(b"ccdcore_app cache content v2\0", digest_size=32)

    def field_(text: str) -> None:
        data = text.encode("utf-8")
        digest.update(len(data).to_bytes(8, "little"))
        digest.update(data)

    field_("" if session.manifest_path is None else file_digest(session.manifest_path))
    for rec in session.frames:
        field_(str(rec.relpath))
        field_(file_digest(rec.path))
    return digest.hexdigest()


# ---------------------------------------------------------------------------------------------
# the folder
# ---------------------------------------------------------------------------------------------
def unsafe_folder(folder: Path, root: Path) -> str | None:
    """Why ``folder`` (``root`` or a folder inside it) may not hold the cache, or None: each
    folder from ``root`` down to ``folder`` must be a real folder owned by this user and not
    writable by its group or by others (someone else could plant entries). Missing folders are
    fine (they are made with mode 0o700)."""
    if not hasattr(os, "getuid"):       # (Windows: no owners or modes to check this way)
        return None
    uid = os.getuid()
    parts = [root] + [root.joinpath(*folder.relative_to(root).parts[:i + 1])
                      for i in range(len(folder.relative_to(root).parts))]
    for part in parts:
        try:
            st = os.stat(part, follow_symlinks=False)
        except FileNotFoundError:
            return None
        except OSError as err:
            return f"{part}: {err.strerror or err}"
        if stat_mod.S_ISLNK(st.st_mode):
            try:
                st = os.stat(part)
            except OSError as err:
                return f"{part}: {err.strerror or err}"
        if not stat_mod.S_ISDIR(st.st_mode):
            return f"{part} is not a folder"
        if st.st_uid != uid:
            return f"{part} is owned by uid {st.st_uid}, not by this user (uid {uid})"
        if st.st_mode & 0o022:
            return (f"{part} is writable by its group or by others (mode "
                    f"{stat_mod.S_IMODE(st.st_mode):04o}); make it 0700")
    return None




class ResultCache:
    """Results on disk under ``folder``, at most ``max_bytes`` in total (least recently used
    entries deleted first).

    Parameters
    ----------
    folder
        The cache folder (created when first written). Results go to ``results/``, the stat ->
        content hash index to ``hashes.json``.
    max_bytes
        The bound of the results' total size.

    Examples
    --------
    >>> cache = ResultCache(folder)                                          # doctest: +SKIP
    >>> key = cache.key(cache.session_hash(session),                         # doctest: +SKIP
    ...                 *photon_transfer_entry(None))
    >>> result = cache.get(key)                                              # doctest: +SKIP
    >>> if result is None:                                                   # doctest: +SKIP
    ...     cache.put(key, photon_transfer(session))
    """

    def __init__(self, folder: str | os.PathLike, max_bytes: int = DEFAULT_MAX_BYTES):
        self.folder = Path(folder)
        self.max_bytes = int(max_bytes)
        self._lock = threading.Lock()
        self._refused: str | None = None      # why the folder is not used (said once)
        self._swept = False                   # older pickle entries deleted

    def usable(self, create: bool = False) -> bool:
        """Whether the folder may hold the cache (:func:`unsafe_folder`, checked on every
        use; ``create``: the folders are made first, mode 0o700). A refused folder is not
        used at all (every :meth:`get` misses, :meth:`put` stores nothing), with one logged
        warning."""
        if create:
            try:
                self.results_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
            except OSError as err:
                log.warning("could not create the cache folder %s: %s", self.results_dir, err)
                return False
        why = unsafe_folder(self.results_dir, self.folder)
        if why is not None:
            if self._refused is None and (str(self.folder), why) not in _REFUSED:
                _REFUSED.add((str(self.folder), why))      # said once per process
                log.warning("not using the result cache in %s: %s", self.folder, why)
            self._refused = why
            return False
        if create and not self._swept:
            self._swept = True
            for old in self.results_dir.glob("*.pkl"):   # an older format: never unpickled
                self._remove(old)
        return True

    @property
    def results_dir(self) -> Path:
        return self.folder / "results"

    @property
    def index_path(self) -> Path:
        return self.folder / "hashes.json"

    # ---- keys ---------------------------------------------------------------------------------
    @staticmethod
    def key(content_hash: str, name: str, params: dict[str, Any] | None = None) -> str:
        """The entry key (hex) of computation ``name`` with ``params`` (plain data: numbers,
        strings, None, lists, tuples, dicts) on the session of ``content_hash``, for this
        ccdcore (:func:`code_version`) and entry format."""
        return _digest({"format": FORMAT, "ccdcore": code_version(),
                        "session": content_hash, "name": name, "params": params or {}})

    def _path(self, key: str) -> Path:
        return self.results_dir / f"{key}{SUFFIX}"

    # ---- results ------------------------------------------------------------------------------
    def get(self, key: str) -> Any | None:
        """The value stored under ``key`` (or under the key it links to, see :meth:`link`), or
        None (absent, unreadable, corrupt or incompatible: such an entry is deleted)."""
        entry = self._load(key)
        if entry is not None and entry["value"] is None:   # a link: followed once
            target = self._load(entry["target"])
            return None if target is None else target["value"]
        return None if entry is None else entry["value"]

    def _load(self, key: str) -> dict[str, Any] | None:
        """The entry of ``key`` (its last use touched), or None."""
        if not _is_key(key):
            return None
        path = self._path(key)
        if not path.is_file() or not self.usable():
            return None
        try:
            oversized = entry_size_problem(path)
            if oversized:
                raise ValueError(oversized)
            # arrays and JSON only: allow_pickle=False, and decode() makes nothing but plain
            # data and ccdcore's own dataclasses and enums
            with np.load(path, allow_pickle=False) as z:
                entry = json.loads(bytes(z["__entry__"]).decode("utf-8"))
                if isinstance(entry, dict) and "value" in entry:
                    entry["value"] = decode(entry["value"], z)
        except FileNotFoundError:
            return None
        except Exception as err:  # truncated, corrupt, a class that changed: recompute
            log.warning("ignoring the cache entry %s: %s: %s", path.name, type(err).__name__, err)
            self._remove(path)
            return None
        if not isinstance(entry, dict) or entry.get("format") != FORMAT \
                or entry.get("key") != key or "value" not in entry \
                or (entry["value"] is None and not _is_key(entry.get("target"))):
            log.warning("ignoring the incompatible cache entry %s", path.name)
            self._remove(path)
            return None
        try:
            os.utime(path)   # the last use, for the least-recently-used eviction
        except OSError:
            pass
        return entry

    def put(self, key: str, value: Any) -> bool:
        """Store ``value`` under ``key`` (temporary file, then an atomic rename) and keep the
        bound; False (logged) when it cannot be written or holds something :func:`encode`
        does not write (it is then computed again next time). None is never stored."""
        if value is None:
            return False
        return self._write(key, {"format": FORMAT, "key": key, "value": value})

    def link(self, key: str, target: str) -> bool:
        """Make ``key`` give what ``target`` holds (a small entry, not a second copy): for a
        computation whose result another key's computation also gives."""
        if key == target:
            return False
        return self._write(key, {"format": FORMAT, "key": key, "value": None, "target": target})

    def _write(self, key: str, entry: dict[str, Any]) -> bool:
        if not _is_key(key):
            raise ValueError(f"key: not a cache key: {key!r}")
        tmp = None
        try:
            arrays: dict[str, np.ndarray] = {}
            entry = {**entry, "value": encode(entry["value"], arrays)}
            text = json.dumps(entry, allow_nan=True).encode("utf-8")
            if not self.usable(create=True):
                return False
            fd, tmp = tempfile.mkstemp(dir=self.results_dir, prefix=f".{key[:16]}-",
                                       suffix=".tmp")
            with os.fdopen(fd, "wb") as f:
                np.savez(f, __entry__=np.frombuffer(text, dtype=np.uint8), **arrays)
            os.replace(tmp, self._path(key))
            tmp = None
        except Exception as err:  # a result encode() does not write, a full disk: app goes on
            log.warning("could not cache %s: %s: %s", key[:16], type(err).__name__, err)
            return False
        finally:
            if tmp is not None:
                self._remove(Path(tmp))
        self.evict(keep=key)
        return True

    def entries(self) -> list[Path]:
        """The entries' files, least recently used first."""
        found = []
        try:
            with os.scandir(self.results_dir) as it:
                for e in it:
                    if e.name.endswith(SUFFIX) and not e.name.startswith("."):
                        try:
                            st = e.stat()
                        except OSError:
                            continue
                        found.append((st.st_mtime_ns, e.name, st.st_size))
        except FileNotFoundError:
            return []
        return [self.results_dir / name for _, name, _ in sorted(found)]

    def size(self) -> int:
        """The entries' total size in bytes."""
        return sum(self._size(p) for p in self.entries())

    @staticmethod
    def _size(path: Path) -> int:
        try:
            return path.stat().st_size
        except OSError:
            return 0

    def evict(self, keep: str | None = None) -> list[Path]:
        """Delete the least recently used entries until the total is within ``max_bytes``
        (the entry of ``keep``, just written, last), and temporary files older than an hour
        (left by a killed writer); the deleted entries."""
        entries = self.entries()
        if keep is not None and self._path(keep) in entries:
            entries.remove(self._path(keep))
            entries.append(self._path(keep))
        sizes = [self._size(p) for p in entries]
        total = sum(sizes)
        removed = []
        for path, size in zip(entries, sizes):
            if total <= self.max_bytes:
                break
            self._remove(path)
            removed.append(path)
            total -= size
        cutoff = time.time() - 3600
        for tmp in self.results_dir.glob(".*.tmp") if self.results_dir.is_dir() else ():
            try:
                if tmp.stat().st_mtime < cutoff:
                    self._remove(tmp)
            except OSError:
                pass
        return removed

    def clear(self) -> None:
        """Delete every entry and the stat index."""
        for path in self.entries():
            self._remove(path)
        self._remove(self.index_path)

    @staticmethod
    def _remove(path: Path) -> None:
        try:
            path.unlink()
        except OSError:
            pass

    # ---- the session's content hash -------------------------------------------------------
    @staticmethod
    def stat_key(session: Session) -> str:
        """A digest of the manifest's and every frame's path, size, ``st_mtime_ns``,
        ``st_ctime_ns``, inode and device (in session order): what the index maps to the
        content hash. Raises OSError."""
        files: Iterable[Path] = [rec.path for rec in session.frames]
        manifest = None if session.manifest_path is None else _stat(session.manifest_path)
        return _digest({"manifest": manifest, "frames": [_stat(p) for p in files]})

    def _read_index(self) -> dict[str, Any]:
        if not self.index_path.is_file() or not self.usable():
            return {}
        try:
            if self.index_path.stat().st_size > MAX_INDEX_BYTES:
                raise ValueError("index larger than any this cache writes")
            data = json.loads(self.index_path.read_text())
            if isinstance(data, dict) and data.get("format") == FORMAT \
                    and isinstance(data.get("sessions"), dict):
                return data["sessions"]
        except (OSError, ValueError, RecursionError) as err:
            # RecursionError: JSON nested thousands deep, which this cache never writes
            log.warning("ignoring the cache index %s: %s", self.index_path,
                        type(err).__name__)
        return {}

    def _write_index(self, sessions: dict[str, Any]) -> None:
        if len(sessions) > INDEX_SIZE:
            keep = sorted(sessions, key=lambda k: sessions[k].get("used", 0))[-INDEX_SIZE:]
            sessions = {k: sessions[k] for k in keep}
        tmp = None
        try:
            if not self.usable(create=True):
                return
            fd, tmp = tempfile.mkstemp(dir=self.folder, prefix=".hashes-", suffix=".tmp")
            with os.fdopen(fd, "w") as f:
                json.dump({"format": FORMAT, "sessions": sessions}, f)
            os.replace(tmp, self.index_path)
            tmp = None
        except OSError as err:
            log.warning("could not write the cache index: %s", err)
        finally:
            if tmp is not None:
                self._remove(Path(tmp))

    def _indexed(self, stat: str) -> str | None:
        with self._lock:
            entry = self._read_index().get(stat)
        if isinstance(entry, dict) and isinstance(entry.get("hash"), str):
            return entry["hash"]
        return None

    def known_hash(self, session: Session) -> str | None:
        """The session's content hash when the index knows its files' stats (no file is
        read), else None (a new session, a changed or unreadable file)."""
        try:
            return self._indexed(self.stat_key(session))
        except OSError:
            return None

    def session_hash(self, session: Session) -> str:
        """The session's content hash: from the index when no file's stat changed, else
        :func:`content_hash` (every byte of a changed file read), then remembered.

        Raises
        ------
        CcdError, OSError
            A file cannot be read.
        """
        stat = self.stat_key(session)
        known = self._indexed(stat)
        if known is not None:
            return known
        content = content_hash(session)
        with self._lock:
            sessions = self._read_index()
            sessions[stat] = {"hash": content, "used": time.time(),
                              "root": str(session.root)}
            self._write_index(sessions)
        return content


# ---------------------------------------------------------------------------------------------
# results shared in memory by the browser sessions of one server
# ---------------------------------------------------------------------------------------------
@dataclass(eq=False)
class Shared:
    """One computation of a :class:`SharedResults` store, running or finished.

    ``future`` (a :class:`concurrent.futures.Future`, safe to wait on from any thread or event
    loop) ends with ``(value, error)``: the value and ``""``; ``None`` and the user-facing
    error message (the same input fails the same way for everyone); or ``None, None`` when it
    was not computed (cancelled by its owner, its browser session gone): a waiter then claims
    the key and computes it itself. ``tracker`` is the owner's
    :class:`ccdcore.progress.Tracker`, for the waiters' progress bars (``None`` until it
    starts)."""

    key: str
    future: concurrent.futures.Future = field(default_factory=concurrent.futures.Future)
    tracker: Any = None


class SharedResults:
    """Finished and running computations in this process's memory, keyed by
    :meth:`ResultCache.key` (the session's content hash, the computation's name and its
    parameters): every browser session of the server gets one computation's result.

    :meth:`claim` gives the value when it is known, else the running :class:`Shared` entry and
    whether the caller owns it (it then computes and calls :meth:`finish`; the others wait on
    ``entry.future``). Thread-safe: one lock guards the tables, held for no computation.

    Parameters
    ----------
    max_entries
        The finished values held for certain (least recently used dropped first). A value
        stored with ``hold=False`` (large results, e.g. HDR radiance maps) and every dropped
        value stay findable as long as anyone else holds them (a weak reference), so a value
        one browser session shows is shared without the store keeping it alive.
    """

    def __init__(self, max_entries: int = 16):
        self.max_entries = int(max_entries)
        self._lock = threading.Lock()
        self._held: OrderedDict[str, Any] = OrderedDict()
        self._weak: weakref.WeakValueDictionary[str, Any] = weakref.WeakValueDictionary()
        self._running: dict[str, Shared] = {}

    def get(self, key: str) -> Any | None:
        """The finished value of ``key`` (its use recorded), or None."""
        with self._lock:
            return self._value(key)

    def _value(self, key: str) -> Any | None:
        if key in self._held:
            self._held.move_to_end(key)
            return self._held[key]
        return self._weak.get(key)

    def claim(self, key: str) -> tuple[Any | None, Shared | None, bool]:
        """``(value, None, False)`` when ``key`` is finished; else ``(None, entry, owner)``:
        the running computation, started by the caller (``owner``: it must compute and call
        :meth:`finish`, even on failure) or by someone else (wait on ``entry.future``)."""
        with self._lock:
            value = self._value(key)
            if value is not None:
                return value, None, False
            entry = self._running.get(key)
            if entry is not None:
                return None, entry, False
            entry = self._running[key] = Shared(key)
            return None, entry, True

    def finish(self, entry: Shared, value: Any | None, error: str | None = "", *,
               hold: bool = True) -> bool:
        """End ``entry`` with ``value`` (kept, see the class; ``hold=False``: weakly only) or,
        when None, with ``error`` (``None``: not computed, the key may be claimed again). Only
        the first call counts (False afterwards)."""
        with self._lock:
            if entry.future.done():
                return False
            if self._running.get(entry.key) is entry:
                del self._running[entry.key]
            if value is not None:
                try:
                    self._weak[entry.key] = value
                except TypeError:          # not weakly referable: held
                    hold = True
                if hold:
                    self._held[entry.key] = value
                    self._held.move_to_end(entry.key)
                    while len(self._held) > self.max_entries:
                        self._held.popitem(last=False)
            entry.future.set_result((value, "" if value is not None else (error or None)))
        return True

    def running(self, key: str) -> Shared | None:
        """The running computation of ``key``, or None."""
        with self._lock:
            return self._running.get(key)

    def __contains__(self, key: str) -> bool:
        return self.get(key) is not None

    def clear(self) -> None:
        """Forget every finished value (running computations finish as they would)."""
        with self._lock:
            self._held.clear()
            self._weak.clear()


_SHARED: SharedResults | None = None
_SHARED_LOCK = threading.Lock()


def shared_results() -> SharedResults:
    """The process-wide :class:`SharedResults` (made on first use)."""
    global _SHARED
    with _SHARED_LOCK:
        if _SHARED is None:
            _SHARED = SharedResults()
        return _SHARED
