"""The bounds of the result cache (:mod:`ccdcore_app.cache.store`) checked before anything of a
file is read: an entry's declared sizes (a few MB that would inflate to GB), the index's size.

Public objects
--------------
entry_size_problem(path)
    Why an entry may not be loaded, from its declared sizes alone, or None.
MAX_INDEX_BYTES
    The largest content-hash index read.
"""
from __future__ import annotations

import os

import numpy as np

__all__ = ["entry_size_problem", "MAX_INDEX_BYTES"]


#: the largest content-hash index read (this cache writes a few hundred bytes per session)
MAX_INDEX_BYTES = 16 * 2 ** 20


def entry_size_problem(path: str | os.PathLike) -> str | None:
    """Why an entry may not be loaded, from its declared sizes alone, or None.

    Entries are written uncompressed (``np.savez``): every member is stored, and each array's
    header declares exactly the bytes its member holds. A member compressed (a few MB that
    inflate to GB), or an array header declaring more bytes than its member holds (NumPy would
    allocate the declared size first), is not an entry of this cache, and nothing of it is
    read."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                if info.compress_type != zipfile.ZIP_STORED or \
                        info.file_size != info.compress_size:
                    return f"{info.filename}: compressed ({info.compress_size} bytes declared " \
                           f"to inflate to {info.file_size})"
                if not info.filename.endswith(".npy"):
                    continue
                with zf.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read_header(f, max_header_size=2 ** 16)
                    declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
                if declared > info.file_size:
                    return f"{info.filename}: declares {declared} bytes in a member of " \
                           f"{info.file_size}"
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        return f"unreadable: {err}"
    return None
