"""The packager: a finished fit -> the `.tw` bytes an encode writes, with the decoded mesh where packing knows it.

`Packer.pack` writes a fit's file; for an encode that keeps an open input's holes it decodes the file once, lists
the faces that span the holes (fit.holes) and, when plain and grown caps differ, keeps the file whose decoded mesh
is closer to the input. The decoded meshes of those files are the closed one with the listed faces removed, which
is exactly the decoder's last step (geometry.holes.open_holes), so they are computed from the one decode instead
of decoding each file again; `Packed.decoded` hands the chosen one on (rate control and the report reuse it).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from tetweave_codec.fit.finish import FinishResult
from tetweave_codec.fit.loop import FitResult
from tetweave_codec.fit.prepared import PreparedInput
from tetweave_codec.fit.step import FitContext

# Samples per mesh of the Chamfer distance in the summary: enough for ~1e-5 resolution in the normalized frame.
SUMMARY_CHAMFER_SAMPLES = 100_000
# Samples per mesh of the Chamfer distance that picks between plain and grown hole caps (Packer.with_holes): their
# files differ by 5-35 % there, well above this count's noise.
HOLES_CHAMFER_SAMPLES = 30_000


@dataclass(frozen=True)
class Packed:
    """A packed file: its bytes and, when packing had to decode it anyway, the decoder's result for exactly these
    bytes (`decoder.DecodeResult`), else None."""

    data: bytes
    decoded: object | None = None


@dataclass
class Packer:
    """Packs the fits of one encode: the input's frame (`input.scale`, `input.offset`), its rim when holes are kept
    (`input.rim`), the SH degree; seconds: the encode's timings ("holes" accumulates the holes' share)."""

    input: PreparedInput
    sh_degree: int
    seconds: dict = field(default_factory=dict)

    def pack(self, fin: FinishResult, ctx: FitContext) -> Packed:
        """The file of `fin` (a fit with context `ctx`), with the holes section when the encode keeps an open
        input's holes."""
        cfg = ctx.config
        data = self.pack_as(fin, ctx.backend, ctx.frame_scale, cfg.smoothing, cfg.subdivision, cfg.creases)
        return Packed(data) if self.input.rim is None else self.with_holes(data)

    def pack_as(
        self, fin: FinishResult, backend: str, frame_scale: float, smoothing: int, subdivision: int, creases: bool
    ) -> bytes:
        """The bytes of `fin` for a fit in the frame normalized x frame_scale (the transform divides it out)."""
        result = FitResult(fin, self.sh_degree, backend, {}, [], smoothing, subdivision, creases)
        return pack_result(result, self.input.scale / frame_scale, self.input.offset)

    def with_holes(self, data: bytes) -> Packed:
        """`data` (a version-2 file without holes) with a holes section listing the faces of its decoded surface
        that span the input's holes (fit.holes); `data` itself when there are none. When the caps grown into their
        far neighbours (`fit.holes.cap_faces(grow=True)`) differ from the plain ones, the file whose decoded mesh
        is closer to the input (Chamfer distance, HOLES_CHAMFER_SAMPLES) is kept: growing them follows a cap that
        sags into the shape (stanford-bunny 40 KB: Chamfer 3.7e-4 -> 2.4e-4) but can cut into the surface around
        the rim (10 KB: 6.1e-4 -> 6.5e-4). The result carries the decoded mesh of the file kept."""
        import time

        from tetweave_codec.decoder import decode_detailed
        from tetweave_codec.fit.holes import hole_ranks
        from tetweave_codec.formats.common import FLAG_HOLES
        from tetweave_codec.formats.tw import pack_v2

        t0 = time.perf_counter()
        prepared = self.input
        full = decode_detailed(data)
        closed = (full.closed_vertices - prepared.offset) / prepared.scale
        tw = full.container
        files = []
        for grow in (False, True):
            ranks = hole_ranks(prepared.rim, closed, full.extracted_faces, grow)
            if len(ranks) and not any(np.array_equal(ranks, r) for r, _ in files):
                files.append((ranks, pack_v2(replace(tw, flags=tw.flags | FLAG_HOLES, holes=ranks, sizes=None))))
        decoded = [_opened(full, candidate) for _, candidate in files]
        if len(files) > 1:
            errors = [prepared.chamfer(out.vertices, out.faces, HOLES_CHAMFER_SAMPLES) for out in decoded]
            best = int(np.argmin(errors))
            files, decoded = [files[best]], [decoded[best]]
        self.seconds["holes"] = self.seconds.get("holes", 0.0) + time.perf_counter() - t0
        return Packed(files[0][1], decoded[0]) if files else Packed(data, full)

    def kept_filter(self, data: bytes, full, chamfer: float | None, measure_chamfer):
        """(bytes, DecodeResult, Chamfer or None) of the file to keep, given `full`, the decoder's result for
        `data`. When the decoder had to drop a subdivided file's whole filter (its crossing check did not settle:
        the result is the unsmoothed, unsubdivided surface of a fit made for the subdivided one), the same points
        with the subdivision bits cleared (the smoothing alone, with its own check) are kept instead if they decode
        closer to the input (`measure_chamfer(vertices, faces)`, the summary's error). Same bytes."""
        from tetweave_codec.decoder import decode_detailed
        from tetweave_codec.formats.common import FLAG_SUBDIVISION
        from tetweave_codec.formats.tw import pack_v2, unpack

        if not full.container.subdivision or not len(full.faces) or full.restored != len(full.vertices):
            return data, full, chamfer
        tw = unpack(data)
        alt = pack_v2(replace(tw, flags=tw.flags & ~FLAG_SUBDIVISION, sizes=None))
        alt_full = decode_detailed(alt)
        err = measure_chamfer(full.vertices, full.faces) if chamfer is None else chamfer
        alt_err = measure_chamfer(alt_full.vertices, alt_full.faces)
        if alt_err < err:
            return alt, alt_full, alt_err
        return data, full, err


def _opened(full, data: bytes):
    """The decoder's result for `data`, a file that differs from the one `full` decoded only by its holes section:
    `full`'s closed surface with the listed faces removed, as `decoder.decode_detailed` removes them."""
    from tetweave_codec.formats.tw import unpack
    from tetweave_codec.geometry.holes import open_holes

    container = unpack(data)
    children = len(full.closed_faces) // max(len(full.extracted_faces), 1)  # 4^L, or 1 when the filter gave up
    vertices, faces = open_holes(
        full.closed_vertices, full.closed_faces, full.extracted_faces, container.holes, children
    )
    return replace(full, vertices=vertices, faces=faces, parsed=container)


def pack_result(result: FitResult, scale: float, offset: np.ndarray) -> bytes:
    """The `.tw` bytes of a fit: version 1 or 2 after `result.finish.version`."""
    from tetweave_codec.formats import octree
    from tetweave_codec.formats.common import (
        FLAG_OCTREE_CONTEXTS,
        FLAG_S_PREDICTED,
        smoothing_flags,
        subdivision_flags,
    )
    from tetweave_codec.formats.tw import TetWeaveFile, TetWeaveFileV2, backend_flags, pack, pack_v2

    fin = result.finish
    shared = {
        "sh_degree": result.sh_degree,
        "scale": float(scale),
        "offset": np.asarray(offset, dtype=np.float64),
        "flags": backend_flags(result.backend),
    }
    if fin.version == 1:
        if result.smoothing or result.subdivision or result.creases:
            raise ValueError("container version 1 cannot store smoothing or subdivision")
        if result.backend == "exact":
            raise ValueError("container version 1 records TetGen or Qhull, not the exact Delaunay")
        return pack(TetWeaveFile(points=fin.points, s=fin.s, c=fin.c, **shared))
    shared["flags"] |= smoothing_flags(result.smoothing) | subdivision_flags(result.subdivision)
    q = fin.quantization
    # The cells hold grid_scale x the fit's positions: the transform divides it out (s and c are unchanged: a
    # marching-tets surface depends on the positions only through the edges' endpoints, on s only through ratios).
    shared["scale"] = float(scale) / q.grid_scale
    steps = tuple(q.c_band_steps[: result.sh_degree + 1])
    shared["flags"] |= FLAG_S_PREDICTED
    if octree.contexts_pay(fin.cells, q.position_bits):  # the new coding only where it saves bytes
        shared["flags"] |= FLAG_OCTREE_CONTEXTS
    return pack_v2(
        TetWeaveFileV2(
            cells=fin.cells,
            s_sym=fin.s_sym,
            c_sym=fin.c_sym,
            position_bits=q.position_bits,
            s_step=q.s_step,
            c_band_steps=steps,
            creases=bool(result.creases and (result.smoothing or result.subdivision)),
            exact=result.backend == "exact",
            **shared,
        )
    )
