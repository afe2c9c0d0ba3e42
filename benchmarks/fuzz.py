"""Structure-aware fuzzing of the version-2 decoder: every case must end in a ContainerError or a closed 2-manifold.

Seed files are valid version-2 files: analytic point sets written with `quantize_file` + `pack_v2` (lattice
cells in a shell around a torus or a sphere, 6-12 position bits, SH degrees -1..3, both Delaunay flags, s
predicted or not, octree context-coded (flags bit 2) or not, 0-3 smoothing steps (flags bits 3-4), 0-2 Loop
subdivision levels (bits 5-6); plus the edge
cases N = 0 and N = 1..5) and any real files given with ``--files``. Each case applies 1-3 mutations that know
the layout (header fields, the three section sizes, the sections' bytes) and then, in 95 % of cases, rewrites the
section sizes and recomputes the CRC so that the mutation reaches the parsers behind the checksum:

* ``field``: one header field (flags, SH degree, position bits, N, scale, offset, s step, a c step) set to an
  extreme or boundary value of its type (0, 1, max, max + 1, NaN, inf, subnormal, the value +-1, ...) or to
  a plausible one (the value times 0.25..4); ``backend``: a Delaunay backend bit toggled (flags bit 0 or byte 12 bit 6);
* ``sizes``: a section size field set to an extreme value without moving any byte (the file disagrees);
* ``boundary``: a boundary between two sections moved by 1..64 bytes (or to an extreme), total unchanged;
* ``splice``: a section replaced by the same section of another seed file;
* ``truncate`` / ``extend``: a section shortened or lengthened (zeros, random bytes or a copy of itself);
* ``flip``: 1-16 bit flips inside the sections; ``models``: model bytes (the starts of the sections) set to
  0, 1, 255 or random values; ``random``: one or all sections replaced by random bytes;
* ``file``: the whole file cut or extended (sizes and CRC left alone).

Every case decodes in a worker process (memory capped at ``--memory-gb``) with a time limit, through
`decode_detailed` with the file's own backend flag; a decoded mesh must pass `marching_tets.check_manifold`
(closed) and manifold3d; a file with a holes section (flags bit 7) must pass these on the surface before the holes
were opened, and its result must be a 2-manifold with boundary (every edge of one or two faces, oriented, no
pinched vertex). Every decoded mesh, as returned (in the input's frame, whatever its filter), must then be free of
self-intersections by the decoder's own check and by the independent exact one (benchmarks/exact_check.py:
no two faces meet other than at a shared vertex, touching included). Outcomes: ``rejected``
(ContainerError), ``closed`` (a non-empty closed 2-manifold), ``open`` (holes opened in one), ``empty`` (no
surface: one sign only, or points spanning no volume), and the failures ``non_manifold``, ``self_intersecting``,
``error`` (any other exception, TopologyError included), ``timeout`` and ``crash`` (the worker died).
Case i uses the generator ``numpy.random.default_rng([seed, i])``, so ``--only i`` replays one case.

`decode_detailed` runs the C decoder core (decoder/, through tetweave_codec._decoder_native) on every file of the
current format and the Python pipeline on earlier encoders' files. ``--compare`` also decodes each case with the
Python pipeline (decoder.CORE off, the reference) and reports ``mismatch`` when the two differ: not the same
error class, or not the same vertices, faces, closed surface, extracted faces, tets and restores bit for bit.
``--harness`` also runs every case through tests/core_decode_harness.c, the whole tw_decode built with
-fsanitize=address,undefined -fno-sanitize-recover=all (each file in a child process, allocations over
``--memory-gb`` refused): a sanitizer report or a dead child is a ``crash``, a status that disagrees with the
worker's outcome a ``mismatch`` (checkout only: it compiles decoder/*.c with the C compiler).

    python -m tetweave_codec.benchmarks.fuzz --cases 10000
    python -m tetweave_codec.benchmarks.fuzz --cases 500 --files a.tw b.tw --out fuzz.md
    python -m tetweave_codec.benchmarks.fuzz --only 1234 -v
    python -m tetweave_codec.benchmarks.fuzz --cases 10000 --files-only --files a.tw b.tw c.tw d.tw
    python -m tetweave_codec.benchmarks.fuzz --cases 2000 --compare --harness
"""

from __future__ import annotations

import argparse
import collections
import multiprocessing as mp
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tetweave_codec.formats import quantize as Q
from tetweave_codec.formats.common import (
    BITS_EXACT,
    CHECKSUM_SIZE,
    FLAG_HOLES,
    FLAG_OCTREE_CONTEXTS,
    FLAG_QHULL,
    FLAG_S_PREDICTED,
    seal,
    smoothing_flags,
    subdivision_flags,
)
from tetweave_codec.formats.tw2 import FIXED_SIZE, MAX_POINTS, header_size, pack_v2, quantize_file

FAILURES = ("non_manifold", "self_intersecting", "error", "timeout", "crash", "mismatch")
OUTCOMES = ("rejected", "closed", "open", "empty", *FAILURES)
NO_RESEAL_SHARE = 0.05  # cases whose sizes and CRC are left as the mutations made them
MAX_MUTATIONS = 3
DEFAULT_TIME_LIMIT = 60.0  # seconds per case; a seed file decodes in well under a second
DEFAULT_MEMORY_GB = 6.0

# v2 header fields: name -> (offset, struct format); the c steps follow at FIXED_SIZE + 4 l.
FIELDS = {
    "flags": (10, "<B"),
    "sh_degree": (11, "<b"),
    "position_bits": (12, "<B"),
    "num_points": (13, "<I"),
    "scale": (17, "<d"),
    "offset_x": (25, "<d"),
    "offset_y": (33, "<d"),
    "offset_z": (41, "<d"),
    "s_step": (49, "<f"),
}
EXTREMES = {
    "<B": [0, 1, 2, 3, 4, 5, 6, 7, 15, 16, 17, 127, 128, 254, 255],
    "<b": [-128, -2, -1, 0, 1, 2, 3, 4, 5, 127],
    "<I": [0, 1, 2, 3, 4, 7, 8, 255, 256, MAX_POINTS - 1, MAX_POINTS, MAX_POINTS + 1, 2**31, 2**32 - 1],
    "<d": [0.0, -0.0, 1.0, -1.0, 5e-324, 2.2e-308, 1e308, -1e308, float("inf"), -float("inf"), float("nan")],
    "<f": [0.0, -0.0, 1e-45, 1.1754944e-38, 1.1754942e-38, 1.0, -1.0, 3.4e38, float("inf"), float("nan")],
}


# -----------------------------------------------------------------------------------------------------------
# seed files


def _shell_cells(rng: np.random.Generator, bits: int, count: int, shape: str) -> tuple[np.ndarray, np.ndarray]:
    """Up to `count` distinct lattice cells near a torus or sphere and their signed distances (normalized frame)."""
    m = 1 << bits
    cells = np.unique(rng.integers(0, m, (count * 8, 3)), axis=0)
    pts = Q.dequantize_positions(cells, bits)
    if shape == "torus":
        sdf = np.hypot(np.hypot(pts[:, 0], pts[:, 1]) - 0.55, pts[:, 2]) - 0.25
    else:
        sdf = np.linalg.norm(pts - rng.uniform(-0.2, 0.2, 3), axis=1) - rng.uniform(0.3, 0.8)
    near = np.argsort(np.abs(sdf), kind="stable")[:count]
    return cells[near], sdf[near]


# The Delaunay backends of the seed files, by turns: the exact Delaunay (what the encoder writes), Qhull and
# TetGen (earlier encoders' files); LEGACY_BACKENDS is the list before the exact Delaunay, which replays the
# campaigns recorded then.
BACKENDS = ("exact", "qhull", "tetgen")
LEGACY_BACKENDS = ("tetgen", "qhull", "tetgen")


def seed_files(
    seed: int = 0, max_points: int = 3000, holes: bool = True, backends: tuple[str, ...] = BACKENDS
) -> list[tuple[str, bytes]]:
    """Valid version-2 files (name, bytes) covering every header variant the writer produces; see module doc.
    backends: the Delaunay backend of seed k is backends[k % 3].
    holes: add copies of a few of them with a holes section (flags bit 7), and of the smoothed ones with
    crease-preserving smoothing (bit 7 of the position-bits byte); without them the list is that of before holes
    existed, so the campaign's recorded cases replay."""
    rng = np.random.default_rng([seed, 2**31])
    files = []
    variants = [(bits, degree) for bits in (6, 8, 10, 12) for degree in (-1, 0, 1, 2, 3)]
    for k, (bits, degree) in enumerate(variants):
        count = int(rng.integers(max(8, max_points // 10), max_points + 1))
        cells, sdf = _shell_cells(rng, bits, count, "torus" if k % 2 else "sphere")
        q = (degree + 1) ** 2
        c = rng.normal(scale=0.4, size=(len(cells), q))
        backend = backends[k % 3]
        flags = (FLAG_QHULL if backend == "qhull" else 0) | (FLAG_S_PREDICTED if k % 4 != 3 else 0)
        flags |= FLAG_OCTREE_CONTEXTS if k % 5 in (1, 2, 4) else 0  # context-coded positions in 3 of 5
        flags |= smoothing_flags(k % 4)  # smoothing 0-3 steps
        flags |= subdivision_flags((k // 4) % 3)  # subdivision 0-2 levels, with every smoothing
        f, _ = quantize_file(
            Q.dequantize_positions(cells, bits), sdf + rng.normal(scale=2e-3, size=len(sdf)), c, degree,
            position_bits=bits, s_step=float(rng.choice([2e-4, 5e-4, 1e-3])),
            c_band_steps=[float(rng.choice([0.1, 0.2, 0.3]))] * (degree + 1),
            scale=float(rng.uniform(0.1, 10)), offset=rng.normal(size=3), flags=flags, exact=backend == "exact",
        )  # fmt: skip
        ctx = "-ctx" if flags & FLAG_OCTREE_CONTEXTS else ""
        name = f"b{bits}-d{degree}-{backend}{ctx}-n{f.num_points}"
        files.append((name, pack_v2(f)))
    for n in (0, 1, 2, 3, 4, 5):
        cells = rng.choice(2**18, size=n, replace=False)
        cells = np.stack(np.unravel_index(cells, (64, 64, 64)), 1)
        pts = Q.dequantize_positions(cells, 6)
        f, _ = quantize_file(
            pts, rng.normal(size=n), None, -1, position_bits=6, s_step=1e-3, c_band_steps=[],
            flags=FLAG_S_PREDICTED | (FLAG_QHULL if n % 2 else 0), exact=not n % 2 and backends[0] == "exact",
        )  # fmt: skip
        files.append((f"tiny-n{n}", pack_v2(f)))
    if holes:
        files += [(f"{name}-holes", h) for name, data in files[:: len(variants) // 4] if (h := _with_holes(data))]
        files += [(f"{name}-creases", _with_creases(data)) for name, data in files[1 : len(variants) : 3]]
    return files


def _with_creases(data: bytes) -> bytes:
    """`data` with crease-preserving smoothing (bit 7 of the position-bits byte; smoothing steps as they are)."""
    from dataclasses import replace

    from tetweave_codec.formats.tw2 import unpack_v2

    return pack_v2(replace(unpack_v2(data), creases=True, sizes=None))


def _with_holes(data: bytes) -> bytes | None:
    """`data` with a holes section that opens the top tenth of its decoded surface (no pinch): a valid file with
    flags bit 7, or None when the surface is empty."""
    from dataclasses import replace

    from tetweave_codec.decoder import decode_detailed
    from tetweave_codec.formats.tw2 import unpack_v2
    from tetweave_codec.geometry.holes import face_ranks, without_pinches

    full = decode_detailed(data)
    f0 = full.extracted_faces
    if len(f0) < 8:
        return None
    z = full.closed_vertices[f0].mean(1)[:, 2]
    remove = without_pinches(f0, z > np.quantile(z, 0.9))
    if not remove.any() or remove.all():
        return None
    tw = unpack_v2(data)
    return pack_v2(replace(tw, flags=tw.flags | FLAG_HOLES, holes=np.sort(face_ranks(f0)[remove]), sizes=None))


def hostile_files(seeds: list[tuple[str, bytes]]) -> list[tuple[str, bytes]]:
    """Valid-CRC files that announce far more than they hold, made from the first exact seed files (name, bytes):

    * ``points-*``: N = 2^22 - 1, 2^22 (the most a file may declare), 2^22 + 1 and 2^32 - 1 over the sections of a
      seed at SH degree 3 and -1 (the decoder allocates O(N (4 + q)) before its octree finds the leaves missing);
    * ``holes-*`` on a seed with a surface of F0 faces: K = 64 N (the most the section's framing allows: 2^28 for
      a file of 2^22 points, which a decoder that took K at its word would allocate), K = F0 + 1, a rank F0, a
      rank 2^32 - 1, every face (a valid file whose mesh is empty) and the top rank alone (valid);
    * ``empty-holes``: a holes section on a file whose s has one sign (no surface to open).
    """
    from dataclasses import replace

    from tetweave_codec.decoder import decode_detailed
    from tetweave_codec.formats.tw2 import unpack_v2

    exact = [(name, data) for name, data in seeds if data[12] & BITS_EXACT and not data[10] & FLAG_HOLES]
    out = []
    for degree in (3, -1):
        name, data = next(
            (n, d) for n, d in exact if struct.unpack_from("<b", d, 11)[0] == degree and d[13:17] != b"\0" * 4
        )
        for n in (MAX_POINTS - 1, MAX_POINTS, MAX_POINTS + 1, 2**32 - 1):
            body = bytearray(data[:-CHECKSUM_SIZE])
            struct.pack_into("<I", body, 13, n)
            out.append((f"points-{n}-d{degree}", seal(bytes(body))))
    for _, data in exact:
        f0 = len(decode_detailed(data).extracted_faces)
        if f0 >= 8:
            break
    tw = unpack_v2(data)
    top = f0 - 1
    for label, ranks in (
        ("max-k", np.arange(64 * tw.num_points)),
        ("k-over-f0", np.arange(f0 + 1)),
        ("rank-f0", np.array([3, f0])),
        ("rank-2^32-1", np.array([0, 2**32 - 1])),
        ("every-face", np.arange(f0)),
        ("top-rank", np.array([top])),
    ):
        out.append((f"holes-{label}", pack_v2(replace(tw, flags=tw.flags | FLAG_HOLES, holes=ranks, sizes=None))))
    one_sign = replace(tw, s_sym=np.abs(tw.s_sym), flags=tw.flags | FLAG_HOLES, holes=np.array([0]), sizes=None)
    out.append(("empty-holes", pack_v2(one_sign)))
    return out


# -----------------------------------------------------------------------------------------------------------
# layout-aware mutations


@dataclass
class Parts:
    """A version-2 file cut along its layout: header (H bytes, size fields included) and its three sections, or
    four with a holes section (flags bit 7 of the seed)."""

    header: bytearray
    sections: list[bytes]
    keep_sizes: bool = False  # a mutation set the size fields on purpose: `assemble` must not rewrite them
    tail: bytes | None = None  # a mutation replaced the whole file's end (see `_m_file`)
    applied: list[str] = field(default_factory=list)


def split(data: bytes) -> Parts:
    """Cut a valid version-2 file into its parts."""
    degree = struct.unpack_from("<b", data, 11)[0]
    count = 3 + bool(data[10] & FLAG_HOLES)
    h = header_size(degree, count == 4)
    sizes = struct.unpack_from(f"<{count}I", data, h - 4 * count)
    starts = np.cumsum((h, *sizes)).tolist()
    return Parts(bytearray(data[:h]), [data[starts[i] : starts[i + 1]] for i in range(count)])


def assemble(parts: Parts, reseal: bool = True) -> bytes:
    """The file's bytes: size fields rewritten (unless a mutation set them) and the CRC recomputed if `reseal`."""
    header = bytearray(parts.header)
    count = len(parts.sections)
    if not parts.keep_sizes and len(header) >= 4 * count:
        struct.pack_into(f"<{count}I", header, len(header) - 4 * count, *(len(s) for s in parts.sections))
    body = bytes(header) + b"".join(parts.sections)
    data = seal(body) if reseal else body + b"\0" * CHECKSUM_SIZE
    if parts.tail is not None:
        cut = int.from_bytes(parts.tail[:4], "little") % (len(data) + 1)
        data = data[:cut] + parts.tail[4:]
    return data


def _field_value(rng: np.random.Generator, fmt: str, old):
    choices = list(EXTREMES[fmt])
    if fmt in ("<B", "<b", "<I"):
        lo, hi = {"<B": (0, 255), "<b": (-128, 127), "<I": (0, 2**32 - 1)}[fmt]
        choices += [min(max(old + d, lo), hi) for d in (-1, 1)] + [int(rng.integers(lo, hi, endpoint=True))]
    else:
        choices += [old * 2.0 ** int(rng.integers(-40, 40)), -old, float(rng.normal())]
        choices += [old * float(rng.uniform(0.25, 4))] * 4  # plausible values: files that still decode
    return choices[int(rng.integers(len(choices)))]


def _header_fields(parts: Parts) -> dict[str, tuple[int, str]]:
    """The seed header's fields: name -> (offset, struct format), the c steps of its SH bands included."""
    bands = (len(parts.header) - FIXED_SIZE - 4 * len(parts.sections)) // 4
    return {**FIELDS, **{f"c_step_{band}": (FIXED_SIZE + 4 * band, "<f") for band in range(bands)}}


# Mutations: (rng, parts, seed files' bytes) -> a short description; each edits `parts` in place.


def _m_field(rng, parts, others):
    fields = _header_fields(parts)
    name = list(fields)[int(rng.integers(len(fields)))]
    offset, fmt = fields[name]
    (old,) = struct.unpack_from(fmt, parts.header, offset)
    value = _field_value(rng, fmt, old)
    if fmt == "<f":
        with np.errstate(over="ignore"):
            value = float(np.float32(value))  # beyond float32: inf, as a writer rounding it would store
    struct.pack_into(fmt, parts.header, offset, value)
    return f"field:{name}={value!r}"


def _m_backend(rng, parts, others):
    """A valid file triangulated by another backend: one of flags bit 0 (Qhull) and byte 12 bit 6 (exact) toggled
    (both set: refused)."""
    if rng.random() < 0.5:
        parts.header[10] ^= FLAG_QHULL
    else:
        parts.header[12] ^= BITS_EXACT
    return "backend"


def _m_sizes(rng, parts, others):
    count = len(parts.sections)
    k = int(rng.integers(count))
    at = len(parts.header) - 4 * count
    (old,) = struct.unpack_from("<I", parts.header, at + 4 * k)
    value = _field_value(rng, "<I", old)
    struct.pack_into(f"<{count}I", parts.header, at, *(len(s) for s in parts.sections))
    struct.pack_into("<I", parts.header, at + 4 * k, value)
    parts.keep_sizes = True
    return f"sizes:{'PSCR'[k]}={value}"


def _m_boundary(rng, parts, others):
    joined = b"".join(parts.sections)
    sizes = [len(s) for s in parts.sections]
    k = int(rng.integers(len(sizes) - 1))  # boundary between section k and k + 1
    move = int(rng.integers(1, 65)) * (1 if rng.random() < 0.5 else -1)
    if rng.random() < 0.2:
        move = -sizes[k] if rng.random() < 0.5 else sizes[k + 1]  # to an extreme: one section empty
    move = max(-sizes[k], min(sizes[k + 1], move))
    sizes[k] += move
    sizes[k + 1] -= move
    starts = np.cumsum([0, *sizes]).tolist()
    parts.sections = [joined[starts[i] : starts[i + 1]] for i in range(len(sizes))]
    return f"boundary:{k}{move:+d}"


def _m_splice(rng, parts, others):
    k = int(rng.integers(len(parts.sections)))
    donor = split(others[int(rng.integers(len(others)))])
    parts.sections[k] = donor.sections[k] if k < len(donor.sections) else b""  # a donor without holes: none
    return f"splice:{k}"


def _m_truncate(rng, parts, others):
    k = int(rng.integers(len(parts.sections)))
    sec = parts.sections[k]
    cut = int(rng.integers(0, len(sec) + 1)) if rng.random() < 0.3 else min(len(sec), int(rng.integers(1, 9)))
    parts.sections[k] = sec[: len(sec) - cut] if rng.random() < 0.8 else sec[cut:]
    return f"truncate:{k}-{cut}"


def _m_extend(rng, parts, others):
    k = int(rng.integers(len(parts.sections)))
    extra = int(rng.integers(1, 257))
    kind = int(rng.integers(3))
    add = (bytes(extra), rng.bytes(extra), (parts.sections[k] * 2)[:extra])[kind]
    parts.sections[k] = parts.sections[k] + add
    return f"extend:{k}+{len(add)}{'zrc'[kind]}"


def _m_flip(rng, parts, others):
    joined = bytearray(b"".join(parts.sections))
    if not joined:
        return "flip:none"
    flips = int(rng.integers(1, 17))
    for _ in range(flips):
        bit = int(rng.integers(len(joined) * 8))
        joined[bit // 8] ^= 1 << (bit % 8)
    sizes = np.cumsum([0, *(len(s) for s in parts.sections)]).tolist()
    parts.sections = [bytes(joined[sizes[i] : sizes[i + 1]]) for i in range(len(parts.sections))]
    return f"flip:{flips}"


def _m_models(rng, parts, others):
    k = int(rng.integers(len(parts.sections)))
    sec = bytearray(parts.sections[k])
    if not sec:
        return "models:none"
    for _ in range(int(rng.integers(1, 5))):
        i = int(rng.integers(min(len(sec), 140)))  # model bytes sit at the start of each section
        sec[i] = int(rng.choice([0, 1, 2, 7, 8, 128, 248, 249, 254, 255, int(rng.integers(256))]))
    parts.sections[k] = bytes(sec)
    return f"models:{k}"


def _m_random(rng, parts, others):
    count = len(parts.sections)
    which = range(count) if rng.random() < 0.3 else [int(rng.integers(count))]
    for k in which:
        length = len(parts.sections[k]) if rng.random() < 0.7 else int(rng.integers(0, 4096))
        parts.sections[k] = rng.bytes(length)
    return f"random:{list(which)}"


def _m_file(rng, parts, others):
    cut = int(rng.integers(0, 2**32))
    extra = rng.bytes(int(rng.integers(0, 16))) if rng.random() < 0.5 else b""
    parts.tail = cut.to_bytes(4, "little") + extra
    return "file"


MUTATIONS = {
    "field": (_m_field, 4.0),
    "backend": (_m_backend, 1.5),
    "sizes": (_m_sizes, 1.0),
    "boundary": (_m_boundary, 2.0),
    "splice": (_m_splice, 1.5),
    "truncate": (_m_truncate, 1.5),
    "extend": (_m_extend, 1.5),
    "flip": (_m_flip, 3.0),
    "models": (_m_models, 2.0),
    "random": (_m_random, 1.0),
    "file": (_m_file, 0.5),
}


def mutate(rng: np.random.Generator, seeds: list[bytes]) -> tuple[int, bytes, list[str]]:
    """One case: (index of the seed file, mutated bytes, description of the mutations applied)."""
    index = int(rng.integers(len(seeds)))
    parts = split(seeds[index])
    names = list(MUTATIONS)
    weights = np.array([MUTATIONS[n][1] for n in names])
    for _ in range(int(rng.integers(1, MAX_MUTATIONS + 1))):
        name = names[int(rng.choice(len(names), p=weights / weights.sum()))]
        parts.applied.append(MUTATIONS[name][0](rng, parts, seeds))
    reseal = rng.random() >= NO_RESEAL_SHARE
    if not reseal:
        parts.applied.append("no-reseal")
    return index, assemble(parts, reseal), parts.applied


# -----------------------------------------------------------------------------------------------------------
# one case, in a worker


def classify(data: bytes, compare: bool = False) -> tuple[str, str]:
    """Decode `data` and name the outcome (see module doc) with a one-line detail; compare: a difference between
    the decoder core and the Python pipeline is the outcome "mismatch"."""
    from tetweave_codec import decoder
    from tetweave_codec.errors import ContainerError

    if compare:
        problem = pipeline_difference(data)
        if problem:
            return "mismatch", problem
    try:
        result = decoder.decode_detailed(data)
    except ContainerError as exc:
        return "rejected", str(exc)
    except Exception as exc:  # noqa: BLE001 -- every other exception is a finding of the campaign
        return "error", f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return classify_result(result)


def _decode_with(data: bytes, core: bool, level: str):
    """decode_detailed through the core (core=True: what decoder.decode runs) or the Python pipeline: the result, or
    the exception it raised."""
    from tetweave_codec import decoder

    saved = decoder.CORE
    decoder.CORE = core and saved
    try:
        return decoder.decode_detailed(data, level=level)
    except Exception as exc:  # noqa: BLE001 -- the caller compares what each pipeline raised
        return exc
    finally:
        decoder.CORE = saved


def pipeline_difference(data: bytes, levels: tuple[str, ...] = ("full",)) -> str | None:
    """How the decoder core and the Python pipeline (decoder.CORE off, the reference) differ on `data` (None when
    they agree): the error class of a refused file, else every array and count of the decode, bit for bit."""
    from tetweave_codec import decoder

    if not decoder.CORE:
        return None  # no core extension: both are the Python pipeline
    for level in levels:
        got, ref = _decode_with(data, True, level), _decode_with(data, False, level)
        if isinstance(ref, MemoryError) or isinstance(got, MemoryError):
            continue  # the worker's memory cap, met by one pipeline: not a difference of the decoders
        if isinstance(got, Exception) or isinstance(ref, Exception):
            if type(got) is not type(ref):
                return f"{level}: core {type(got).__name__}: {got}, reference {type(ref).__name__}: {ref}"
            continue
        for name in ("vertices", "faces", "closed_vertices", "closed_faces", "extracted_faces"):
            a, b = getattr(got, name), getattr(ref, name)
            if a.shape != b.shape or a.dtype != b.dtype or not np.array_equal(a, b):
                return f"{level}: {name} differ (core {a.shape} {a.dtype}, reference {b.shape} {b.dtype})"
        for name in ("num_tets", "restored", "smoothing", "subdivision", "backend"):
            if getattr(got, name) != getattr(ref, name):
                return f"{level}: {name} {getattr(got, name)} against the reference's {getattr(ref, name)}"
    return None


def classify_result(result) -> tuple[str, str]:
    """ "closed", "open", "empty" or "non_manifold" (with a detail) for a `decoder.DecodeResult`."""
    from dataclasses import replace

    holes = result.container.holes
    if holes is None or not len(result.faces):
        outcome, detail = _classify_closed(result)
    else:
        outcome, detail = _classify_closed(replace(result, vertices=result.closed_vertices, faces=result.closed_faces))
        if outcome != "closed":
            return outcome, f"before the holes: {detail}"
        problem = _open_problem(result.vertices, result.faces)
        if problem:
            return "non_manifold", problem
        outcome, detail = "open", f"{detail}, {len(holes)} faces opened"
    if outcome in ("closed", "open"):
        problem = crossing_problem(result.vertices, result.faces)
        if problem:
            return "self_intersecting", problem
    return outcome, detail


def _open_problem(v: np.ndarray, f: np.ndarray) -> str | None:
    """Why (v, f) is not a 2-manifold with boundary (None when it is): edges of one or two faces seen in opposite
    directions, every vertex used, one fan per vertex."""
    from tetweave_codec.geometry.holes import pinched_vertices
    from tetweave_codec.geometry.marching_tets import check_manifold

    try:
        check_manifold(f, len(v), closed=False)  # every directed edge once: edges of one or two faces, oriented
    except Exception as exc:  # noqa: BLE001
        return str(exc)
    if len(np.unique(f)) != len(v) or not np.isfinite(v).all():
        return "unreferenced or non-finite vertices"
    if len(pinched_vertices(f, len(v))):
        return "a pinched vertex"
    return None


def _classify_closed(result) -> tuple[str, str]:
    import manifold3d

    from tetweave_codec.geometry.marching_tets import check_manifold

    v, f = result.vertices, result.faces
    if len(f) == 0:
        return ("empty", f"{result.container.num_points} points") if len(v) == 0 else ("non_manifold", "stray")
    try:
        check_manifold(f, len(v), closed=True)
    except Exception as exc:  # noqa: BLE001
        return "non_manifold", str(exc)
    if len(np.unique(f)) != len(v) or not np.isfinite(v).all():
        return "non_manifold", "unreferenced or non-finite vertices"
    # manifold3d takes float32: check the mesh in the normalized frame, which the header's transform may not fit.
    local = (v - result.container.offset) / result.container.scale
    mesh = manifold3d.Mesh(vert_properties=local.astype(np.float32), tri_verts=f.astype(np.uint32))
    status = manifold3d.Manifold(mesh).status()
    if status != manifold3d.Error.NoError:
        return "non_manifold", f"manifold3d: {status.name}"
    return "closed", f"{result.backend} {result.container.num_points} points {len(f)} faces"


def crossing_problem(v: np.ndarray, f: np.ndarray) -> str | None:
    """Why the decoded mesh (v, f), as returned, is not free of self-intersections (None when it is): faces the
    decoder's own check flags, or pairs of faces that meet other than at a shared vertex by the independent
    exact check (benchmarks/exact_check.py, which shares no code with the decoder's)."""
    from tetweave_codec.benchmarks.exact_check import check
    from tetweave_codec.geometry.intersections import self_intersecting_faces

    if len(f) < 2:
        return None
    try:
        own = int(self_intersecting_faces(v, f).sum())
    except RuntimeError:
        own = -1  # the decoder's check cannot bound its work on the mesh it returned
    found = check(v, f)
    if own or len(found.pairs):
        return f"{own} faces by the decoder's check, {len(found.pairs)} pairs meeting by the exact check"
    return None


def _worker(conn, memory_gb: float, compare: bool = False) -> None:
    """Decode what arrives on `conn` until None; memory capped so that a runaway allocation fails here."""
    try:
        import resource

        limit = int(memory_gb * 2**30)
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    except (ImportError, ValueError, OSError):  # pragma: no cover - not on every platform
        pass
    while True:
        data = conn.recv()
        if data is None:
            return
        try:
            conn.send(classify(data, compare))
        except MemoryError:
            conn.send(("error", "MemoryError"))


class Runner:
    """A worker process that decodes one case at a time; restarted after a timeout or a crash."""

    def __init__(self, time_limit: float, memory_gb: float, compare: bool = False):
        self.time_limit, self.memory_gb, self.compare = time_limit, memory_gb, compare
        self.ctx = mp.get_context("spawn")
        self.proc = None

    def _start(self) -> None:
        self.conn, child = self.ctx.Pipe()
        self.proc = self.ctx.Process(target=_worker, args=(child, self.memory_gb, self.compare), daemon=True)
        self.proc.start()

    def _stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.join()
            self.proc = None

    def run(self, data: bytes) -> tuple[str, str]:
        if self.proc is None:
            self._start()
        try:
            self.conn.send(data)
            if self.conn.poll(self.time_limit):
                return self.conn.recv()
            self._stop()
            return "timeout", f"over {self.time_limit:g} s"
        except (EOFError, OSError, BrokenPipeError):
            code = self.proc.exitcode if self.proc is not None else None
            self._stop()
            return "crash", f"worker exit code {code}"

    def close(self) -> None:
        if self.proc is not None:
            try:
                self.conn.send(None)
                self.proc.join(5)
            finally:
                self._stop()


# -----------------------------------------------------------------------------------------------------------
# the C decoder core under sanitizers (tests/core_decode_harness.c)

ROOT = Path(__file__).resolve().parent.parent
HARNESS_SOURCE = ROOT / "tests" / "core_decode_harness.c"
CORE_SOURCES = ROOT / "decoder"
SANITIZE = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all")
# ASan reserves terabytes of address space (no RLIMIT_AS under it): its own cap refuses single allocations over
# the limit instead (malloc returns NULL, as under RLIMIT_AS), and a leak is a report.
ASAN_OPTIONS = "detect_leaks=1:abort_on_error=0:allocator_may_return_null=1:max_allocation_size_mb={mb}"
HARNESS_DEAD = 99  # statuses >= this: the child did not end normally (99), or died of signal status - 100


def harness_compiler() -> str | None:
    """The C compiler for the harness ($CC, else cc / gcc / clang on PATH), or None."""
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return name
    return None


def build_harness(directory: str | Path, sanitize: bool = True) -> Path | None:
    """Compile tests/core_decode_harness.c with every decoder/*.c into `directory` (the core's flags; with ASan
    and UBSan when `sanitize`): the executable, or None without a checkout, a compiler or sanitizer support."""
    cc = harness_compiler()
    if cc is None or not HARNESS_SOURCE.exists() or not CORE_SOURCES.is_dir():
        return None
    exe = Path(directory) / ("decode_harness_asan" if sanitize else "decode_harness")
    flags = ["-std=c99", "-ffp-contract=off", "-fno-fast-math", "-Wall", "-Wextra"]
    flags += ["-O1", "-g", "-fno-omit-frame-pointer", *SANITIZE] if sanitize else ["-O2"]
    sources = [*sorted(map(str, CORE_SOURCES.glob("*.c"))), str(HARNESS_SOURCE)]
    run = subprocess.run([cc, *flags, "-o", str(exe), *sources, "-lm", "-pthread"], capture_output=True, text=True)
    return exe if run.returncode == 0 else None


@dataclass
class HarnessRow:
    """One file's decode by the harness: tw_status (>= HARNESS_DEAD: the child died), counts, peak RSS, message."""

    status: int
    vertices: int
    faces: int
    peak_rss_kib: int
    message: str
    report: str = ""  # what the decode wrote on stderr (a sanitizer report)


def run_harness(
    exe: str | Path,
    blobs: list[bytes],
    level: int = 2,
    limit_mb: int = 0,
    sanitized: bool = True,
    out: str | Path | None = None,
    timeout: float = 600,
) -> tuple[list[HarnessRow], str]:
    """Decode `blobs` with the harness `exe` (one child process per file): a row per file and the harness's stderr
    (sanitizer reports). limit_mb: the memory cap (RLIMIT_AS of each child, or ASan's largest allocation when
    `sanitized`; 0 none); out: a folder for the decoded arrays (i.v float64, i.f uint32)."""
    with tempfile.TemporaryDirectory(prefix="twfuzz") as tmp:
        paths = []
        for i, data in enumerate(blobs):
            path = Path(tmp) / f"{i:06d}.tw"
            path.write_bytes(data)
            paths.append(str(path))
        cmd = [str(exe), "--level", str(level)]
        if out is not None:
            cmd += ["--out", str(out)]
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin")}
        if sanitized:
            env["ASAN_OPTIONS"] = ASAN_OPTIONS.format(mb=limit_mb or 1 << 20)
            env["UBSAN_OPTIONS"] = "print_stacktrace=1"
        elif limit_mb:
            cmd += ["--limit-mb", str(limit_mb)]
        run = subprocess.run([*cmd, *paths], capture_output=True, text=True, timeout=timeout, env=env)
    rows = {}
    for line in run.stdout.splitlines():
        index, status, nv, nf, rss, *message = line.split(" ", 5)
        rows[int(index)] = HarnessRow(int(status), int(nv), int(nf), int(rss), " ".join(message))
    missing = HarnessRow(HARNESS_DEAD, 0, 0, 0, "no answer from the harness")
    result = [rows.get(i, missing) for i in range(len(blobs))]
    index = None
    for line in run.stderr.splitlines():  # "== i FILE" starts file i's part of stderr
        if line.startswith("== ") and line.split(" ")[1].isdigit():
            index = int(line.split(" ")[1])
        elif index is not None and index < len(result) and line.strip():
            result[index].report += line + "\n"
    return result, run.stderr


# tw_status codes (decoder/tetweave_decoder.h) and the worker's outcomes they agree with
HARNESS_AGREES = {
    0: ("closed", "open", "empty"),
    1: ("rejected",),
    3: ("rejected",),  # TW_ERROR_LIMIT: the Python pipeline's face cap is a ContainerError too
}


def harness_disagreement(row: HarnessRow, outcome: str) -> tuple[str, str] | None:
    """("crash" | "mismatch", detail) when the harness's answer is a failure or disagrees with the worker's outcome
    of the same file through decoder.decode_detailed; None when they agree (or the core left the file to the Python
    pipeline: an earlier encoder's, status 2)."""
    if row.status >= HARNESS_DEAD:
        signal = f"signal {row.status - 100}" if row.status > HARNESS_DEAD else "abnormal exit"
        return "crash", f"core harness: {signal} (sanitizer report or crash)"
    if row.status == 2 or outcome in FAILURES:  # an earlier encoder's file, or a finding already
        return None
    if outcome not in HARNESS_AGREES.get(row.status, ()):
        return "mismatch", f"core harness status {row.status} ({row.message}) but the worker's outcome is {outcome}"
    return None


# -----------------------------------------------------------------------------------------------------------
# the campaign


@dataclass
class Campaign:
    """Counts of a campaign: outcome -> cases; per outcome, per Delaunay flag of the mutated file; findings."""

    counts: collections.Counter = field(default_factory=collections.Counter)
    by_backend: collections.Counter = field(default_factory=collections.Counter)
    reasons: collections.Counter = field(default_factory=collections.Counter)
    mutations: collections.Counter = field(default_factory=collections.Counter)
    findings: list = field(default_factory=list)
    seconds: float = 0.0
    harness: collections.Counter = field(default_factory=collections.Counter)  # agree / crash / mismatch / memory

    @property
    def failures(self) -> int:
        return sum(self.counts[k] for k in FAILURES) + self.harness["crash"] + self.harness["mismatch"]


def _backend_flag(data: bytes) -> str:
    if len(data) > 12 and data[12] & BITS_EXACT:
        return "exact"
    return "qhull" if len(data) > 10 and data[10] & FLAG_QHULL else "tetgen"


def run_campaign(
    seeds: list[tuple[str, bytes]],
    cases: int,
    seed: int = 0,
    time_limit: float = DEFAULT_TIME_LIMIT,
    memory_gb: float = DEFAULT_MEMORY_GB,
    only: list[int] | None = None,
    progress=None,
    compare: bool = False,
    harness: str | Path | None = None,
    harness_batch: int = 200,
) -> Campaign:
    """Run `cases` mutated files (or just the case numbers in `only`) through the decoder; see module doc.
    compare: the worker also compares the core with the Python pipeline; harness: a sanitized
    tests/core_decode_harness.c executable (build_harness) that decodes every case too, `harness_batch` at a time."""
    blobs = [b for _, b in seeds]
    result = Campaign()
    runner = Runner(time_limit, memory_gb, compare)
    pending: list[tuple[int, int, bytes, list[str], str]] = []

    def flush() -> None:
        if not pending:
            return
        rows, _ = run_harness(harness, [p[2] for p in pending], limit_mb=int(memory_gb * 1024))
        for (i, index, _, applied, outcome), row in zip(pending, rows, strict=True):
            found = harness_disagreement(row, outcome)
            result.harness["memory" if row.status == 4 else found[0] if found else "agree"] += 1
            if found:
                summary = [line for line in row.report.splitlines() if "SUMMARY" in line or "runtime error" in line]
                detail = found[1] + (f"; {summary[0].strip()}" if summary else "")
                result.findings.append((i, seeds[index][0], applied, found[0], detail))
                if progress is not None:
                    progress(i, found[0], detail, seeds[index][0], applied)
        pending.clear()

    start = time.perf_counter()
    try:
        for i in only if only is not None else range(cases):
            index, data, applied = mutate(np.random.default_rng([seed, i]), blobs)
            outcome, detail = runner.run(data)
            if harness is not None:
                pending.append((i, index, data, applied, outcome))
                if len(pending) >= harness_batch:
                    flush()
            result.counts[outcome] += 1
            result.by_backend[outcome, _backend_flag(data)] += 1
            for name in applied:
                result.mutations[name.split(":")[0]] += 1
            if outcome == "rejected":
                result.reasons[_reason(detail)] += 1
            if outcome in FAILURES:
                result.findings.append((i, seeds[index][0], applied, outcome, detail))
            if progress is not None:
                progress(i, outcome, detail, seeds[index][0], applied)
        if harness is not None:
            flush()
    finally:
        runner.close()
    result.seconds = time.perf_counter() - start
    return result


def _reason(message: str) -> str:
    """The kind of a ContainerError message, without its numbers ("truncated .tw file", "invalid .tw header: ...")."""
    head = message.split(":")[0]
    if head.startswith("invalid .tw header") and ":" in message:
        words = [w for w in message.split(":")[1].split() if not any(ch.isdigit() for ch in w)]
        return f"{head}: {' '.join(words[:3])}"
    return head


def report(result: Campaign, seeds: list[tuple[str, bytes]], cases: int, seed: int) -> str:
    """The campaign as Markdown."""
    total = sum(result.counts.values())
    lines = [
        f"# Fuzz campaign: {total:,} structure-aware mutations of {len(seeds)} version-2 seed files (seed {seed})",
        "",
        f"{result.seconds:.0f} s in all. Failures (non-manifold, self-intersecting, other exceptions, timeouts, "
        "crashes): "
        f"**{result.failures}**.",
        "",
        "| outcome | cases | exact | TetGen flag | Qhull flag |",
        "|---|---:|---:|---:|---:|",
    ]
    for name in OUTCOMES:
        lines.append(
            f"| {name} | {result.counts[name]:,} | {result.by_backend[name, 'exact']:,} | "
            f"{result.by_backend[name, 'tetgen']:,} | {result.by_backend[name, 'qhull']:,} |"
        )
    if result.harness:
        lines += [
            "",
            "The C decoder core under ASan + UBSan (tests/core_decode_harness.c, one process per case): "
            + ", ".join(f"{k} {v:,}" for k, v in sorted(result.harness.items())),
        ]
    lines += ["", "Mutations applied: " + ", ".join(f"{k} {v:,}" for k, v in result.mutations.most_common()), ""]
    lines += ["Rejections by message:", ""] + [f"* {k}: {v:,}" for k, v in result.reasons.most_common()]
    found = result.findings
    if found:
        lines += ["", "Findings (case, seed file, mutations, outcome, detail):", ""]
        lines += [
            f"* {i} {name} {applied} {outcome}: {detail}" for i, name, applied, outcome, detail in result.findings
        ]
    lines += ["", "Seed files: " + ", ".join(f"{name} ({len(data):,} B)" for name, data in seeds)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--files", nargs="*", default=[], help="extra version-2 seed files (real encodes)")
    parser.add_argument("--files-only", action="store_true", help="the --files alone, no analytic seed files")
    parser.add_argument("--max-points", type=int, default=3000, help="largest analytic seed file")
    parser.add_argument("--time-limit", type=float, default=DEFAULT_TIME_LIMIT)
    parser.add_argument("--memory-gb", type=float, default=DEFAULT_MEMORY_GB)
    parser.add_argument("--only", type=int, nargs="*", help="replay these case numbers")
    parser.add_argument("--out", help="write the Markdown report here")
    parser.add_argument("-v", "--verbose", action="store_true", help="one line per case")
    parser.add_argument(
        "--compare", action="store_true", help="also decode with the Python pipeline: a difference is a mismatch"
    )
    parser.add_argument(
        "--harness", action="store_true", help="also decode every case with the C core under ASan + UBSan (checkout)"
    )
    args = parser.parse_args(argv)
    seeds = [] if args.files_only else seed_files(args.seed, args.max_points)
    for path in args.files:
        with open(path, "rb") as fh:
            seeds.append(("/".join(path.split("/")[-2:]), fh.read()))  # folder/name: bench files share names
    if not seeds:
        parser.error("no seed files (--files-only needs --files)")

    def progress(i, outcome, detail, name, applied):
        if args.verbose or outcome in FAILURES:
            print(f"{i} {name} {applied} -> {outcome}: {detail}", file=sys.stderr, flush=True)
        elif (i + 1) % 500 == 0:
            print(f"{i + 1} cases", file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory(prefix="twharness") as tmp:
        exe = build_harness(tmp) if args.harness else None
        if args.harness and exe is None:
            parser.error("--harness needs a checkout (decoder/, tests/) and a C compiler with ASan + UBSan")
        result = run_campaign(
            seeds, args.cases, args.seed, args.time_limit, args.memory_gb, args.only, progress, args.compare, exe
        )
    text = report(result, seeds, args.cases, args.seed)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text)
    print(text)
    return 1 if result.failures else 0


if __name__ == "__main__":
    sys.exit(main())
