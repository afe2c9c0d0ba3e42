"""tetweave's visible-surface fit against MeshLab decimation + Draco of the messy input, at equal error (issue 46).

The messy inputs are those of benchmarks/visible_surface.py (`build`: hidden part, inner wall, overlapping
primitives), built from a clean closed mesh, so the surface a viewer sees (the truth) is known exactly. For each
kind and --size:

- tetweave: `encode(messy, --size, --surface auto)`; its decoded mesh's Chamfer distance to the truth;
- MeshLab + Draco of the messy input as a user gives it (every face, the hidden ones too), through the bench's own
  baseline (bench.baselines: `mlab_decimate`, MeshLab's quadric edge collapse with `MLAB_QUADRIC` in the input's
  normalized frame, then Draco at `MLAB_BITS` 9-12 bits, compression level 7), and the same after MeshLab's
  best-effort cleanup (`ao_cleanup`: ambient occlusion, then the faces no ray leaves deleted). Its size at
  tetweave's error is read off the Pareto front of every (fraction, bits) measured (`rate_distortion.bytes_at`,
  log-log, never extrapolated). The fractions: the bench's MLAB_KEEP (eight per octave, 50 % to 0.5 %) plus the
  whole mesh, searched per bit depth with the bench's `sweep.bracket`, then DENSE more between the two fractions
  that bracket each tetweave error (64 per octave there).

Every distance is measured against the truth in its normalized frame with the same samples (`batch.
reference_chamfer`, --samples). The ratio is tetweave's bytes / MeshLab + Draco's bytes (below 1: tetweave is
smaller); "floor" is MeshLab + Draco's smallest error when no setting reaches tetweave's.

    python -m tetweave_codec.benchmarks.visible_mlab --only spot --kinds hidden,inner_wall,overlap --sizes 5k,10k \
        --threads 1

--save DIR writes each messy input (DIR/MESH_KIND.ply) and tetweave file (DIR/MESH_KIND_SIZE_SURFACE.tw) for
`tetweave render`; --before also encodes each input with --surface all (the encode before the option) and saves
and measures that file, outside the MeshLab comparison.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

KINDS = ("hidden", "inner_wall", "overlap")
DENSE = 8  # fractions added between two bracketing fractions of MLAB_KEEP (1/8 octave apart): 64 per octave
VARIANTS = ("none", "ao")  # MeshLab's cleanup before the decimation: none, or ambient occlusion (`ao_cleanup`)


def ao_cleanup(vertices: np.ndarray, faces: np.ndarray, rays: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """MeshLab's best-effort removal of what no one sees: per-face ambient occlusion
    (`compute_scalar_ambient_occlusion`, `rays` directions), the faces whose value is zero (no ray leaves them)
    selected (`compute_selection_by_scalar_per_face`) and deleted, then the unreferenced vertices. Deleting faces
    with a low but nonzero value too (up to 2 of ~16 on spot's overlap) only raised the error (2.65e-4 -> 2.68e-4
    without decimation): zero is MeshLab's strongest setting here."""
    import pymeshlab

    meshes = pymeshlab.MeshSet()
    meshes.add_mesh(
        pymeshlab.Mesh(
            vertex_matrix=np.ascontiguousarray(vertices, dtype=np.float64),
            face_matrix=np.ascontiguousarray(faces, dtype=np.int32),
        )
    )
    meshes.compute_scalar_ambient_occlusion(rays=rays)
    meshes.compute_selection_by_scalar_per_face(minq=0.0, maxq=1e-9, inclusive=True)
    meshes.meshing_remove_selected_faces()
    meshes.meshing_remove_unreferenced_vertices()
    out = meshes.current_mesh()
    return np.asarray(out.vertex_matrix(), dtype=np.float64), np.asarray(out.face_matrix(), dtype=np.int64)


class MlabFront:
    """MeshLab + Draco of one mesh against one reference: every (fraction, bits) measured once, on demand."""

    def __init__(self, vertices, faces, reference, options) -> None:
        from tetweave_codec.bench.baselines import MLAB_BITS, MLAB_KEEP, DecimationCache, mlab_decimate

        self.vertices, self.faces, self.reference, self.options = vertices, faces, reference, options
        self.cache = DecimationCache(mlab_decimate)
        self.keeps = sorted({*MLAB_KEEP, 1.0})  # smallest file first along each bit depth's curve
        self.bits = MLAB_BITS
        self.points: dict[tuple[float, int], tuple[int, float]] = {}  # (keep, bits) -> (bytes, chamfer)

    def measure(self, keep: float, bits: int) -> float:
        """Chamfer distance of (keep, bits) to the reference (the bytes kept in `points`)."""
        from tetweave_codec.bench.rows import reference_chamfer
        from tetweave_codec.classical import DRACO_COMPRESSION_LEVEL, draco_decode, draco_encode

        if (keep, bits) not in self.points:
            v, f, _, _ = self.cache.get(self.vertices, self.faces, keep)
            data = draco_encode(v, f, bits, DRACO_COMPRESSION_LEVEL)
            error = reference_chamfer(self.reference, *draco_decode(data), self.options)
            self.points[(keep, bits)] = (len(data), error)
        return self.points[(keep, bits)][1]

    def around(self, target: float) -> None:
        """Measure, on every bit depth's curve, the fractions that bracket `target` (sweep.bracket) and DENSE
        fractions between them."""
        from tetweave_codec.bench.sweep import bracket

        n = len(self.keeps)
        for bits in self.bits:
            lo, hi = bracket(lambda i, b=bits: self.measure(self.keeps[i], b), n, target, n // 2)
            if 0 <= lo and hi < n:
                a, b = self.keeps[lo], self.keeps[hi]
                for k in np.geomspace(a, b, DENSE + 2)[1:-1]:
                    self.measure(float(f"{k:.4g}"), bits)

    def bytes_at(self, target: float) -> float | None:
        from tetweave_codec.metrics.rate_distortion import bytes_at, pareto_front

        return bytes_at(pareto_front([(e, b) for b, e in self.points.values()]), target)

    def floor(self) -> float:
        return min(e for _, e in self.points.values())

    def floor_text(self) -> str:
        """The most accurate setting measured: 'floor E (keep% qbits, bytes B)'."""
        (k, q), (b, e) = min(self.points.items(), key=lambda kv: kv[1][1])
        return f"not reached: floor {e:.3g} ({100 * k:.3g}% q{q}, {b:,} B)"

    def best_within(self, target: float) -> str:
        """The smallest measured setting within `target`: 'keep% qbits, bytes B'."""
        within = [(b, k, q) for (k, q), (b, e) in self.points.items() if e <= target]
        if not within:
            return "-"
        b, k, q = min(within)
        return f"{100 * k:.3g}% q{q}, {b:,} B"


def main() -> None:
    from importlib.metadata import version

    from tetweave_codec.bench.rows import reference_chamfer
    from tetweave_codec.benchmarks.common import script_meshes, script_parser
    from tetweave_codec.benchmarks.visible_surface import build
    from tetweave_codec.encoder import encode
    from tetweave_codec.meshio import load_mesh, normalize, save_mesh, write_bytes_atomic
    from tetweave_codec.metrics.common import MetricOptions
    from tetweave_codec.metrics.fidelity import prepare_reference
    from tetweave_codec.options import EncodeOptions

    ap = script_parser(__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="5k,10k", help="comma-separated --size values (k = 1024)")
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--samples", type=int, default=100_000, help="surface samples of every Chamfer distance")
    ap.add_argument("--save", type=Path, default=None, help="folder for the messy inputs and the tetweave files")
    ap.add_argument("--before", action="store_true", help="also encode with --surface all (saved, measured)")
    args = ap.parse_args()
    sizes = [int(float(s[:-1]) * 1024) if s.endswith("k") else int(s) for s in args.sizes.split(",")]
    options = MetricOptions.for_samples(args.samples)
    print(f"pymeshlab {version('pymeshlab')}", flush=True)
    table = []
    for path in script_meshes(args):
        v0, f0 = load_mesh(path)
        v, _, _ = normalize(v0)
        for kind in args.kinds.split(","):
            (mv, mf), truth = build(kind, v, f0)
            reference = prepare_reference(*truth, options)
            if args.save:
                args.save.mkdir(parents=True, exist_ok=True)
                save_mesh(args.save / f"{path.stem}_{kind}.ply", mv, mf)
            fits = []
            for size in sizes:
                for surface in ("auto", "all") if args.before else ("auto",):
                    t0 = time.perf_counter()
                    res = encode(mv, mf, options=EncodeOptions(size=size, surface=surface, quality=args.quality))
                    error = reference_chamfer(reference, res.vertices, res.faces, options)
                    if args.save:
                        write_bytes_atomic(args.save / f"{path.stem}_{kind}_{size // 1024}k_{surface}.tw", res.data)
                    seconds = f"{time.perf_counter() - t0:.0f}s"
                    print(path.stem, kind, size, surface, res.stats["bytes"], f"{error:.3g}", seconds, flush=True)
                    if surface == "auto":
                        fits.append((size, res.stats["bytes"], error, res.stats["surface"]))
            fronts = {}
            for variant in VARIANTS:
                t0 = time.perf_counter()
                cv, cf = (mv, mf) if variant == "none" else ao_cleanup(mv, mf)
                front = MlabFront(cv, cf, reference, options)
                for _, _, error, _ in fits:
                    front.around(error)
                fronts[variant] = front
                print(
                    f"{path.stem} {kind} MeshLab ({variant}): {len(cf):,} of {len(mf):,} faces, "
                    f"{len(front.points)} settings, floor {front.floor():.3g}, {time.perf_counter() - t0:.0f}s",
                    flush=True,
                )
            for size, nbytes, error, surface in fits:
                cells = [path.stem, kind, f"{size // 1024}k", f"{nbytes:,}", f"{error:.3g}", surface]
                for variant in VARIANTS:
                    front = fronts[variant]
                    size_at = front.bytes_at(error)
                    if size_at is None:
                        cells += [front.floor_text(), "-", "-"]
                    else:
                        cells += [f"{size_at:,.0f}", f"**{nbytes / size_at:.2f}**", front.best_within(error)]
                table.append(cells)
                print(*cells, flush=True)
    print()
    print(
        "| mesh | input | --size | tetweave bytes | Chamfer vs visible truth | surface | MeshLab + Draco bytes "
        "| ratio | smallest MeshLab file within | with AO cleanup: bytes | ratio | smallest within |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for cells in table:
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
