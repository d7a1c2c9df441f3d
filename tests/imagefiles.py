"""Image files the tests need that no writer makes: a small TIFF declaring a huge image."""
from __future__ import annotations

import struct
import zlib
from pathlib import Path


def bomb_tiff(path: Path, width: int, height: int, rows: int = 256, pad: int = 1_500_000):
    """A real deflate TIFF of ``width x height`` zeros that takes about ``pad`` bytes on disk.

    Every strip points at the same compressed block of zeros, so the file is written in
    milliseconds; ``pad`` trailing bytes keep the compression ratio near deflate's real ~1000:1
    (OpenImageIO refuses to open a file claiming a far higher ratio).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    blob = zlib.compress(bytes(width * rows), 9)
    n = -(-height // rows)
    offsets_at = 8 + len(blob)
    counts_at = offsets_at + 4 * n
    ifd_at = counts_at + 4 * n
    tags = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, 8), (259, 3, 1, 8),
            (262, 3, 1, 1), (273, 4, n, offsets_at), (277, 3, 1, 1), (278, 4, 1, rows),
            (279, 4, n, counts_at), (284, 3, 1, 1)]
    ifd = (struct.pack("<H", len(tags)) + b"".join(struct.pack("<HHII", *t) for t in tags)
           + struct.pack("<I", 0))
    path.write_bytes(b"II*\x00" + struct.pack("<I", ifd_at) + blob
                     + struct.pack(f"<{n}I", *[8] * n) + struct.pack(f"<{n}I", *[len(blob)] * n)
                     + ifd + bytes(pad))
    return path
