"""A decode is the same mesh on any thread count (issue 47, item 2): the committed bench files and a perturbed one
decode to the same bytes with the crossing checks on 1, 2 and 4 threads, through the API and `tetweave decode
--threads`; a thread count out of range is a usage error."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tetweave_codec.decoder import decode, decode_detailed
from tetweave_codec.formats.tw import unpack
from tetweave_codec.formats.tw2 import pack_v2
from tetweave_codec.geometry import intersections

ROOT = Path(__file__).resolve().parents[1]
FILES = ROOT / "benchmarks/results/files"
needs_native = pytest.mark.skipif(intersections._intersect_native is None, reason="_intersect_native not built")


def digest(vertices: np.ndarray, faces: np.ndarray) -> str:
    return hashlib.sha256(vertices.tobytes() + faces.tobytes()).hexdigest()


def perturbed(path: Path, seed: int) -> bytes:
    """The file at `path` with 30 % of its SH symbols moved by up to 6 steps: a surface whose smoothing makes faces
    cross (the stanford-bunny 10 KB file with seed 2: 71 vertices restored over several checks)."""
    tw = unpack(path.read_bytes())
    rng = np.random.default_rng(seed)
    c = np.array(tw.c_sym, copy=True)
    pick = rng.random(c.shape) < 0.3
    c[pick] += rng.integers(-6, 7, int(pick.sum()))
    return pack_v2(replace(tw, c_sym=c))


@needs_native
@pytest.mark.parametrize(
    "name",
    [
        "fandisk/size-10240-sh-auto.tw",  # three crease-preserving Taubin steps: the full grid check
        "igea/size-10240-sh-auto.tw",  # one Loop level: the patch check
        "stanford-bunny/size-40960-sh-auto.tw",  # 320K faces, five restore rounds: the marked faces' checks
    ],
)
def test_committed_files_decode_to_the_same_bytes_on_any_thread_count(name):
    data = (FILES / name).read_bytes()
    results = {t: decode_detailed(data, threads=t) for t in (1, 2, 4)}
    hashes = {t: digest(r.vertices, r.faces) for t, r in results.items()}
    assert len(set(hashes.values())) == 1, hashes
    assert len({r.restored for r in results.values()}) == 1
    if name.startswith("stanford-bunny"):
        assert results[1].restored > 0  # the later checks ran


@needs_native
def test_a_perturbed_file_decodes_to_the_same_bytes_on_any_thread_count():
    data = perturbed(FILES / "stanford-bunny/size-10240-sh-auto.tw", seed=2)
    results = {t: decode_detailed(data, threads=t) for t in (1, 2, 4, 0)}
    assert results[1].restored > 0
    assert len({digest(r.vertices, r.faces) for r in results.values()}) == 1
    for level in ("control", "smoothed"):  # the other levels' checks too
        assert len({digest(*decode(data, level=level, threads=t)) for t in (1, 3)}) == 1


def test_a_negative_thread_count_is_refused():
    data = (FILES / "spot/size-5120-sh-auto.tw").read_bytes()
    with pytest.raises(ValueError, match="threads"):
        decode(data, threads=-1)
    with pytest.raises(ValueError, match="threads"):
        intersections.resolve_threads(1.5)
    assert intersections.resolve_threads(0) >= 1 and intersections.resolve_threads(3) == 3


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "tetweave_codec.cli.main", *args], capture_output=True, text=True)


@pytest.mark.parametrize("value", ["-1", "1025", "two"])
def test_threads_out_of_range_is_a_usage_error(tmp_path, value):
    out = tmp_path / "out.obj"
    done = run("decode", str(FILES / "spot/size-5120-sh-auto.tw"), "-o", str(out), "--threads", value)
    assert done.returncode == 2
    assert "--threads" in done.stderr and "Traceback" not in done.stderr
    assert not out.exists()


@needs_native
def test_the_command_writes_the_same_file_on_one_and_two_threads(tmp_path):
    src = FILES / "igea/size-5120-sh-auto.tw"
    written = []
    for threads in ("1", "2", "0"):
        out = tmp_path / f"t{threads}.ply"
        done = run("decode", str(src), "-o", str(out), "--threads", threads)
        assert done.returncode == 0, done.stderr
        written.append(out.read_bytes())
    assert written[0] == written[1] == written[2]


def test_the_decode_command_bounds_threads_as_the_others_do():
    from tetweave_codec.cli import common, decode

    assert decode.MAX_THREADS == common.MAX_THREADS


def test_the_decode_command_imports_neither_torch_nor_scipy_nor_the_fit(tmp_path):
    """`tetweave decode`'s fixed cost is Python, numpy and click: the command imports no module it does not use."""
    code = (
        "import sys\n"
        "from tetweave_codec.cli.main import main\n"
        "try:\n"
        f"    main(['decode', {str(FILES / 'spot/size-5120-sh-auto.tw')!r}, '-o', {str(tmp_path / 'o.obj')!r}])\n"
        "except SystemExit:\n"
        "    pass\n"
        "print('modules:', *sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'scipy', 'trimesh') "
        "or m.startswith(('tetweave_codec.fit', 'tetweave_codec.cli.common'))))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "o.obj").exists()
    assert done.stdout.splitlines()[-1] == "modules:"
