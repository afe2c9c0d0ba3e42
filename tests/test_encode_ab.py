"""benchmarks/encode_ab.py's parts that run without a fit: the hidden optional packages and the case checks."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tetweave_codec.benchmarks import encode_ab


def test_hidden_modules_fail_to_import_first_on_the_path(tmp_path):
    folder = encode_ab.hidden_modules(["json"], tmp_path)
    code = "import json"
    done = subprocess.run([sys.executable, "-c", code], env={"PYTHONPATH": str(folder)}, capture_output=True, text=True)
    assert done.returncode != 0 and "hidden by encode_ab --without" in done.stderr
    assert encode_ab.hidden_modules([], tmp_path) is None


def test_a_case_on_an_unknown_mesh_stops_before_any_encode(tmp_path):
    (tmp_path / "ball.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    with pytest.raises(SystemExit, match="no mesh named teapot"):
        encode_ab.main(["HEAD", "--meshes", str(tmp_path), "--cases", "ball:10k,teapot:5k"])
