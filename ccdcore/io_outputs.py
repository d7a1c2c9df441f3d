"""Output sets for :mod:`ccdcore.io`: every write of a verb as one set (a temporary folder swapped
in), never over an input of the run nor over a FIFO or a device. Re-exported by :mod:`ccdcore.io`.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import signal
import stat
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping

from .errors import CcdError, ImageWriteError
from .io_base import os_problem, sync_folder

__all__ = ["TEMP_PREFIX", "real_path", "check_output", "check_not_inputs", "check_outputs",
           "remove_stale_temporaries", "output_set", "write_outputs"]


# --------------------------------------------------------------------------------------------
# output sets: every write of a verb as one set, never over an input nor a special file
# --------------------------------------------------------------------------------------------
#: the prefix of the temporary folders an output set is written into (removed on failure, on
#: SIGTERM, and by the next write into the same folder once the process that made it is gone)
TEMP_PREFIX = ".ccdcore-tmp-"


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
                  inputs: Iterable[str | os.PathLike] = ()) -> None:
    """Check the outputs ``folder/name`` of a run before anything is computed or written:
    ``folder`` a folder (or absent) neither an input nor inside one, each output a regular
    file (a folder where ``names`` maps the name to ``True``) or absent, and none equal to,
    inside or containing an input (:func:`check_output`, :func:`check_not_inputs`).

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


class _Terminated(BaseException):
    """SIGTERM while an output set is written: unwinds like KeyboardInterrupt so the temporary
    folder goes."""


def remove_stale_temporaries(folder: str | os.PathLike) -> None:
    """Remove the temporary folders killed writes left in ``folder`` (not those of live
    processes: their name ends with the writer's process id)."""
    for p in Path(folder).glob(f"{TEMP_PREFIX}*"):
        pid = p.name.rsplit("-", 1)[-1]
        if pid.isdigit() and int(pid) != os.getpid() and _alive(int(pid)):
            continue
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


def _swap_in(tmp: Path, folder: Path, last: str | None, replaces: Iterable[str]) -> None:
    """Move the entries of ``tmp`` into ``folder`` (or ``tmp`` onto ``folder`` when there is
    none yet); a folder entry replaces the earlier one whole; the entries ``replaces`` of the
    earlier set go even when not written again; ``last`` goes last, and its earlier version
    first (so ``folder`` is never a mix of two sets that ``last`` describes)."""
    if not folder.exists():
        os.chmod(tmp, 0o755)
        os.replace(tmp, folder)
        return
    names = sorted(n for n in os.listdir(tmp) if n != last)
    old = Path(tempfile.mkdtemp(prefix=f"{TEMP_PREFIX}old-", suffix=f"-{os.getpid()}",
                                dir=folder))
    if last is not None and os.path.lexists(folder / last):
        os.replace(folder / last, old / last)
    for name in replaces:
        if name != last and name not in names and os.path.lexists(folder / name):
            os.replace(folder / name, old / name)
    for name in names:
        dst = folder / name
        if (tmp / name).is_dir() and dst.is_dir() and not dst.is_symlink():
            os.replace(dst, old / name)
        os.replace(tmp / name, dst)
    if last is not None and os.path.lexists(tmp / last):
        os.replace(tmp / last, folder / last)
    shutil.rmtree(old, ignore_errors=True)
    shutil.rmtree(tmp, ignore_errors=True)
    sync_folder(folder)


@contextlib.contextmanager
def output_set(folder: str | os.PathLike, *, inputs: Iterable[str | os.PathLike] = (),
               last: str | None = None, replaces: Iterable[str] = ()) -> Iterator[Path]:
    """Yield a temporary folder; what the body writes into it becomes part of ``folder`` as
    one set once the body is done.

    The one mechanism of every output (product saves, ``report``, ``apply``, ``hdr``,
    ``change``, ``simulate``): the body writes into a hidden ``.ccdcore-tmp-…-<pid>`` folder in
    ``folder`` (or beside it when ``folder`` does not exist yet, which then becomes it by one
    rename), so a full disk, an error, Ctrl+C or SIGTERM while writing leaves the earlier
    outputs untouched and removes the temporary folder; only then are the new entries renamed
    into ``folder`` (SIGTERM waits until the renames are done). Entries of ``folder`` the body
    did not write are left alone, except those named in ``replaces`` (the parts of an earlier
    set, removed); ``last`` is renamed in last (a description of the set). Leftovers of a killed process (SIGKILL) are removed by the
    next write into the same place.

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
        tmp = Path(tempfile.mkdtemp(prefix=TEMP_PREFIX, suffix=f"-{os.getpid()}", dir=home))
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
            check_outputs(folder, {n: (tmp / n).is_dir() for n in os.listdir(tmp)}, inputs)
            state["defer"] = True
            _swap_in(tmp, folder, last, tuple(replaces))
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
