"""The demo sessions: the committed ``assets/`` of a checkout, written again on demand.

A checkout carries the demos in ``assets/`` (``assets/regenerate.py`` writes them from here, and
``tests/test_assets.py`` checks the committed files are what it writes). An installed package
(``pip install ccdcore``) carries no data files: :func:`ensure_demos` writes the same sessions
into a folder of the user's (the simulators give the same bytes for the same seed on every CPU),
about 3 s and 7 MB once, so ``ccdcore app`` shows its demos after a plain ``pip install``.

Public objects
--------------
DEMO_SEED, DEMOS
    The seed and the per-preset options of every demo.
write_demo(preset, root)
    Write one demo into ``root/<preset>`` (replacing an earlier one).
ensure_demos(root)
    Write the demos missing from ``root``; each appears whole or not at all.
user_demos_dir()
    Where an installed package keeps its demos: ``$XDG_DATA_HOME/ccdcore/demos``
    (``~/.local/share/ccdcore/demos``).
"""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Callable, Iterable

__all__ = ["DEMO_SEED", "DEMOS", "write_demo", "ensure_demos", "user_demos_dir"]

DEMO_SEED = 1994
#: preset -> options for the demo (small enough to commit: all of assets/ stays well under 20 MB)
DEMOS: dict[str, dict] = {
    "healey94": {"size": (256, 192)},
    "delasarte07": {},
    "tsin01": {},
    "tsin01-camera": {"size": (192, 128)},        # RGB, 10 exposures one stop apart, ~1 MB
    "change": {},
    "emva1288": {"size": (96, 64)},               # an EMVA 1288 exposure-time series, ~1 MB
}

#: the file every complete demo holds (written last by the simulators' session writer)
MANIFEST = "session.toml"


def user_demos_dir() -> Path:
    """``$XDG_DATA_HOME/ccdcore/demos``, or ``~/.local/share/ccdcore/demos``."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base).expanduser() / "ccdcore" / "demos"


def write_demo(preset: str, root: str | Path) -> Path:
    """Write the demo ``preset`` into ``root/<preset>``: into a new sibling folder first, then
    swapped in, so a reader never sees half a demo and an interrupted write leaves the earlier
    one (or none)."""
    from . import simulate

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    out = root / preset
    tmp = Path(tempfile.mkdtemp(prefix=f".{preset}-", dir=root))
    try:
        simulate(preset, tmp / preset, seed=DEMO_SEED, **DEMOS[preset])
        if out.exists():
            shutil.rmtree(out)
        (tmp / preset).rename(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def ensure_demos(root: str | Path, presets: Iterable[str] | None = None, *,
                 say: Callable[[str], None] | None = None) -> list[Path]:
    """Write every demo of ``presets`` (all by default) that ``root`` lacks; the demo folders.
    ``say(message)`` hears what is being written (once, before the first)."""
    root = Path(root)
    names = list(DEMOS if presets is None else presets)
    missing = [p for p in names if not (root / p / MANIFEST).is_file()]
    if missing and say is not None:
        say(f"writing the demo sessions {', '.join(missing)} into {root} (once, a few seconds)")
    for preset in missing:
        write_demo(preset, root)
    return [root / p for p in names]
