"""Encoder API: mesh -> normalized frame -> fit -> `.tw` bytes, plus the mesh a decoder will rebuild from them.

    result = encode(vertices, faces, points=16384, sh_degree=1, quality="default")
    open("mesh.tw", "wb").write(result.data)
    result.vertices, result.faces   # exactly what `tetweave_codec.decoder.decode(result.data)` returns

The reported mesh is produced by the decoder itself from the finished bytes, so "decode gives exactly the mesh the
encoder reported" holds by construction (and is tested).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from tetweave_codec.errors import InputError
from tetweave_codec.fit.config import FitConfig, Quantization, default_quantization, schedule_for
from tetweave_codec.fit.loop import FitResult, fit
from tetweave_codec.fit.step import ProgressFn
from tetweave_codec.geometry.sh import check_degree
from tetweave_codec.geometry.triangles import face_areas

DEFAULT_POINTS = 16384
DEFAULT_SH_DEGREE = 1
# Samples per mesh of the Chamfer distance in the summary: enough for ~1e-5 resolution in the normalized frame.
SUMMARY_CHAMFER_SAMPLES = 100_000
MAX_POINTS = 1 << 22


@dataclass
class EncodeResult:
    """What `encode` produced.

    data: the `.tw` file. vertices (V,3) float64 and faces (F,3) int64: the decoded mesh, in the input's frame.
    stats: points_kept, sh_degree, bytes, seconds per stage, chamfer (normalized frame; None if not measured), ...
    """

    data: bytes
    vertices: np.ndarray
    faces: np.ndarray
    stats: dict = field(default_factory=dict)


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
    return v, f


def encode(
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    points: int = DEFAULT_POINTS,
    sh_degree: int = DEFAULT_SH_DEGREE,
    quality: str = "default",
    iters: int | None = None,
    device: str | torch.device = "auto",
    seed: int = 0,
    init: str = "sdf",
    progress: ProgressFn | None = None,
    measure: bool = True,
    container_version: int = 2,
    quantization: Quantization | None = None,
) -> EncodeResult:
    """Fit a TetWeave representation to a triangle mesh and return the `.tw` bytes and the decoded mesh.

    vertices (V,3), faces (F,3): any triangle mesh (open, multi-component and non-manifold inputs are fine).
    points: target grid points during the fit (passive ones are dropped before writing, so fewer are stored).
    sh_degree: -1 (none) or 0..3, directional distance coefficients per point (q = (degree+1)^2).
    quality: "fast", "default" or "best" (see fit.QUALITY); iters overrides its main+late iteration count.
    measure: compute the Chamfer distance between the input and the decoded mesh for `stats`.
    container_version: 2 (quantized, entropy-coded; default) or 1 (raw float16).
    quantization: v2's position bits and steps; None = `fit.config.default_quantization(points)`.
    Deterministic: the same input, options, seed, device and thread count give the same bytes.
    """
    from tetweave_codec.decoder import decode
    from tetweave_codec.meshio import normalize

    v, f = _validate(vertices, faces)
    if not 64 <= points <= MAX_POINTS:
        raise InputError(f"points must be between 64 and {MAX_POINTS}, got {points}")
    try:
        check_degree(sh_degree)
    except ValueError as exc:
        raise InputError(f"{exc} (-1 = none)") from None
    if container_version not in (1, 2):
        raise InputError(f"container version must be 1 or 2, got {container_version}")
    if container_version == 1:
        quantization = None
    elif quantization is None:
        quantization = default_quantization(points)
    schedule = schedule_for(quality, iters)
    dev = resolve_device(device)

    t_start = time.perf_counter()
    normalized, scale, offset = normalize(v)
    config = FitConfig(
        points=points, sh_degree=sh_degree, schedule=schedule, init=init, seed=seed, quantization=quantization
    )
    result = fit(normalized, f, config, device=dev, progress=progress)

    t0 = time.perf_counter()
    data = pack_result(result, scale, offset)
    out_v, out_f = decode(data)
    seconds = dict(result.stage_seconds)
    seconds["extract"] = time.perf_counter() - t0
    seconds["total"] = time.perf_counter() - t_start
    stats = {
        "bytes": len(data),
        "points_kept": int(len(result.finish.s)),
        "container_version": result.finish.version,
        "points_target": points,
        "sh_degree": sh_degree,
        "quality": quality,
        "device": str(dev),
        "vertices": int(len(out_v)),
        "faces": int(len(out_f)),
        "seconds": seconds,
        "chamfer": None,
    }
    if measure and len(out_f):
        from tetweave_codec.metrics import chamfer_distance

        stats["chamfer"] = chamfer_distance(v, f, out_v, out_f, n_samples=SUMMARY_CHAMFER_SAMPLES, seed=seed)
    return EncodeResult(data, out_v, out_f, stats)


def pack_result(result: FitResult, scale: float, offset: np.ndarray) -> bytes:
    """The `.tw` bytes of a fit: version 1 or 2 after `result.finish.version`."""
    from tetweave_codec.formats.tw import TetWeaveFile, TetWeaveFileV2, backend_flags, pack, pack_v2

    fin = result.finish
    offset = np.asarray(offset, dtype=np.float64)
    if fin.version == 1:
        return pack(
            TetWeaveFile(
                points=fin.points,
                s=fin.s,
                c=fin.c,
                sh_degree=result.sh_degree,
                scale=float(scale),
                offset=offset,
                flags=backend_flags(result.backend),
            )
        )
    q = fin.quantization
    return pack_v2(
        TetWeaveFileV2(
            cells=fin.cells,
            s_sym=fin.s_sym,
            c_sym=fin.c_sym,
            position_bits=q.position_bits,
            s_step=q.s_step,
            c_band_steps=tuple(q.c_band_steps[: result.sh_degree + 1]),
            sh_degree=result.sh_degree,
            scale=float(scale),
            offset=offset,
            flags=backend_flags(result.backend),
        )
    )
