"""What a batch worker does with one file: `encode_file` and `decode_file`, plain functions of a `Task` that run in
any process (a local worker, a Ray task) and never raise for a bad input.

A worker returns a result dict: ``status`` ("ok" / "failed"), ``data`` (the output file's bytes: the driver
writes it, so workers need no access to the output directory), ``error`` (one line) and what the manifest
records (bytes, points, chamfer, seconds). This module imports neither torch nor the encoder at import time:
`decode_file` must run where torch is not installed.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from tetweave_codec.errors import error_line


@dataclass(frozen=True)
class Task:
    """One file of a batch.

    input: the input file. output: where the driver writes the result. key: the output's path relative to the
    output directory (the manifest's key). options: JSON-able options that decide the output bytes (for
    `encode_file`, the fields of `EncodeOptions`). data: the input's bytes when the worker may not see the
    driver's files (Ray on several machines); None = read `input`.
    """

    input: str
    output: str
    key: str
    options: dict
    data: bytes | None = None


def sh_degree_value(text: str) -> int | None:
    """The encoder's `sh_degree` for the CLI's --sh-degree: "auto" -> None (the encoder's choice), "none" -> -1."""
    return {"auto": None, "none": -1}[text] if text in ("auto", "none") else int(text)


# Options added to EncodeOptions after batch manifests existed, with the value runs before them had.
LATER_OPTIONS = {"layout": "fit", "holes": "close", "keep_creases": None}


@dataclass(frozen=True)
class EncodeOptions:
    """`tetweave encode`'s options for one file, as the encoder API takes them (see `encoder_kwargs`).

    sh_degree: "auto", "none" or "0".."3". size: target bytes; max_error: target Chamfer distance (rate control).
    format_version: 1 or 2. position_bits (fractional ones: formats.quantize.fractional_grid) / s_step / c_step:
    v2 quantization overrides (None = the defaults for `points`; not with the grid layout, which has its own).
    smoothing, subdivision: the decoder's Taubin steps and Loop levels (None = the encoder's default).
    keep_creases: the smoothing keeps the surface's creases (None = the encoder's default). layout:
    "fit", "grid" or "best" (encoder.LAYOUTS). holes: "close" or "keep" (encoder.HOLES: an open input's holes
    spanned, or kept open). threads: torch CPU threads (0 = torch's default). measure: compute the Chamfer distance.
    """

    points: int = 16384
    sh_degree: str = "auto"
    layout: str = "fit"
    holes: str = "close"
    quality: str = "default"
    iters: int | None = None
    size: int | None = None
    max_error: float | None = None
    format_version: int = 2
    position_bits: float | None = None
    s_step: float | None = None
    c_step: float | None = None
    smoothing: int | None = None
    subdivision: int | None = None
    keep_creases: bool | None = None
    device: str = "auto"
    seed: int = 0
    threads: int = 0
    measure: bool = True

    def as_dict(self) -> dict:
        """The options as a batch manifest records them (`EncodeOptions(**d)` rebuilds them); options added after
        manifests existed are left out at the value every earlier run had (LATER_OPTIONS), so a re-run of a batch
        started before them still skips the files it finished."""
        d = asdict(self)
        for name, value in LATER_OPTIONS.items():
            if d[name] == value:
                del d[name]
        return d

    def encoder_kwargs(self, device) -> dict:
        """Keyword arguments of `tetweave_codec.encoder.encode` (device: the resolved torch.device); the one
        translation of these options, shared by single-file `tetweave encode` and every batch worker."""
        from tetweave_codec.errors import InputError
        from tetweave_codec.fit.config import default_quantization

        overrides = (self.position_bits, self.s_step, self.c_step)
        if self.layout != "fit" and any(x is not None for x in overrides):
            raise InputError(
                f"the {self.layout} layout chooses its own quantization: drop --position-bits, --s-step, --c-step"
            )
        quant = default_quantization(self.points)
        if self.position_bits is not None:
            from tetweave_codec.formats.quantize import fractional_grid

            bits, grid_scale = fractional_grid(self.position_bits)
            quant = replace(quant, position_bits=bits, grid_scale=grid_scale)
        if self.s_step is not None:
            quant = replace(quant, s_step=self.s_step)
        if self.c_step is not None:
            quant = replace(quant, c_band_steps=(self.c_step,) * 4)
        return dict(
            points=self.points,
            sh_degree=sh_degree_value(self.sh_degree),
            quality=self.quality,
            iters=self.iters,
            device=device,
            seed=self.seed,
            container_version=int(self.format_version),
            quantization=quant if self.layout == "fit" else None,
            layout=self.layout,
            holes=self.holes,
            size=self.size,
            max_error=self.max_error,
            measure=self.measure,
            smoothing=self.smoothing,
            subdivision=self.subdivision,
            keep_creases=self.keep_creases,
        )


def mesh_sha256(vertices: np.ndarray, faces: np.ndarray) -> str:
    """Hex sha256 of a loaded mesh's arrays (float64 vertices, int64 faces): names the mesh by its content."""
    digest = hashlib.sha256(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return digest.hexdigest()


def failed(exc: BaseException, t0: float) -> dict:
    """The result of a file whose work raised `exc`."""
    return {"status": "failed", "error": error_line(exc), "seconds": time.perf_counter() - t0}


def encode_file(task: Task) -> dict:
    """Fit and pack one mesh with `EncodeOptions(**task.options)`; sets torch's threads to the options' first.

    Returns {"status": "ok", "data": .tw bytes, "bytes", "points" (stored), "points_target" (grid points of the
    fit), "chamfer", "device", "seconds", "mesh_sha256" (`mesh_sha256` of the loaded mesh)} or a failed result
    with the one-line error (and mesh_sha256 when the mesh loaded). Same task, same bytes, in any process.
    """
    t0 = time.perf_counter()
    mesh_key: dict = {}
    try:
        from tetweave_codec.meshio import load_mesh

        options = EncodeOptions(**task.options)
        vertices, faces = load_mesh(Path(task.input), task.data)  # before torch: a bad file fails in a blink
        mesh_key["mesh_sha256"] = mesh_sha256(vertices, faces)
        import torch

        from tetweave_codec.encoder import encode, resolve_device

        if options.threads:
            torch.set_num_threads(options.threads)
        result = encode(vertices, faces, **options.encoder_kwargs(resolve_device(options.device)))
    except Exception as exc:  # bad input, unreachable target, a bug: a failed record, never a stopped batch
        return {**failed(exc, t0), **mesh_key}
    st = result.stats
    return {
        "status": "ok",
        "data": result.data,
        "bytes": st["bytes"],
        "points": st["points_kept"],
        "points_target": st["points_target"],
        "chamfer": st["chamfer"],
        "device": st["device"],
        "seconds": time.perf_counter() - t0,
        **mesh_key,
    }


def decode_file(task: Task) -> dict:
    """Rebuild the mesh of one .tw file; task.options: {"format": "obj"|"ply"|..., "delaunay": "file"|backend,
    "level": "control"|"smoothed"|"full" (default full)}.

    Returns {"status": "ok", "data": mesh file bytes, "points", "vertices", "faces", "seconds"} or a failed
    result. Numpy only: never imports torch.
    """
    t0 = time.perf_counter()
    try:
        import warnings

        from tetweave_codec.decoder import decode_detailed
        from tetweave_codec.meshio import mesh_bytes

        data = task.data if task.data is not None else Path(task.input).read_bytes()
        backend = task.options.get("delaunay", "file")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a missing backend: the file decodes with another one
            result = decode_detailed(
                data, None if backend == "file" else backend, level=task.options.get("level", "full")
            )
        out = mesh_bytes(result.vertices, result.faces, task.options.get("format", "obj"))
    except Exception as exc:
        return failed(exc, t0)
    return {
        "status": "ok",
        "data": out,
        "bytes": len(out),
        "points": result.container.num_points,
        "vertices": len(result.vertices),
        "faces": len(result.faces),
        "seconds": time.perf_counter() - t0,
    }
