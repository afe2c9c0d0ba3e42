"""The crossing check kept across restore rounds (decoder/intersect.c tw_self_intersecting_kept, tw_check_state)
gives tw_self_intersecting's status and flags, call after call, while vertices move: small moves (the first cell
size kept), moves that cross the median extent (the lattice moves, the count follows), moves of the extreme
vertices and degenerate faces (the state computed afresh), crossings, on one thread and on three."""

from __future__ import annotations

import ctypes
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

from tests.core_lib import CORE, FLAGS, require_compiler

HARNESS = Path(__file__).resolve().parent / "core_kept_harness.c"
P = ctypes.c_void_p


@pytest.fixture(scope="module")
def lib():
    cc = require_compiler()
    out = Path(tempfile.mkdtemp(prefix="twkept")) / "libtwkept.so"
    cmd = [cc, *FLAGS, f"-I{CORE}", "-o", str(out), str(HARNESS), str(CORE / "common.c"), "-lm", "-pthread"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    lib = ctypes.CDLL(str(out))
    lib.tw_check_state_new.restype = P
    lib.tw_check_state_free.argtypes = [P]
    lib.tw_self_intersecting.argtypes = [P, ctypes.c_size_t, P, ctypes.c_size_t, P, ctypes.c_int, ctypes.c_int, P]
    lib.tw_self_intersecting_kept.argtypes = [
        P, P, ctypes.c_size_t, P, ctypes.c_size_t, P, P, ctypes.c_int, ctypes.c_int, P,
    ]  # fmt: skip
    lib.tw_test_kept_info.restype = ctypes.c_double
    lib.tw_test_kept_info.argtypes = [P, P]
    return lib


def torus(nu: int, nw: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """A closed torus of 2 nu nw faces, its vertices jittered (no ties between the faces' extents)."""
    u, w = np.meshgrid(np.arange(nu) * 2 * np.pi / nu, np.arange(nw) * 2 * np.pi / nw, indexing="ij")
    v = np.stack([(2 + np.cos(w)) * np.cos(u), (2 + np.cos(w)) * np.sin(u), np.sin(w)], -1).reshape(-1, 3)
    v = v + rng.normal(0, 0.002, v.shape)
    i, j = np.meshgrid(np.arange(nu), np.arange(nw), indexing="ij")
    a, b = i * nw + j, ((i + 1) % nu) * nw + j
    c, d = ((i + 1) % nu) * nw + (j + 1) % nw, i * nw + (j + 1) % nw
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return np.ascontiguousarray(v), np.ascontiguousarray(f.astype(np.int32))


def check(lib, v, f, only, threads):
    flags = np.zeros(len(f), np.uint8)
    status = lib.tw_self_intersecting(v.ctypes.data, len(v), f.ctypes.data, len(f), only.ctypes.data, 4, threads,
                                      flags.ctypes.data)  # fmt: skip
    return status, flags


@pytest.mark.parametrize("threads", [1, 3])
def test_kept_rounds_match_fresh_checks(lib, threads):
    rng = np.random.default_rng(7 + threads)
    v, f = torus(160, 90, rng)
    extent = (v[f].max(1) - v[f].min(1)).max(1)
    median = np.median(extent)
    state = lib.tw_check_state_new()
    try:
        incremental = moved_lattice = flagged = 0
        cell = 0.0
        changed = np.zeros(len(f), np.uint8)
        for round_ in range(40):
            moved = np.zeros(len(v), bool)
            kind = round_ % 8
            pick = rng.choice(len(v), 1 + rng.integers(0, 40), replace=False)
            if kind == 5:  # a vertex of the box's corner: origin / top move (computed afresh)
                pick = np.array([int(np.argmin(v[:, 0]))])
            if kind == 6:  # a face made degenerate (validity changes: computed afresh)
                a, b, _ = f[rng.integers(len(f))]
                v[b] = v[a]
                pick = np.array([b])
            elif kind in (0, 1, 2):  # small moves: faces' extents barely change
                v[pick] += rng.normal(0, 1e-5, (len(pick), 3))
            elif kind in (3, 4):  # extents across the median: the cell size moves a few ranks, the lattice with it
                pick = pick[:3]
                v[pick] += rng.normal(0, median, (len(pick), 3))
            elif kind == 7:  # through the torus: crossings
                v[pick] *= np.array([1.0, 1.0, -1.0])
            moved[pick] = True
            changed[:] = moved[f].any(1)
            only = changed.copy()
            only[rng.choice(len(f), 20, replace=False)] = 1  # faces flagged at the last check
            status, want = check(lib, v, f, only, threads)
            got = np.zeros(len(f), np.uint8)
            first = round_ == 0
            kept = lib.tw_self_intersecting_kept(state, v.ctypes.data, len(v), f.ctypes.data, len(f),
                                                 only.ctypes.data, None if first else changed.ctypes.data, 4, threads,
                                                 got.ctypes.data)  # fmt: skip
            assert (kept, got.tobytes()) == (status, want.tobytes()), f"round {round_}"
            info = np.zeros(4, np.int64)
            last, cell = cell, lib.tw_test_kept_info(state, info.ctypes.data)
            incremental += bool(info[0] and info[1] and info[2])
            moved_lattice += bool(info[0] and info[1] and info[2] and cell != last)
            flagged += int(want.sum())
        assert incremental >= 10  # most rounds moved the state rather than computing it afresh
        assert moved_lattice >= 2  # among them, rounds whose cell size changed
        assert flagged > 0
    finally:
        lib.tw_check_state_free(state)


def test_kept_follows_only_its_own_calls(lib):
    """A check of many marked faces (not through the state) drops it; a NULL `changed` computes it afresh."""
    rng = np.random.default_rng(3)
    v, f = torus(80, 40, rng)
    state = lib.tw_check_state_new()
    try:
        only = np.zeros(len(f), np.uint8)
        only[:50] = 1
        got = np.zeros(len(f), np.uint8)
        assert lib.tw_self_intersecting_kept(state, v.ctypes.data, len(v), f.ctypes.data, len(f), only.ctypes.data,
                                             None, 4, 1, got.ctypes.data) == 0  # fmt: skip
        info = np.zeros(4, np.int64)
        lib.tw_test_kept_info(state, info.ctypes.data)
        assert info[0] == 1 and info[3] == len(f)
        many = np.ones(len(f), np.uint8)
        v[f[0]] += 0.3  # moved while the state does not look
        status, want = check(lib, v, f, many, 1)
        assert lib.tw_self_intersecting_kept(state, v.ctypes.data, len(v), f.ctypes.data, len(f), many.ctypes.data,
                                             None, 4, 1, got.ctypes.data) == status  # fmt: skip
        assert got.tobytes() == want.tobytes()
        lib.tw_test_kept_info(state, info.ctypes.data)
        assert info[0] == 0
        status, want = check(lib, v, f, only, 1)
        changed = np.zeros(len(f), np.uint8)
        assert lib.tw_self_intersecting_kept(state, v.ctypes.data, len(v), f.ctypes.data, len(f), only.ctypes.data,
                                             changed.ctypes.data, 4, 1, got.ctypes.data) == status  # fmt: skip
        assert got.tobytes() == want.tobytes()
    finally:
        lib.tw_check_state_free(state)
