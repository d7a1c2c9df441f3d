"""Output sets for :mod:`ccdcore.io.frames`: every write of a verb as one set (a temporary folder
swapped in), never over an input of the run nor over a FIFO or a device. Re-exported by
:mod:`ccdcore.io.frames`.
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import stat
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

from ..errors import CcdError, ImageWriteError
from .base import os_problem, sync_folder

__all__ = ["TEMP_PREFIX", "MARK", "RECORD", "JOURNAL_PREFIX", "real_path", "check_output",
           "check_not_inputs", "check_outputs", "read_record", "ownership_problem",
           "recover_swaps", "remove_stale_temporaries", "output_set", "write_outputs"]


# --------------------------------------------------------------------------------------------
# output sets: every write of a verb as one set, never over an input nor a special file
# --------------------------------------------------------------------------------------------
#: the prefix of the temporary folders an output set is written into (removed on failure, on
#: SIGTERM, and by the next write into the same folder once the process that made it is gone)
TEMP_PREFIX = ".ccdcore-tmp-"
#: the file in each of our temporary folders that marks it as ours (it holds the writer's
#: process id): a folder of the user's that happens to share the prefix is never removed
MARK = ".ccdcore-run"
#: the file in every output folder that records what ccdcore wrote there (name -> the files of
#: a folder entry, or null for a file): only those are ever replaced or removed
RECORD = ".ccdcore-outputs.json"
#: the journal of a swap in progress (``.ccdcore-swap-<pid>.json``): which entries were moved
#: aside and which moved in, so that a run killed halfway is undone by the next write
JOURNAL_PREFIX = ".ccdcore-swap-"


def real_path(path: str | os.PathLike) -> Path:
    """``path`` absolute with every symlink resolved (what a write would really touch)."""
    return Path(os.path.abspath(path)).resolve()


def _not_regular(mode: int) -> str:
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISREG(mode):
        return "a file"
    return "a folder" if stat.S_ISDIR(mode) else "not a regular file"


def check_output(path: str | os.PathLike, *, folder: bool = False) -> None:
    """Refuse an output path that exists as something a write must not replace.

    A file output may be absent or a regular file (or a symlink to one: the link is replaced);
    a folder output may be absent or a folder. A FIFO, a device node or a socket -- or a
    symlink to one -- would otherwise be replaced by a regular file (or, for a FIFO, block).

    Raises
    ------
    CcdError
        Naming ``path`` and what it is.
    """
    path = Path(path)
    if not os.path.lexists(path):
        return
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return  # a dangling symlink: the link itself is replaced
    except OSError as exc:
        raise CcdError(path, f"cannot check the output: {exc.strerror}") from None
    wanted = stat.S_ISDIR(mode) if folder else stat.S_ISREG(mode)
    if not wanted:
        link = f"is a symlink to {os.path.realpath(path)}, which is" if path.is_symlink() \
            else "is"
        kind = "a folder" if folder else "a file"
        raise CcdError(path, f"{link} {_not_regular(mode)}, not {kind}; choose another -o")


def check_not_inputs(outputs: Iterable[str | os.PathLike],
                     inputs: Iterable[str | os.PathLike], *, contain: bool = True) -> None:
    """Refuse an output equal to, inside, or (``contain``) containing an input of the same run
    (resolved paths, so a symlink or ``..`` does not hide it): writing would destroy what is
    being read.

    Raises
    ------
    CcdError
        Naming the output and the input it would overwrite.
    """
    ins = [(Path(i), real_path(i)) for i in inputs]
    for out in outputs:
        o = real_path(out)
        for given, i in ins:
            if o == i:
                raise CcdError(out, "would overwrite an input of this run; choose another -o")
            if i in o.parents or (contain and o in i.parents):
                how = "is inside" if i in o.parents else "holds"
                raise CcdError(out, f"{how} {given}, an input of this run: writing there would "
                                    "overwrite an input; choose another -o")


def check_outputs(folder: str | os.PathLike, names: Iterable[str] | Mapping[str, bool],
                  inputs: Iterable[str | os.PathLike] = (), *, owned: bool = True) -> None:
    """Check the outputs ``folder/name`` of a run before anything is computed or written:
    ``folder`` a folder (or absent) neither an input nor inside one, each output a regular
    file (a folder where ``names`` maps the name to ``True``) or absent, none equal to,
    inside or containing an input (:func:`check_output`, :func:`check_not_inputs`), and, with
    ``owned``, each existing output one that ccdcore wrote there (:func:`ownership_problem`):
    an output replaces only what a run of ours wrote.

    Raises
    ------
    CcdError
        Naming the output and the problem.
    """
    folder = Path(folder)
    inputs = list(inputs)
    check_output(folder, folder=True)
    check_not_inputs([folder], inputs, contain=False)
    kinds = names if isinstance(names, Mapping) else dict.fromkeys(names, False)
    for name, is_folder in kinds.items():
        check_output(folder / name, folder=is_folder)
    check_not_inputs([folder / n for n in kinds], inputs)
    if owned and kinds and folder.is_dir():
        record = read_record(folder)
        for name in kinds:
            problem = ownership_problem(folder, name, record)
            if problem:
                raise CcdError(folder / name, f"{problem}: an output replaces only what ccdcore "
                                              "wrote there; move it away or choose another -o")


def _plain_name(name: Any) -> bool:
    """A name of one entry of a folder (no separator, not . or ..)."""
    return isinstance(name, str) and name not in ("", ".", "..") and "/" not in name \
        and os.sep not in name and "\0" not in name


def read_record(folder: str | os.PathLike) -> dict[str, list[str] | None]:
    """What ccdcore wrote in ``folder`` (its :data:`RECORD`): entry name -> the files of a
    folder entry (relative paths), or None for a file. Empty when there is none or it is
    damaged: then nothing there is known as ours."""
    try:
        with open(Path(folder) / RECORD, encoding="utf-8") as f:
            data = json.loads(f.read(1 << 22))
        entries = data["entries"]
        out: dict[str, list[str] | None] = {}
        for name, files in entries.items():
            if _plain_name(name) and (files is None or (isinstance(files, list) and all(
                    isinstance(x, str) for x in files))):
                out[name] = files
        return out
    except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError):
        return {}


def _entry_files(path: Path) -> list[str]:
    """The files under a folder entry, as sorted relative paths (symlinks counted as files)."""
    out = []
    for root, dirs, files in os.walk(path):
        rel = os.path.relpath(root, path)
        for name in files + [d for d in dirs if os.path.islink(os.path.join(root, d))]:
            out.append(os.path.normpath(os.path.join(rel, name)))
    return sorted(out)


def ownership_problem(folder: str | os.PathLike, name: str,
                      record: Mapping[str, list[str] | None] | None = None) -> str | None:
    """Why the existing entry ``folder/name`` may not be replaced by a run (it, or a file in
    it, was not written by ccdcore: not in ``folder``'s :data:`RECORD`), or None (absent, or
    ours)."""
    path = Path(folder) / name
    if not os.path.lexists(path):
        return None
    record = read_record(folder) if record is None else record
    if name not in record:
        return "exists and was not written by ccdcore"
    files = record[name]
    is_dir = path.is_dir() and not path.is_symlink()
    if files is None:
        return "is a folder, where ccdcore wrote a file" if is_dir else None
    if not is_dir:
        return "is a file, where ccdcore wrote a folder"
    extra = sorted(set(_entry_files(path)) - set(files))
    if extra:
        more = f" (and {len(extra) - 1} more)" if len(extra) > 1 else ""
        return f"holds {extra[0]}{more}, which ccdcore did not write"
    return None


def _write_json(path: Path, data: Any) -> None:
    """``data`` as JSON at ``path``, durably and atomically (a temporary file, then a rename)."""
    part = path.with_name(f"{path.name}.{os.getpid()}.part")
    with open(part, "w", encoding="utf-8") as f:
        json.dump(data, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(part, path)
    sync_folder(path.parent)


def _temp_folder(home: Path, tag: str = "") -> Path:
    """A new temporary folder of ours in ``home``, marked as ours (:data:`MARK`)."""
    tmp = Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}{tag}", suffix=f"-{os.getpid()}",
                                dir=home))
    (tmp / MARK).write_text(str(os.getpid()))
    return tmp


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


class _Terminated(BaseException):
    """SIGTERM while an output set is written: unwinds like KeyboardInterrupt so the temporary
    folder goes."""


def recover_swaps(folder: str | os.PathLike) -> None:
    """Finish or undo the swaps that killed runs (SIGKILL, a power cut) left in ``folder``,
    from their journals: a swap that had moved its whole set in is finished (the set moved
    aside goes); one that had not is undone (the entries it moved in go, the earlier set moved
    aside comes back). ``folder`` then holds the earlier set or the new one, never a mix, and a
    set moved aside is never deleted before the new one is whole."""
    folder = Path(folder)
    for part in folder.glob(f"{JOURNAL_PREFIX}*.json.*.part"):   # a journal half written
        pid = part.name[:-len(".part")].rsplit(".", 1)[-1]
        if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)):
            with contextlib.suppress(OSError):
                part.unlink()
    for journal in sorted(folder.glob(f"{JOURNAL_PREFIX}*.json")):
        pid = journal.name[len(JOURNAL_PREFIX):-len(".json")]
        if not pid.isdigit() or int(pid) == os.getpid() or _alive(int(pid)):
            continue
        try:
            data = json.loads(journal.read_text(encoding="utf-8"))
            tmp, old = data["tmp"], data["old"]
            new, parked = list(data["new"]), list(data["parked"])
            if not (all(_plain_name(n) for n in [tmp, old, *new, *parked])
                    and tmp.startswith(TEMP_PREFIX) and old.startswith(TEMP_PREFIX)):
                raise ValueError("names outside the folder")
        except (OSError, ValueError, KeyError, TypeError, RecursionError):
            continue                         # not a journal of ours: left alone
        if data.get("state") != "done":
            for name in new:                 # moved in: ours, and not the earlier set
                if not os.path.lexists(folder / tmp / name):
                    _remove(folder / name)
            for name in parked:              # the earlier set, back in place
                if os.path.lexists(folder / old / name):
                    os.replace(folder / old / name, folder / name)
        shutil.rmtree(folder / old, ignore_errors=True)
        shutil.rmtree(folder / tmp, ignore_errors=True)
        journal.unlink()
        sync_folder(folder)


def remove_stale_temporaries(folder: str | os.PathLike) -> None:
    """Undo or finish the swaps killed runs left in ``folder`` (:func:`recover_swaps`), then
    remove the temporary folders they left (not those of live processes: their :data:`MARK`
    holds the writer's process id). Only folders marked as ours are removed; a folder of the
    user's named like one is left alone."""
    recover_swaps(folder)
    journals = list(Path(folder).glob(f"{JOURNAL_PREFIX}*.json"))
    for p in Path(folder).glob(f"{TEMP_PREFIX}*"):
        if not p.is_dir() or p.is_symlink() or not (p / MARK).is_file():
            continue
        try:
            pid = (p / MARK).read_text().strip()
        except OSError:
            continue
        if not pid.isdigit() or (int(pid) != os.getpid() and _alive(int(pid))):
            continue
        if any(p.name in j.read_text(errors="replace") for j in journals if j.is_file()):
            continue                         # a swap not undone yet holds a set in it
        shutil.rmtree(p, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _renamed(err: CcdError, tmp: Path, folder: Path) -> CcdError:
    """``err`` naming ``folder`` where it named the internal temporary folder ``tmp``."""
    def fix(text: str | None) -> str | None:
        return None if text is None else text.replace(str(tmp), str(folder))

    cls = ImageWriteError if isinstance(err, ImageWriteError) else CcdError
    return cls(fix(err.where), fix(err.problem) or "")


def _check_replaced(folder: Path, replaces: Iterable[str]) -> None:
    """Refuse to remove an earlier set's entry of ours that now holds files of the user's."""
    record = read_record(folder)
    for name in replaces:
        if name in record:
            problem = ownership_problem(folder, name, record)
            if problem:
                raise CcdError(folder / name, f"{problem}: the earlier outputs it belongs to "
                                              "would be removed; move it away or choose "
                                              "another -o")


def _entry_record(path: Path) -> list[str] | None:
    return _entry_files(path) if path.is_dir() and not path.is_symlink() else None


def _swap_in(tmp: Path, folder: Path, last: str | None, replaces: Iterable[str],
             force: bool = False, record: bool = True) -> None:
    """Move the entries of ``tmp`` into ``folder`` (or ``tmp`` onto ``folder`` when there is
    none yet, one rename) as one set, with the folder's :data:`RECORD` of what ccdcore wrote.

    Every entry the set replaces, and the entries ``replaces`` of an earlier set of ours not
    written again, are first moved aside into a folder of ours, then the new entries moved in
    (``last`` last), a journal recording each stage, so that a run killed at any moment leaves
    a state :func:`recover_swaps` turns into the earlier set or the new one. Entries ccdcore
    did not write are never removed (``force``: the caller took the folder as it is)."""
    names = sorted(n for n in os.listdir(tmp) if n not in (MARK, RECORD, last))
    written = names + ([last] if last is not None and os.path.lexists(tmp / last) else [])
    if not folder.exists():
        if record:
            _write_json(tmp / RECORD, {"format": 1, "entries": {
                n: _entry_record(tmp / n) for n in written}})
        (tmp / MARK).unlink()
        os.chmod(tmp, 0o755)
        os.replace(tmp, folder)
        sync_folder(folder.parent)
        return
    prev = read_record(folder)
    gone = [n for n in replaces if n not in written and _plain_name(n)
            and os.path.lexists(folder / n) and (force or n in prev)]
    entries = {n: f for n, f in prev.items() if n not in gone and os.path.lexists(folder / n)}
    entries.update({n: _entry_record(tmp / n) for n in written})
    if record:
        _write_json(tmp / RECORD, {"format": 1, "entries": entries})
    new = names + ([RECORD] if record else []) + written[len(names):]   # ``last`` goes last
    parked = ([last] if last in new and os.path.lexists(folder / last) else []) + \
        [n for n in new if n != last and os.path.lexists(folder / n)] + gone
    old = _temp_folder(folder, "old-")
    journal = folder / f"{JOURNAL_PREFIX}{os.getpid()}.json"
    stage = {"tmp": tmp.name, "old": old.name, "new": new, "parked": parked}
    _write_json(journal, {**stage, "state": "swapping"})
    for name in parked:
        os.replace(folder / name, old / name)
    for name in new:
        os.replace(tmp / name, folder / name)
    sync_folder(folder)
    _write_json(journal, {**stage, "state": "done"})
    shutil.rmtree(old, ignore_errors=True)
    shutil.rmtree(tmp, ignore_errors=True)
    journal.unlink()
    sync_folder(folder)


@contextlib.contextmanager
def output_set(folder: str | os.PathLike, *, inputs: Iterable[str | os.PathLike] = (),
               last: str | None = None, replaces: Iterable[str] = (),
               force: bool = False, record: bool = True) -> Iterator[Path]:
    """Yield a temporary folder; what the body writes into it becomes part of ``folder`` as
    one set once the body is done.

    The one mechanism of every output (product saves, ``report``, ``apply``, ``hdr``,
    ``change``, ``simulate``): the body writes into a hidden ``.ccdcore-tmp-…-<pid>`` folder in
    ``folder`` (or beside it when ``folder`` does not exist yet, which then becomes it by one
    rename), so a full disk, an error, Ctrl+C or SIGTERM while writing leaves the earlier
    outputs untouched and removes the temporary folder; only then are the new entries renamed
    into ``folder`` (SIGTERM waits until the renames are done). Entries of ``folder`` the body
    did not write are left alone, except those named in ``replaces`` (the parts of an earlier
    set, removed); ``last`` is renamed in last (a description of the set). An existing entry
    is replaced, and an entry of ``replaces`` removed, only when ccdcore wrote it there (the
    folder's :data:`RECORD`; ``force``: the caller took the folder as it is, ``simulate
    --force``; ``record=False``: no :data:`RECORD` is written, for a set that marks itself,
    as a simulated session does with its truth.json). A run killed at any moment (SIGKILL) leaves
    the earlier set or the new one: the next write into the same place finishes or undoes its swap
    (:func:`recover_swaps`) and removes its temporary folders, and only folders marked as ours.

    Before anything is written, each entry's target is checked (:func:`check_output`, and
    :func:`check_not_inputs` against ``inputs``); errors name ``folder``'s entries, never the
    temporary folder.

    Raises
    ------
    CcdError
        ``folder`` is not a folder, an output is a special file or an input, or writing failed
        (the message names the path the user gave and the system's reason).
    """
    folder = Path(os.path.abspath(folder))
    inputs = list(inputs)
    check_outputs(folder, (), inputs)
    home = folder if folder.is_dir() else folder.parent
    try:
        home.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(home)
        if home != folder.parent and folder.parent.is_dir():
            remove_stale_temporaries(folder.parent)
        tmp = _temp_folder(home)
    except OSError as exc:
        raise CcdError(folder, f"cannot write into the folder: {os_problem(exc)}") from None
    state = {"defer": False, "pending": False}

    def on_term(signum: int, frame: Any) -> None:
        if state["defer"]:
            state["pending"] = True
        else:
            raise _Terminated()

    previous = None
    with contextlib.suppress(ValueError):  # not the main thread: signals cannot be handled here
        previous = signal.signal(signal.SIGTERM, on_term)
    try:
        try:
            yield tmp
            check_outputs(folder, {n: (tmp / n).is_dir() for n in os.listdir(tmp)
                                   if n not in (MARK, RECORD)}, inputs, owned=not force)
            if not force and folder.is_dir():
                _check_replaced(folder, replaces)
            state["defer"] = True
            _swap_in(tmp, folder, last, tuple(replaces), force, record)
        except _Terminated:
            raise SystemExit(128 + signal.SIGTERM) from None
        except CcdError as err:
            raise _renamed(err, tmp, folder) from None
        except OSError as exc:
            raise CcdError(folder, "cannot write the outputs: "
                                   f"{os_problem(exc, tmp, folder)}") from None
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    if state["pending"]:
        raise SystemExit(128 + signal.SIGTERM)


def write_outputs(folder: str | os.PathLike, writers: Mapping[str, Callable[[Path], Any]], *,
                  inputs: Iterable[str | os.PathLike] = (), last: str | None = None
                  ) -> list[Path]:
    """Write the files ``name -> writer(path)`` into ``folder`` as one set (:func:`output_set`);
    the paths written, in ``folder``."""
    folder = Path(folder)
    with output_set(folder, inputs=inputs, last=last) as tmp:
        for name, writer in writers.items():
            writer(tmp / name)
    return [folder / name for name in writers]
