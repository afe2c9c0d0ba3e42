"""The license claim of README ("License"): encode and decode load no GPL or AGPL module.

tetweave is Apache-2.0 because nothing encode or decode runs is copyleft: the Delaunay is tetweave's own
(geometry/_delaunay_native.c), and of libigl's wheel (which also ships GPL bindings) only the MPL-2.0 core is
imported. A fresh interpreter encodes a small sphere through the command line, decodes the file, and reports every
module it loaded; the test fails if any of them is copyleft.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import trimesh

# Module name prefixes that are GPL / AGPL: TetGen (tetgenpy, libigl's igl.copyleft.tetgen), CGAL
# (igl.copyleft.cgal), Triangle (igl.triangle, non-commercial), MeshLab (pymeshlab).
COPYLEFT = ("tetgenpy", "igl.copyleft", "igl.triangle", "pymeshlab")

SCRIPT = """
import json, sys
from tetweave_codec.cli.main import main
for args in ({encode!r}, {decode!r}):
    try:
        main(args, standalone_mode=False)
    except SystemExit as exc:
        if exc.code:
            raise
print(json.dumps(sorted(sys.modules)))
"""


def test_encode_and_decode_load_no_copyleft_module(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=2)
    src = tmp_path / "ball.obj"
    mesh.export(src)
    encode = ["encode", str(src), "-o", str(tmp_path / "b.tw"), "--points", "512", "--quality", "fast"]
    encode += ["--iters", "20", "--surface", "all"]
    decode = ["decode", str(tmp_path / "b.tw"), "-o", str(tmp_path / "b.obj")]
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT.format(encode=encode, decode=decode)], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]
    loaded = json.loads(done.stdout.strip().splitlines()[-1])
    assert (tmp_path / "b.obj").exists()
    bad = [m for m in loaded if m.startswith(COPYLEFT)]
    assert not bad, f"copyleft modules loaded by encode + decode: {bad}"
    # The check can fail: the decode really ran the exact Delaunay.
    assert "tetweave_codec.geometry._delaunay_native" in loaded
    assert np.isfinite(np.loadtxt(tmp_path / "b.obj", usecols=(1, 2, 3), comments=("#", "f"))).all()
