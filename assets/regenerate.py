"""Regenerate the bundled demo sessions.

    .venv/bin/python -m assets.regenerate            # all presets (or: assets/regenerate.py)
    .venv/bin/python -m assets.regenerate healey94   # one

Each demo is ``ccdcore.simulate.simulate(preset, assets/<preset>, seed=DEMO_SEED,
**DEMOS[preset])`` (:mod:`ccdcore.simulate.demos`, which also writes them for an installed package).  The simulators' bytes do not depend on the CPU's vector features (AVX2,
AVX-512, NEON): digital numbers are computed without NumPy's CPU-dispatched vector functions,
and truth.json's floats carry 12 significant digits.  ``tests/test_assets.py`` checks
that the committed files are what this writes: frames, masks and ``session.toml`` byte for byte,
the float32 true maps to one float32 ulp and ``truth.json`` to one unit in the 12th significant
digit (the margin for a value that an ulp upstream could round either way).
"""
from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from ccdcore.simulate.demos import DEMO_SEED, DEMOS, write_demo  # noqa: E402,F401


def regenerate(preset: str, out_root: Path = HERE) -> Path:
    return write_demo(preset, out_root)


def main(argv: list[str]) -> None:
    for preset in argv or list(DEMOS):
        out = regenerate(preset)
        size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
        print(f"{preset}: {out} ({size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main(sys.argv[1:])
