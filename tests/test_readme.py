"""The README's Python example runs as printed, from a folder that is not the repository."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_the_python_example_runs_from_any_folder(tmp_path):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), re.S)
    assert blocks, "the README has no Python example"
    code = blocks[0]
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.strip().splitlines()
    assert "'dark'" in lines[0] and "'ptc'" in lines[0]
    a, a_err, truth = (float(v) for v in lines[1].split())
    assert abs(a - truth) < 4 * a_err            # the photon-transfer A within its error
    mean, var = (float(v) for v in lines[2].split())
    assert mean > 0 and var > 0
