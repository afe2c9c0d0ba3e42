"""The whole C decoder core (tw_decode: parse, exact Delaunay, marching tets, filter, holes) on hostile files.

benchmarks/fuzz.py's corpus (analytic seed files, a few hundred structure-aware mutations with a valid CRC, and
its hostile files: huge declared counts, holes sections that name more faces than the surface has) goes through
tests/core_decode_harness.c built with -fsanitize=address,undefined -fno-sanitize-recover=all, one child process
per file: every file must end normally (no crash, no sanitizer report, no leak) in a clear error or a mesh, and
agree with the Python pipeline (decoder.CORE off, the reference): the same error class, or the same vertices and
faces bit for bit. A plain build under RLIMIT_AS shows the hostile files refused before their counts are
allocated (small peak RSS). Skipped cleanly without a C compiler or sanitizer support.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from tetweave_codec import decoder
from tetweave_codec.benchmarks import fuzz
from tetweave_codec.errors import ContainerError

ROOT = Path(__file__).resolve().parent.parent
MUTATIONS = 360  # cases of the campaign's generator (seed SEED), on top of the seed and hostile files
SEED = 11
LIMIT_MB = 2048  # the memory cap of each decode: RLIMIT_AS (plain build), largest allocation (ASan)
OK, INVALID, UNSUPPORTED, LIMIT = 0, 1, 2, 3


def committed_exact_files() -> list[Path]:
    names = subprocess.run(["git", "ls-files", "*.tw"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    return [ROOT / n for n in sorted(names) if "legacy" not in n]


@pytest.fixture(scope="module")
def corpus() -> list[tuple[str, bytes]]:
    seeds = fuzz.seed_files(seed=0, max_points=300, backends=("exact",) * 3)  # the core's files only
    blobs = [b for _, b in seeds]
    cases = [(f"case-{i}", fuzz.mutate(np.random.default_rng([SEED, i]), blobs)[1]) for i in range(MUTATIONS)]
    smallest = [(p.name, p.read_bytes()) for p in committed_exact_files() if "size-5120" in str(p)]
    return seeds + fuzz.hostile_files(seeds) + cases + smallest


def _built(tmp_path_factory, sanitize: bool) -> Path:
    if fuzz.harness_compiler() is None:
        pytest.skip("no C compiler (install gcc or clang) to build the decoder core")
    exe = fuzz.build_harness(tmp_path_factory.mktemp("harness"), sanitize=sanitize)
    if exe is None:
        pytest.skip("the C compiler cannot build the harness" + (" with ASan + UBSan" if sanitize else ""))
    return exe


@pytest.fixture(scope="module")
def sanitized(tmp_path_factory) -> Path:
    return _built(tmp_path_factory, True)


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> Path:
    return _built(tmp_path_factory, False)


def reference(data: bytes, level: str):
    """The Python pipeline's answer: its (vertices, faces), or the exception it raised."""
    saved = decoder.CORE
    decoder.CORE = False
    try:
        return decoder.decode_detailed(data, level=level)
    except Exception as exc:  # noqa: BLE001 -- compared with the core's status
        return exc
    finally:
        decoder.CORE = saved


def check_against_reference(rows, corpus, out: Path, level: str) -> dict[str, int]:
    seen = {"ok": 0, "refused": 0, "earlier": 0}
    for i, ((name, data), row) in enumerate(zip(corpus, rows, strict=True)):
        assert row.status < fuzz.HARNESS_DEAD and not row.report, (name, row.status, row.report[-3000:])
        if row.status == UNSUPPORTED:  # an earlier encoder's file: the Python pipeline decodes it
            seen["earlier"] += 1
            continue
        ref = reference(data, level)
        if row.status in (INVALID, LIMIT):
            assert isinstance(ref, ContainerError), (name, row.message, ref)
            assert row.message and "\n" not in row.message
            seen["refused"] += 1
            continue
        assert row.status == OK, (name, row.status, row.message)
        assert not isinstance(ref, Exception), (name, ref)
        vertices = np.fromfile(out / f"{i}.v", dtype=np.float64).reshape(-1, 3) if row.faces else np.zeros((0, 3))
        faces = np.fromfile(out / f"{i}.f", dtype=np.uint32).reshape(-1, 3) if row.faces else np.zeros((0, 3))
        assert (len(vertices), len(faces)) == (row.vertices, row.faces)
        assert np.array_equal(vertices, ref.vertices), name  # bit for bit: float64 equality, no NaN
        assert np.array_equal(faces.astype(np.int64), ref.faces), name
        seen["ok"] += 1
    return seen


def test_corpus_under_sanitizers_is_the_reference(sanitized, corpus, tmp_path):
    rows, stderr = fuzz.run_harness(sanitized, [d for _, d in corpus], level=2, limit_mb=LIMIT_MB, out=tmp_path)
    seen = check_against_reference(rows, corpus, tmp_path, "full")
    assert "ERROR: AddressSanitizer" not in stderr and "runtime error" not in stderr, stderr[-3000:]
    assert seen["ok"] >= 60 and seen["refused"] >= 250 and seen["earlier"] >= 10, seen


@pytest.mark.parametrize("level", [0, 1])
def test_decoded_files_at_the_lower_levels_under_sanitizers(sanitized, corpus, tmp_path, level):
    """The files the core decodes, at the control and smoothed levels (no Loop: another path through the filter)."""
    ok = [(name, data) for name, data in corpus if not isinstance(reference(data, "full"), Exception)]
    ok = [(name, data) for name, data in ok if data[12] & 0x40][:60]  # exact files: the core's own
    rows, _ = fuzz.run_harness(sanitized, [d for _, d in ok], level=level, limit_mb=LIMIT_MB, out=tmp_path)
    seen = check_against_reference(rows, ok, tmp_path, decoder.LEVELS[level])
    assert seen["ok"] >= 40, seen


def test_hostile_counts_are_refused_before_allocation(plain, corpus):
    """Under RLIMIT_AS every hostile file ends in a clear error (or, for the valid ones, a mesh) in a few MiB:
    2^22 declared points over a seed's sections, 64 N hole faces against a surface of a few hundred."""
    hostile = [(n, d) for n, d in corpus if n.startswith(("points-", "holes-", "empty-"))]
    rows, _ = fuzz.run_harness(plain, [d for _, d in hostile], limit_mb=LIMIT_MB, sanitized=False)
    by_name = dict(zip((n for n, _ in hostile), rows, strict=True))
    for name, row in by_name.items():
        assert row.status in (OK, INVALID), (name, row)
        if name in ("holes-every-face", "holes-top-rank"):
            assert row.status == OK
        else:
            assert row.status == INVALID and row.message, (name, row)
        # 2^22 points allocate O(N (4 + q)) address space the octree never touches; hole faces are refused unread
        assert row.peak_rss_kib < 64 * 1024, (name, row)
    assert "hole faces for a surface of" in by_name["holes-max-k"].message
    assert "hole face rank" in by_name["holes-rank-f0"].message


def test_committed_files_decode_within_the_memory_cap(plain):
    """The largest committed file decodes under RLIMIT_AS with the peak RSS formats/README.md states (< 128 MiB)."""
    files = committed_exact_files()
    rows, _ = fuzz.run_harness(plain, [p.read_bytes() for p in files], limit_mb=LIMIT_MB, sanitized=False)
    assert all(r.status == OK and r.faces > 0 for r in rows), [(p.name, r) for p, r in zip(files, rows, strict=True)]
    assert max(r.peak_rss_kib for r in rows) < 128 * 1024


def test_deferred_holes_match_the_reference_messages(corpus):
    """Through the extension (decoder.decode): a rank >= F0 is the reference's message; K > F0, refused before the
    ranks are read, and a holes section on an empty surface are ContainerErrors as there."""
    if not decoder.CORE:
        pytest.skip("the decoder core's extension is not built")
    named = dict(corpus)
    for name in ("holes-rank-f0", "holes-rank-2^32-1", "holes-k-over-f0", "holes-max-k", "empty-holes"):
        ref = reference(named[name], "full")
        assert isinstance(ref, ContainerError)
        with pytest.raises(ContainerError) as got:
            decoder.decode(named[name])
        if "rank" in name:
            assert str(got.value) == str(ref), name
    assert fuzz.pipeline_difference(named["holes-top-rank"], ("control", "smoothed", "full")) is None
