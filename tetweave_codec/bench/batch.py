"""The batch runner of `tetweave bench`: every mesh x every method -> encode, decode, time, measure.

One result row per (mesh, method, setting), a plain dict with the keys of `COLUMNS`, plus one "input" row per
mesh (raw size and the input's own triangle quality and topology, for reference). Every method compresses the
input as given (all its faces) and is measured against the surface tetweave fits (`bench_target`: the input, or
its visible surface when `--surface` resolves to visible), named in each row's ``target`` column. A failure of
one method on one mesh (an exception anywhere in encode, decode or the metrics) is recorded in that row's
``error`` column and the batch goes on. Decoded meshes are handed to `on_mesh` one mesh at a time (for the
pictures), never all kept at once.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tetweave_codec.bench.methods import TETWEAVE, Method
from tetweave_codec.geometry.closest import SurfaceTree
from tetweave_codec.geometry.triangles import sample_surface
from tetweave_codec.metrics.common import MetricOptions, as_mesh
from tetweave_codec.metrics.fidelity import (
    Reference,
    point_surface_distance,
    prepare_mesh,
    prepare_reference,
    to_frame,
)
from tetweave_codec.metrics.summary import evaluate, mesh_report

# Result columns in CSV order. Distances are in the input's normalized frame (see tetweave_codec.metrics.fidelity).
ID_COLUMNS = ["mesh", "family", "curve", "setting"]
PARAM_COLUMNS = [
    "quantization_bits",
    "keep_fraction",
    "points",
    "target_bytes",
    "sh_degree",
    "layout",
    "holes",
    "points_stored",
]
SIZE_COLUMNS = ["bytes", "bits_per_vertex", "encode_s", "decode_s", "metrics_s"]
FIDELITY_COLUMNS = [
    "chamfer",
    "hausdorff",
    "normal_consistency",
    "f1@0.001",
    "f1@0.005",
    "edge_chamfer",
    "edge_f1",
    "inaccurate_normals_pct",
]
QUALITY_COLUMNS = [
    "aspect_ratio_gt4_pct",
    "radius_ratio_gt4_pct",
    "small_angle_lt10_pct",
    "self_intersect_pct",
    "watertight",
    "two_manifold",
    "oriented",
    "manifold3d_ok",
    "boundary_edges",
    "nonmanifold_edges",
    "n_vertices",
    "n_faces",
]
# unseen_area_pct (tetweave rows): % of the decoded area no outside view sees, the encode summary's self-check
# (metrics.unseen); target: what the distances are measured against, "all" (the input's faces) or "visible"
# (`bench_target`)
COLUMNS = [
    *ID_COLUMNS,
    *PARAM_COLUMNS,
    *SIZE_COLUMNS,
    *FIDELITY_COLUMNS,
    *QUALITY_COLUMNS,
    "unseen_area_pct",
    "target",
    "error",
]

INPUT_FAMILY = "input"
# How the classical settings are chosen (`tetweave bench --sweep`): every one, or those around the tetweave points.
ADAPTIVE, FULL = "adaptive", "full"
SWEEPS = (ADAPTIVE, FULL)
ProgressFn = Callable[[str], None]


@dataclass
class MeshResult:
    """Everything measured on one input mesh.

    name: label of the mesh (file stem, made unique). vertices (V,3), faces (F,3): the input. rows: result
    rows (the input row first). decoded: method name -> decoded (vertices, faces), successes only. files:
    tetweave setting -> its `.tw` bytes, successes only (classical outputs are not kept). target: what the rows
    were measured against (`Target.describe`; empty when the input could not be measured).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    rows: list[dict] = field(default_factory=list)
    decoded: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    files: dict[str, bytes] = field(default_factory=dict)
    target: str = ""


@dataclass(frozen=True)
class Target:
    """What a mesh's rows are measured against: mode "all" (the input) or "visible" (its visible surface,
    fit.visible), why (fit.visible.SurfaceChoice.reason), and the prepared reference (in the input's normalized
    frame either way, the frame of the encoder's own Chamfer distance)."""

    mode: str
    reason: str
    reference: Reference

    def describe(self) -> str:
        """One phrase for the summary and the progress lines."""
        if self.mode == "visible":
            return f"the input's visible surface ({self.reason}); the classical methods compress every input face"
        return f"the input ({self.reason})" if self.reason else "the input"


def bench_target(vertices: np.ndarray, faces: np.ndarray, surface: str, options: MetricOptions) -> Target:
    """The surface tetweave's `--surface` fits on this input (fit.visible.choose_surface on the normalized input,
    as the encoder decides it), prepared as the reference of every method's metrics. "all", and "auto" on a clean
    input, give exactly `prepare_reference(vertices, faces)`. InputError (fit.visible) when no face is visible."""
    if surface == "all":
        return Target("all", "", prepare_reference(vertices, faces, options))
    from tetweave_codec.fit.visible import choose_surface
    from tetweave_codec.meshio import normalize

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    normalized, scale, offset = normalize(v)
    choice = choose_surface(normalized, f, surface)
    if choice.mode != "visible":
        return Target("all", choice.reason, prepare_reference(vertices, faces, options))
    # the visible surface is in the input's normalized frame already: measured there, as the encoder measures
    mesh = prepare_mesh(choice.surface.vertices, choice.surface.faces, options)
    return Target("visible", choice.reason, Reference(mesh, float(scale), np.asarray(offset, dtype=np.float64)))


def find_meshes(path: str | Path) -> list[Path]:
    """The mesh files of a folder (by extension, sorted, not recursive), or [path] for a single file.

    Raises InputError when there is nothing to benchmark.
    """
    from tetweave_codec.errors import InputError
    from tetweave_codec.meshio import MESH_FORMATS

    path = Path(path)
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise InputError(f"{path}: no such file or folder")
    found = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in MESH_FORMATS)
    if not found:
        raise InputError(f"{path}: no mesh files ({', '.join(sorted(MESH_FORMATS))})")
    return found


def mesh_labels(paths: Sequence[Path]) -> list[str]:
    """Unique, file-name-safe labels: the stem, or stem_ext when two files share a stem."""
    stems = [re.sub(r"[^A-Za-z0-9._+-]+", "_", p.stem) for p in paths]
    labels = []
    for path, stem in zip(paths, stems, strict=True):
        labels.append(stem if stems.count(stem) == 1 else f"{stem}_{path.suffix.lstrip('.').lower()}")
    return labels


def _referenced_vertices(faces: np.ndarray) -> int:
    used = np.zeros(int(faces.max()) + 1 if len(faces) else 0, dtype=bool)
    used[faces.reshape(-1)] = True
    return int(used.sum())


def _empty_row(name: str, method: Method | None) -> dict:
    row = dict.fromkeys(COLUMNS, "")
    row["mesh"] = name
    if method is None:
        row.update(family=INPUT_FAMILY, curve=INPUT_FAMILY, setting="raw float32")
    else:
        row.update(family=method.family, curve=method.curve, setting=method.setting)
        row.update(method.params())
    return row


def _error_text(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return f"{type(exc).__name__}: {text}"[:300]


def input_row(name: str, vertices: np.ndarray, faces: np.ndarray, options: MetricOptions) -> dict:
    """The reference row of an input: raw size (float32 xyz + uint32 indices) and its own quality."""
    row = _empty_row(name, None)
    n_in = _referenced_vertices(faces)
    row["bytes"] = 12 * n_in + 12 * len(faces)
    row["bits_per_vertex"] = 8.0 * row["bytes"] / n_in
    t0 = time.perf_counter()
    report = mesh_report(vertices, faces, options)
    row["metrics_s"] = time.perf_counter() - t0
    row.update({k: v for k, v in report.items() if k in COLUMNS})
    return row


def encode_method(name: str, method: Method, vertices: np.ndarray, faces: np.ndarray) -> tuple[dict, bytes | None]:
    """Encode one mesh with one method: (its row with the size columns, the bytes; None and the row's error on
    failure)."""
    row = _empty_row(name, method)
    try:
        t0 = time.perf_counter()
        data = method.encode(vertices, faces)
        row["encode_s"] = time.perf_counter() - t0 + method.reused_seconds()
        row["bytes"] = len(data)
        row["bits_per_vertex"] = 8.0 * len(data) / _referenced_vertices(faces)
        row.update(method.info(data))
        return row, data
    except Exception as exc:  # one failure must not stop the batch; it is reported in the row
        row["error"] = _error_text(exc)
        return row, None


def measure_method(
    row: dict, method: Method, data: bytes, reference: Reference, options: MetricOptions, chamfer_only: bool = False
) -> tuple[np.ndarray, np.ndarray] | None:
    """Decode `encode_method`'s bytes and fill `row` with the decoded mesh's metrics against the prepared input
    (all of them, or with `chamfer_only` the Chamfer distance and the counts: `reference_chamfer`, ~6x cheaper);
    returns the decoded mesh, None (and the row's error) on failure."""
    try:
        t0 = time.perf_counter()
        v_out, f_out = method.decode(data)
        row["decode_s"] = time.perf_counter() - t0
        row["n_vertices"], row["n_faces"] = _referenced_vertices(f_out), len(f_out)
        t0 = time.perf_counter()
        if chamfer_only:
            metrics = {"chamfer": reference_chamfer(reference, v_out, f_out, options)}
        else:
            metrics = evaluate(reference, v_out, f_out, options)
        row["metrics_s"] = time.perf_counter() - t0
        row.update({k: v for k, v in metrics.items() if k in COLUMNS})
        return v_out, f_out
    except Exception as exc:  # one failure must not stop the batch; it is reported in the row
        row["error"] = _error_text(exc)
        return None


def reference_chamfer(reference: Reference, vertices: np.ndarray, faces: np.ndarray, options: MetricOptions) -> float:
    """The `chamfer` of `summary.evaluate` (the same samples, hence the same value) without the other metrics: the
    input's samples and tree come prepared, the decoded mesh (vertices (V,3) in the input's frame, faces (F,3)) is
    sampled and its tree built. ValueError on a mesh without faces."""
    v, f = as_mesh(to_frame(vertices, reference.scale, reference.offset), faces)
    if len(f) == 0:
        raise ValueError("the decoded mesh has no faces")
    points, _ = sample_surface(v, f, options.n_samples, options.seed)
    to_decoded, _ = SurfaceTree(v, f).query(reference.mesh.points)[:2]
    to_input, _ = point_surface_distance(points, reference.mesh)
    return float(0.5 * (np.sqrt(np.maximum(to_decoded, 0.0)).mean() + to_input.mean()))


def run_method(
    name: str, method: Method, vertices: np.ndarray, faces: np.ndarray, reference, options: MetricOptions
) -> tuple[dict, tuple[np.ndarray, np.ndarray] | None, bytes | None]:
    """Encode, decode and measure one method on one mesh; returns (row, decoded mesh, encoded bytes), the last
    two None on failure."""
    row, data = encode_method(name, method, vertices, faces)
    decoded = None if data is None else measure_method(row, method, data, reference, options)
    if decoded is not None and method.family == TETWEAVE:
        _self_check(row, *decoded)
    return row, decoded, (None if decoded is None else data)


def _self_check(row: dict, vertices: np.ndarray, faces: np.ndarray) -> None:
    """The encode summary's self-check of a decoded tetweave mesh into `row`: unseen_area_pct (metrics.unseen;
    left empty when not measured), its time added to metrics_s."""
    from tetweave_codec.metrics.unseen import self_check

    try:
        check = self_check(vertices, faces)
    except Exception as exc:  # one failure must not stop the batch; it is reported in the row
        row["error"] = _error_text(exc)
        return
    if check is not None:
        row["unseen_area_pct"] = 100.0 * check.share
        row["metrics_s"] = (row.get("metrics_s") or 0.0) + check.seconds


def say_row(say: ProgressFn, name: str, label: str, row: dict) -> None:
    """One progress line for a measured row (or its failure)."""
    if row.get("error"):
        say(f"{name}: {label}: FAILED: {row['error']}")
        return
    say(
        f"{name}: {label}: {row['bytes']:,} bytes, CD {row['chamfer']:.3g}, {row['n_faces']:,} faces "
        f"(encode {row['encode_s']:.2f}s, decode {row['decode_s']:.2f}s, metrics {row['metrics_s']:.1f}s)"
    )


def run_mesh(
    name: str,
    vertices: np.ndarray,
    faces: np.ndarray,
    methods: Sequence[Method],
    options: MetricOptions | None = None,
    progress: ProgressFn | None = None,
    sweep: str = ADAPTIVE,
    surface: str = "auto",
) -> MeshResult:
    """All methods on one (already loaded) mesh. sweep: "full" measures every classical setting; "adaptive" (the
    default) runs the tetweave methods first and then only the classical settings that bracket their Chamfer
    distances (`sweep.adaptive_sweep`; every setting when there is no tetweave point to compare with). surface:
    the tetweave methods' `--surface`; every row is measured against what it resolves to (`bench_target`)."""
    if sweep not in SWEEPS:
        raise ValueError(f"sweep is one of {', '.join(SWEEPS)}, got {sweep!r}")
    opts = options or MetricOptions()
    say = progress or (lambda _msg: None)
    result = MeshResult(name, vertices, faces)
    try:
        result.rows.append(input_row(name, vertices, faces, opts))
        target = bench_target(vertices, faces, surface, opts)
    except Exception as exc:  # e.g. a zero-area input: nothing can be measured against it
        error = _error_text(exc)
        say(f"{name}: cannot measure against this input: {error}")
        result.rows = [_empty_row(name, m) | {"error": f"input: {error}"} for m in [None, *methods]]
        return result
    reference, result.target = target.reference, target.describe()
    say(f"{name}: measured against {result.target}")
    fits = [m for m in methods if m.family == TETWEAVE]
    if sweep == ADAPTIVE and fits and len(fits) < len(methods):
        from tetweave_codec.bench.sweep import adaptive_sweep

        _run_each(result, fits, reference, opts, say)
        targets = [float(r["chamfer"]) for r in result.rows if r["family"] == TETWEAVE and not r.get("error")]
        classical = [m for m in methods if m.family != TETWEAVE]
        adaptive_sweep(result, classical, targets, reference, opts, say)
    else:
        _run_each(result, methods, reference, opts, say)
    for row in result.rows:
        row["target"] = target.mode
    return result


def _run_each(result: MeshResult, methods: Sequence[Method], reference: Reference, options, say) -> None:
    """Every method on result's mesh, in order, all metrics; rows, decoded meshes and tetweave files into result."""
    for i, method in enumerate(methods, 1):
        label = f"[{i}/{len(methods)}] {method.name}"
        say(f"{result.name}: {label} ...")
        row, decoded, data = run_method(result.name, method, result.vertices, result.faces, reference, options)
        result.rows.append(row)
        if decoded is not None:
            result.decoded[method.name] = decoded
            if method.family == TETWEAVE:
                result.files[method.setting] = data
        say_row(say, result.name, label, row)


def run_batch(
    paths: Sequence[str | Path],
    methods: Sequence[Method],
    options: MetricOptions | None = None,
    progress: ProgressFn | None = None,
    on_mesh: Callable[[MeshResult], None] | None = None,
    sweep: str = ADAPTIVE,
    surface: str = "auto",
) -> list[dict]:
    """Run every method on every mesh file; returns all rows (input rows included).

    A mesh that cannot be loaded gets one row per method carrying the load error. `on_mesh` is called after
    each mesh with its MeshResult (decoded meshes included), e.g. to write pictures and partial results. surface:
    as in `run_mesh`.
    """
    from tetweave_codec.meshio import load_mesh

    say = progress or (lambda _msg: None)
    paths = [Path(p) for p in paths]
    rows: list[dict] = []
    for k, (path, name) in enumerate(zip(paths, mesh_labels(paths), strict=True), 1):
        say(f"mesh {k}/{len(paths)}: {path}")
        try:
            vertices, faces = load_mesh(path)
        except Exception as exc:
            error = _error_text(exc)
            say(f"{name}: cannot load: {error}")
            for method in methods:
                row = _empty_row(name, method)
                row["error"] = f"load: {error}"
                rows.append(row)
            continue
        result = run_mesh(name, vertices, faces, methods, options, progress, sweep, surface)
        rows.extend(result.rows)
        if on_mesh is not None:
            on_mesh(result)
    return rows
