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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tetweave_codec.errors import error_line
from tetweave_codec.options import LATER_OPTIONS, EncodeOptions, sh_degree_value

__all__ = ["LATER_OPTIONS", "EncodeOptions", "Task", "decode_file", "encode_file", "mesh_sha256", "sh_degree_value"]


@dataclass(frozen=True)
class Task:
    """One file of a batch.

    input: the input file. output: where the driver writes the result. key: the output's path relative to the
    output directory (the manifest's key). options: JSON-able options that decide the output bytes (for
    `encode_file`, the fields of `options.EncodeOptions`). data: the input's bytes when the worker may not see the
    driver's files (Ray on several machines); None = read `input`.
    """

    input: str
    output: str
    key: str
    options: dict
    data: bytes | None = None


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
    fit), "chamfer", "draco_bytes", "decimate_draco_bytes" (the summary's classical context:
    `classical.classical_context`), "unseen_area_share" (the share of the decoded area no outside view sees,
    `metrics.unseen.self_check`; None when not measured, as with options.measure off), "device", "seconds",
    "mesh_sha256" (`mesh_sha256` of the loaded mesh)} or a
    failed result with the one-line error (and mesh_sha256 when the mesh loaded). Same task, same bytes, in any
    process.
    """
    t0 = time.perf_counter()
    mesh_key: dict = {}
    try:
        from tetweave_codec.meshio import load_mesh

        options = EncodeOptions(**task.options)
        vertices, faces = load_mesh(Path(task.input), task.data)  # before torch: a bad file fails in a blink
        mesh_key["mesh_sha256"] = mesh_sha256(vertices, faces)
        import torch

        from tetweave_codec.encoder import encode

        if options.threads:
            torch.set_num_threads(options.threads)
        result = encode(vertices, faces, options=options)
        context = _classical_record(result)
        unseen = _unseen_share(result) if options.measure else None
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
        **context,
        "unseen_area_share": unseen,
        "device": st["device"],
        "seconds": time.perf_counter() - t0,
        **mesh_key,
    }


def _classical_record(result) -> dict:
    """The encoder summary's classical context for a manifest record: {"draco_bytes", "decimate_draco_bytes"}
    (null where not measured)."""
    from tetweave_codec.classical import encode_context

    context = encode_context(result)
    return context["record"] if context else {"draco_bytes": None, "decimate_draco_bytes": None}


def _unseen_share(result) -> float | None:
    """The encode summary's self-check for a manifest record: the share of the decoded area no outside view sees
    (metrics.unseen), None when not measured."""
    from tetweave_codec.metrics.unseen import self_check

    check = self_check(result.vertices, result.faces)
    return None if check is None else check.share


def decode_file(task: Task) -> dict:
    """Rebuild the mesh of one .tw file; task.options: {"format": "obj"|"ply"|..., "delaunay": "file"|backend,
    "level": "control"|"smoothed"|"full" (default full), "threads": the crossing check's threads (default 1)}.

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
                data,
                None if backend == "file" else backend,
                level=task.options.get("level", "full"),
                threads=task.options.get("threads", 1),
            )
        out = mesh_bytes(result.vertices, result.faces, task.options.get("format", "obj"))
    except Exception as exc:
        return failed(exc, t0)
    return {
        "status": "ok",
        "data": out,
        "bytes": len(out),
        "points": result.header.num_points,
        "vertices": len(result.vertices),
        "faces": len(result.faces),
        "seconds": time.perf_counter() - t0,
    }
