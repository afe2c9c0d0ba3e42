"""Encoder API: mesh -> normalized frame -> fit -> `.tw` bytes, plus the mesh a decoder will rebuild from them.

    result = encode(vertices, faces, points=16384, sh_degree=1, quality="default")
    open("mesh.tw", "wb").write(result.data)
    result.vertices, result.faces   # exactly what `tetweave_codec.decoder.decode(result.data)` returns

The reported mesh is produced by the decoder itself from the finished bytes, so "decode gives exactly the mesh the
encoder reported" holds by construction (and is tested).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import NamedTuple

import numpy as np
import torch

from tetweave_codec.errors import InputError
from tetweave_codec.fit.config import DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, schedule_for
from tetweave_codec.fit.finish import complete, finish
from tetweave_codec.fit.loop import deterministic_torch
from tetweave_codec.fit.prepared import PreparedInput, prepare_input
from tetweave_codec.fit.step import ProgressFn
from tetweave_codec.formats.quantize import Quantization
from tetweave_codec.geometry.triangles import face_areas
from tetweave_codec.job import EncodeResult, FitSettings, Job
from tetweave_codec.options import HOLES, LAYOUTS, MAX_POINTS, EncodeOptions, check_encode_arguments
from tetweave_codec.packing import HOLES_CHAMFER_SAMPLES, SUMMARY_CHAMFER_SAMPLES, pack_result

__all__ = [
    "HOLES",
    "HOLES_CHAMFER_SAMPLES",
    "LAYOUTS",
    "MAX_POINTS",
    "SUMMARY_CHAMFER_SAMPLES",
    "EncodeOptions",
    "EncodeResult",
    "Job",
    "encode",
    "input_defaults",
    "pack_result",
    "resolve_device",
]

DEFAULT_POINTS = 16384  # the most grid points an encode without a rate option fits (`default_points`)
# Without --points, --size or --max-error the fit's size follows the input (`default_points`): its decoded mesh
# gets at most about DEFAULT_FACE_RATIO x the input's faces. A fixed 16K-point default turned spot's 23K faces
# into 268K (issue 41); a user compressing a mesh does not expect a denser one back.
DEFAULT_FACE_RATIO = 2.0
# Marching-tets faces per fit grid point, before the decoder's Loop levels (x4 each): 4.1 (spot), 4.5 (igea),
# 4.6 (stanford-bunny, fandisk) on the bench's 5 KB files (benchmarks/results/results.csv: faces / 4^levels /
# grid points); the largest keeps the decoded faces under the ratio.
CONTROL_FACES_PER_POINT = 4.6
MIN_DEFAULT_POINTS = 256  # below this the fit cannot hold a shape; tiny inputs get it (and the summary's Draco line)
# The default encode of a tiny input (`small_input`: one whose `default_points` is MIN_DEFAULT_POINTS, below ~2,350
# faces with a Loop level, ~590 without) runs the preset's iterations as they are (not scaled up for a small fit,
# fit.config.scaled_schedule: 400 instead of 700 by default) with SMALL_INPUT_SAMPLES input samples per call of the
# 3-D term instead of fit.surface_loss.INPUT_SAMPLES (8,000): the control mesh of 256 points has ~1,000 faces, and
# 8,000 samples per call were half of each iteration. Encode (one thread, API) of a 4-face tetrahedron, a 12-face
# cube, a 20-face icosahedron, an 80-face sphere, a 500-face torus: 12-13 s -> 3.0-3.4 s; Chamfer 1.59e-3 / 1.03e-3 /
# 3.00e-3 / 3.08e-3 / 3.95e-3 -> 1.43e-3 / 2.47e-3 / 4.00e-3 / 3.44e-3 / 4.50e-3; with 700 iterations 4.5-5.1 s and
# 1.80e-3 / 1.15e-3 / 4.68e-3 / 3.22e-3 / 3.83e-3 (tiny fits vary by ~1.5x from run to run); 1,000 samples per call
# measured the same errors as 500 (docs/measurements/small_inputs.md).
SMALL_INPUT_SAMPLES = 500
DEFAULT_SH_DEGREE = 1
# SH degree of CAD parts (`input_defaults`): none. fandisk, bytes x Chamfer of rate-controlled
# files against degree 1 (docs/measurements/creases.md, 2026-12-01): 10 KB 0.87-0.92 (three seeds), 20 / 40 KB
# 0.97-0.99, 5 KB 0.85-1.10 (three seeds, noise); CSG parts at 1-2 KB median 0.93. On the smooth meshes degree 1
# stays (igea 10 KB 1.075 without it, spot 0.978-1.000, stanford-bunny 0.978-1.014).
CREASED_SH_DEGREE = -1
# Taubin steps of CAD parts (`input_defaults`): three crease-preserving steps (the smoothing keeps the
# extracted surface's creases, geometry.smoothing.crease_neighbours; three is the most the header holds), fitted
# through in the late stage only (FitConfig.main_filter); no subdivision (it raised the edge Chamfer 1.2-2.2x).
# fandisk, bytes x Chamfer against no smoothing at 5 / 10 / 20 / 40 KB (one thread, the same run): 1 step 0.880
# / 0.886 / 0.918 / 0.931, 2 steps 0.828 / 0.830 / 0.893 / 0.910, 3 steps 0.788 / 0.803 / 0.885 / 0.915, with the
# edge Chamfer lower than without smoothing at every size (docs/measurements/creases.md, 2026-12-02).
CREASED_SMOOTHING = 3
# Crease density (`fit.features.crease_density`: crease length / sqrt(area)) from which an input with sharp creases is a
# CAD part and takes the settings above (`input_defaults`); below it, the smooth-mesh settings (one smoothing step, one
# Loop level, SH degree 1) with the creases kept. Shapes whose every face is bounded by creases lie above (a cube 4.90,
# a regular tetrahedron 4.56, boxes and prisms more; fandisk 8.83, CSG parts 5.8-10.3: creases.py at ffee759),
# shapes whose creases bound curved faces and organic models with a few sharp details below (a cylinder 2.89, a sphere
# cut by a plane 1.45, a capsule with a flat end 1.14, beast 1.02, cheburashka 0.50). Bytes x Chamfer of --size files,
# smooth settings with creases kept against the CAD settings, one thread, one run: the cut sphere 2 / 5 KB 0.94 / 0.94,
# the capsule 2 KB 0.86, the cylinder 2 KB 0.89, cheburashka 10 KB 0.84, beast 0.93, edge Chamfer 0.93-1.10x; above it
# the CAD settings win on fandisk (5 / 10 / 20 KB 1.15 / 1.04 / 1.46 with the smooth ones, edge Chamfer 1.4-3.1x), the
# cube and the fin (1.03-1.18), not on three boxes (0.65-0.77): docs/measurements/creases.md, 2026-12-02. 4.0 keeps a
# margin below those shapes (cow, 4.49, stays with the CAD settings although it measured 0.92).
CAD_CREASE_DENSITY = 4.0


def resolve_device(device: str | torch.device) -> torch.device:
    """'auto' -> CUDA when available, else CPU."""
    if isinstance(device, torch.device):
        return device
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device == "cuda" and not torch.cuda.is_available():
        raise InputError("device 'cuda' was asked for but no CUDA device is available")
    if device not in ("cpu", "cuda"):
        raise InputError(f"unknown device {device!r}; use auto, cpu or cuda")
    return torch.device(device)


def _validate(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """float64 vertices and int64 faces, or InputError (meshio's checks, plus a surface to fit)."""
    from tetweave_codec.meshio import validate_mesh

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    validate_mesh(v, f)
    if not face_areas(v, f).any():
        raise InputError("mesh: every triangle has zero area")
    if _is_planar(v[np.unique(f)]):
        raise InputError(
            "mesh: every vertex lies in one plane, so the surface encloses no volume; tetweave encodes closed or "
            "nearly closed shapes"
        )
    return v, f


# Relative thickness (smallest over largest singular value of the centred vertices) below which a mesh counts as
# planar: a float64 plane rotated off the axes measures ~1e-16; a sheet 1e-6 thick as 1e-6.
PLANAR_THICKNESS = 1e-9


def _is_planar(points: np.ndarray) -> bool:
    """Whether the points (V,3) lie in one plane, up to PLANAR_THICKNESS of their spread."""
    if len(points) < 4:
        return True
    sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)  # descending
    return bool(sv[-1] < PLANAR_THICKNESS * sv[0])


def encode(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    points: int | None = None,
    sh_degree: int | None = None,
    quality: str = "default",
    iters: int | None = None,
    device: str | torch.device = "auto",
    seed: int = 0,
    init: str = "sdf",
    progress: ProgressFn | None = None,
    measure: bool = True,
    container_version: int = 2,
    quantization: Quantization | None = None,
    size: int | None = None,
    max_error: float | None = None,
    smoothing: int | None = None,
    subdivision: int | None = None,
    layout: str = "fit",
    holes: str = "close",
    keep_creases: bool | None = None,
    surface: str = "auto",
    options: EncodeOptions | None = None,
) -> EncodeResult:
    """Fit a TetWeave representation to a triangle mesh and return the `.tw` bytes and the decoded mesh.

    vertices (V,3), faces (F,3): any triangle mesh (open, multi-component and non-manifold inputs are fine).
    points: target grid points during the fit (passive ones are dropped before writing, so fewer are stored);
        None = `default_points` of the input's faces and the decoder's subdivision.
    sh_degree: -1 (none) or 0..3, directional distance coefficients per point (q = (degree+1)^2); None =
        `input_defaults`' choice.
    quality: "fast", "default" or "best" (see fit.QUALITY); iters overrides its main+late iteration count.
    measure: compute the Chamfer distance between the input and the decoded mesh for `stats`.
    container_version: 2 (quantized, entropy-coded; default) or 1 (raw float16).
    quantization: v2's position bits and steps; None = `formats.quantize.default_quantization(points)`.
    size: rate control, the file is at most `size` bytes and at least 85 % of it (points and quantization are
        chosen by tetweave_codec.rate_control; `points` and `quantization` are ignored).
    max_error: rate control, the decoded mesh's Chamfer distance to the input (normalized frame, the summary's
        metric) is at most `max_error`, at the smallest size rate control finds.
    smoothing: Taubin steps 0-3 the decoder applies to the surface (the fit optimizes the smoothed one); None =
        `input_defaults`' choice for container version 2, 0 for version 1 (which cannot store it).
    subdivision: Loop levels 0-2 the decoder applies after the smoothing (the fit optimizes the subdivided
        surface); None = `input_defaults`' choice for container version 2, 0 for version 1.
    keep_creases: the decoder's smoothing and subdivision keep the creases of the extracted surface (edges whose
        faces turn by more than 30 degrees; geometry.smoothing.crease_neighbours, Loop's crease rules) instead of
        rounding them; None = `input_defaults`' choice (on for inputs with sharp creases). Container version 2;
        nothing to keep without smoothing or subdivision.
    layout: where the points come from (see LAYOUTS): "fit" (placed by the fit, then snapped to the grid),
        "grid" (the cells of a lattice in a band around the input, fit.grid; container version 2 only; `points`
        sets the cell size: the band holds about that many points) or "best" (with `size` or `max_error` only:
        both, and the better file).
    holes: "close" (every output watertight) or "keep" (an open input's holes stay open: the decoder removes the
        faces that span them, listed in the file; container version 2 only). See HOLES.
    surface: what the fit takes as the input's surface (options.SURFACES, fit/visible.py): "all" its faces,
        "visible" the faces offscreen renders see from outside (hidden parts and internal walls dropped, each face
        oriented towards its views), "auto" the visible surface where the input needs it (inconsistent
        orientation, hidden area), else all (the same bytes). Chamfer distances, --size and --max-error then
        measure against that surface; stats["surface"] and stats["surface_reason"] say which and why.
    options: all of the above as one validated `options.EncodeOptions` (what the CLI and the batch workers pass);
        then no other option may be given (progress may).
    Deterministic: the same input, options, seed, device and thread count give the same bytes.
    """
    if options is not None:
        _check_no_other_options(locals())
        kwargs = options.encoder_kwargs(resolve_device(options.device))
        return encode(vertices, faces, progress=progress, **kwargs)
    given = {k: v for k, v in locals().items() if k not in ("vertices", "faces", "options", "surface")}
    result = _encode(vertices, faces, surface=surface, **given)
    if surface == "auto" and measure and result.prepared.outside_differs:
        result = _checked(result, lambda: _encode(vertices, faces, surface="visible", **given))
    return result


def _checked(result: EncodeResult, outside) -> EncodeResult:
    """The self-check acting (metrics.unseen): when `auto` kept every face of an input whose outside surface is
    another (open or inconsistently oriented pieces: `PreparedInput.outside_differs`) and more than WARN_SHARE of
    the decoded area is hidden from every outside view, something chose wrong: `outside()` encodes the outside
    surface (--surface visible) and the file whose decoded mesh the check finds less hidden is kept; the summary's
    reason says so. (Closed parts alone, disjoint or touching, are their own outside surface: nothing to try.)"""
    from tetweave_codec.metrics.unseen import WARN_SHARE, self_check

    check = self_check(result.vertices, result.faces)
    if check is None or check.share <= WARN_SHARE:
        return result
    other = outside()
    other_check = self_check(other.vertices, other.faces)
    if other_check is None:
        return result
    kept, dropped = (other, result) if other_check.share < check.share else (result, other)
    what = "the outside surface" if kept is other else "every face"
    kept.stats["surface_reason"] = (
        f"{kept.stats.get('surface_reason', '')}; the self-check found {100 * check.share:.1f} % of the decoded "
        f"area hidden with every face, {100 * other_check.share:.1f} % with the outside surface: kept {what}"
    )
    return kept


def _encode(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    points: int | None,
    sh_degree: int | None,
    quality: str,
    iters: int | None,
    device,
    seed: int,
    init: str,
    progress: ProgressFn | None,
    measure: bool,
    container_version: int,
    quantization: Quantization | None,
    size: int | None,
    max_error: float | None,
    smoothing: int | None,
    subdivision: int | None,
    layout: str,
    holes: str,
    keep_creases: bool | None,
    surface: str,
) -> EncodeResult:
    """`encode` with `surface` as given (the self-check does not act here); every option as `encode` has it."""
    check_encode_arguments(
        points=points,
        sh_degree=sh_degree,
        container_version=container_version,
        size=size,
        max_error=max_error,
        layout=layout,
        quantization_given=quantization is not None,
        holes=holes,
        smoothing=smoothing,
        subdivision=subdivision,
        keep_creases=keep_creases,
        surface=surface,
    )
    v, f = _validate(vertices, faces)
    prepared = prepare_input(v, f, seed=seed, keep_holes=holes == "keep")
    sizing_faces = len(f)  # the faces the default fit's size follows (`default_points`)
    if surface != "all":
        from tetweave_codec.fit.visible import choose_surface

        choice = choose_surface(prepared.normalized, prepared.faces, surface)
        if choice.mode == "visible":
            prepared = prepared.on_visible_surface(choice.surface, choice.reason)
            sizing_faces = target_faces(choice.surface, len(f))
        else:
            prepared.surface_reason = choice.reason
            prepared.outside_differs = choice.outside_differs
    if smoothing is None or subdivision is None or sh_degree is None or keep_creases is None:
        chosen = prepared_defaults(prepared)
        if container_version != 2:  # version 1 stores neither filter
            chosen = chosen._replace(smoothing=0, subdivision=0, creases=False)
        smoothing = chosen.smoothing if smoothing is None else smoothing
        subdivision = chosen.subdivision if subdivision is None else subdivision
        sh_degree = chosen.sh_degree if sh_degree is None else sh_degree
        keep_creases = chosen.creases if keep_creases is None else keep_creases
    schedule = schedule_for(quality, iters)
    small = points is None and size is None and max_error is None and small_input(sizing_faces, subdivision)
    if small:  # a tiny input's default fit: see SMALL_INPUT_SAMPLES
        schedule = replace(schedule, surface_samples=SMALL_INPUT_SAMPLES)
    if points is None:
        points = default_points(sizing_faces, subdivision)
    settings = FitSettings(
        sh_degree=sh_degree,
        schedule=schedule,
        quality=quality,
        device=resolve_device(device),
        seed=seed,
        init=init,
        scale_iterations=iters is None and not small,
        smoothing=smoothing,
        subdivision=subdivision,
        creases=bool(keep_creases and (smoothing or subdivision)),
    )

    def make_job(layout: str) -> Job:
        return Job(prepared, settings, layout, progress)

    if layout == "best":
        return _best_layout(make_job, size, max_error)
    job = make_job(layout)
    if size is not None:
        from tetweave_codec.rate_control import encode_to_size

        return encode_to_size(job, int(size), measure=measure)
    if max_error is not None:
        from tetweave_codec.rate_control import encode_to_error

        return encode_to_error(job, float(max_error))
    if container_version == 1:
        ctx, params = job.main_stage(points, None)
        with deterministic_torch():
            fin = finish(params, ctx)
        return job.result(fin, ctx, points, measure=measure)
    ctx, fixed, quantization = job.stage(points, quantization)
    with deterministic_torch():
        fin = complete(fixed, ctx, quantization)
    return job.result(fin, ctx, points, measure=measure)


def default_points(input_faces: int, subdivision: int) -> int:
    """Grid points of an encode without a rate option: the most (up to DEFAULT_POINTS, at least
    MIN_DEFAULT_POINTS) whose decoded mesh has about DEFAULT_FACE_RATIO x `input_faces` faces or fewer, given the
    decoder's `subdivision` Loop levels (each multiplies the faces by 4)."""
    per_point = CONTROL_FACES_PER_POINT * 4**subdivision
    return int(min(DEFAULT_POINTS, max(MIN_DEFAULT_POINTS, DEFAULT_FACE_RATIO * input_faces / per_point)))


def target_faces(surface, input_faces: int) -> int:
    """The faces the default fit's size follows when the encode fits `surface` (fit.visible.VisibleSurface) of an
    input of `input_faces` faces: the surface's own, at most the input's. Hidden parts and inner walls are not the
    shape's detail (a ball with a hidden ball inside is sized as the ball alone); the pieces the union cuts at seams
    and renders split to pixels are not either (parts through each other are sized by their faces, not more)."""
    return min(input_faces, len(surface.faces))


def small_input(input_faces: int, subdivision: int) -> bool:
    """Whether an input of `input_faces` faces is tiny: its default fit (`default_points`, the decoder's `subdivision`
    Loop levels) is the smallest, MIN_DEFAULT_POINTS. Its default encode takes the fast settings of
    SMALL_INPUT_SAMPLES."""
    return default_points(input_faces, subdivision) == MIN_DEFAULT_POINTS


def _check_no_other_options(given: dict) -> None:
    """TypeError when `encode` was given `options` and also another option (one source of options per call)."""
    import inspect

    skip = {"vertices", "faces", "options", "progress"}
    others = [
        name
        for name, param in inspect.signature(encode).parameters.items()
        if name not in skip and given[name] is not param.default and given[name] != param.default
    ]
    if others:
        raise TypeError(f"encode: give either options or {', '.join(others)}, not both")


def _best_layout(make_job, size: int | None, max_error: float | None) -> EncodeResult:
    """Rate control in both layouts; the file with the lower Chamfer distance (--size) or the fewer bytes
    (--max-error). A layout that cannot meet the target is skipped; when neither can, the fit layout's error is
    raised. The stats say which layout won and what each gave ("layouts")."""
    from tetweave_codec.rate_control import encode_to_error, encode_to_size

    t0 = time.perf_counter()
    results: dict[str, EncodeResult] = {}
    failures: dict[str, InputError] = {}
    for name in ("fit", "grid"):
        try:
            job = make_job(name)
            if size is not None:
                results[name] = encode_to_size(job, int(size), measure=True)
            else:
                results[name] = encode_to_error(job, float(max_error))
        except InputError as exc:
            failures[name] = exc
    if not results:
        raise failures["fit"]
    if size is not None:
        best = min(results, key=lambda k: (results[k].stats["chamfer"], len(results[k].data)))
    else:
        best = min(results, key=lambda k: (len(results[k].data), results[k].stats["chamfer"]))
    chosen = results[best]
    tried = {k: {"bytes": len(r.data), "chamfer": r.stats["chamfer"]} for k, r in results.items()}
    tried.update({k: {"error": str(exc)} for k, exc in failures.items()})
    others = ", ".join(
        f"{k}: {t['bytes']:,} B at {t['chamfer']:.3g}" if "bytes" in t else f"{k}: {t['error']}"
        for k, t in tried.items()
        if k != best
    )
    stats = dict(chosen.stats, layouts=tried)
    stats["rate_control"] = f"best layout {best} ({chosen.stats['rate_control']}; {others})"
    stats["seconds"] = dict(stats["seconds"], total=time.perf_counter() - t0)
    return EncodeResult(chosen.data, chosen.vertices, chosen.faces, stats, chosen.prepared)


class InputDefaults(NamedTuple):
    """What `encode` picks for an input when not told: the decoder's Taubin steps and Loop levels, the SH degree."""

    smoothing: int
    subdivision: int
    sh_degree: int
    creases: bool = False  # the smoothing keeps the surface's creases


def input_defaults(vertices: np.ndarray, faces: np.ndarray) -> InputDefaults:
    """The settings `encode` picks for a mesh. Without sharp creases (`fit.features.detect_features(...).found`):
    (DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, DEFAULT_SH_DEGREE, no creases kept). CAD parts (sharp creases with a
    crease density of at least CAD_CREASE_DENSITY): (CREASED_SMOOTHING, 0, CREASED_SH_DEGREE, creases kept). Other
    inputs with sharp creases (curved faces between a few creases, organic models with sharp details): the smooth
    settings with the creases kept. Why: the plain smoothing and subdivision round every crease the fit reproduces
    (on CSG parts smoothing doubled the edge Chamfer distance at 1-2 KB, docs/measurements/smoothing.md), while on
    scans and smooth shapes they save bytes at equal error (docs/measurements/subdivision.md); crease-preserving
    smoothing saves CAD parts bytes without rounding their edges, Loop subdivision even with crease rules still
    raised their edge Chamfer (see CREASED_SMOOTHING); the SH coefficients cost CAD parts more than they buy (see
    CREASED_SH_DEGREE); where the creases bound only a small part of the surface, the smooth settings with the
    creases kept win (see CAD_CREASE_DENSITY). vertices (V,3) in any frame (the creases are looked for in the
    normalized frame, as the fit's start does)."""
    return prepared_defaults(prepare_input(vertices, faces))


def prepared_defaults(prepared: PreparedInput) -> InputDefaults:
    """`input_defaults` of an input already prepared (its creases detected once for the whole encode)."""
    from tetweave_codec.fit.features import crease_density

    features = prepared.features
    if not features.found:
        return InputDefaults(DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, DEFAULT_SH_DEGREE)
    if crease_density(features, prepared.normalized, prepared.faces) >= CAD_CREASE_DENSITY:
        return InputDefaults(CREASED_SMOOTHING, 0, CREASED_SH_DEGREE, creases=True)
    return InputDefaults(DEFAULT_SMOOTHING, DEFAULT_SUBDIVISION, DEFAULT_SH_DEGREE, creases=True)
