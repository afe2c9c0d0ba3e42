"""The batch runner of `tetweave bench`: every mesh x every method -> encode, decode, time, measure.

One result row per (mesh, method, setting) plus one "input" row per mesh (rows.py: the columns, one method on one
mesh). Every method compresses the input as given (all its faces) and is measured against the surface tetweave
fits (`bench_target`: the input, or its visible surface when `--surface` resolves to visible), named in each row's
``target`` column. The classical settings are every one (`--sweep full`) or those around the tetweave files'
Chamfer distances (sweep.py, the default). A failure of one method on one mesh (an exception anywhere in encode,
decode or the metrics) is recorded in that row's ``error`` column and the batch goes on. Decoded meshes are
handed to `on_mesh` one mesh at a time (for the pictures), never all kept at once.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tetweave_codec.bench.methods import TETWEAVE, Method
from tetweave_codec.bench.rows import MeshResult, ProgressFn, empty_row, error_text, input_row, run_method, say_row
from tetweave_codec.bench.sweep import adaptive_sweep
from tetweave_codec.metrics.common import MetricOptions
from tetweave_codec.metrics.fidelity import Reference, prepare_mesh, prepare_reference

# How the classical settings are chosen (`tetweave bench --sweep`): every one, or those around the tetweave points.
ADAPTIVE, FULL = "adaptive", "full"
SWEEPS = (ADAPTIVE, FULL)


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
        error = error_text(exc)
        say(f"{name}: cannot measure against this input: {error}")
        result.rows = [empty_row(name, m) | {"error": f"input: {error}"} for m in [None, *methods]]
        return result
    reference, result.target = target.reference, target.describe()
    say(f"{name}: measured against {result.target}")
    fits = [m for m in methods if m.family == TETWEAVE]
    if sweep == ADAPTIVE and fits and len(fits) < len(methods):
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
            error = error_text(exc)
            say(f"{name}: cannot load: {error}")
            for method in methods:
                row = empty_row(name, method)
                row["error"] = f"load: {error}"
                rows.append(row)
            continue
        result = run_mesh(name, vertices, faces, methods, options, progress, sweep, surface)
        rows.extend(result.rows)
        if on_mesh is not None:
            on_mesh(result)
    return rows
