"""Mesh files in and out: validated loading, normalization to [-0.9, 0.9]^3, atomic writing.

Formats (by file extension, through trimesh): OBJ, PLY, STL, OFF, GLB/GLTF. Scenes (GLB, multi-object OBJ)
are merged into one triangle mesh with their node transforms applied. Files are read with ``process=False``:
vertex order, duplicate vertices and degenerate faces are kept as stored (STL files therefore have three
vertices per triangle).

Every problem with an input file raises `InputError` with a one-line message; every output goes through a
temporary file in the destination directory and `os.replace`, so a failed write never leaves a half-written
file.
"""

from __future__ import annotations

import io
import os
import tempfile
from pathlib import Path

import numpy as np

from tetweave_codec.errors import InputError

try:  # the compiled text rows (optional; the same bytes)
    from tetweave_codec import _text_native
except ImportError:  # not built: the %-formatting below
    _text_native = None
# tetweave_codec/_text_native.c for the OBJ and OFF rows; TETWEAVE_NATIVE=0: the Python formatting
NATIVE = _text_native is not None and os.environ.get("TETWEAVE_NATIVE", "1") != "0"

# File extensions we read and write, mapped to trimesh's file type names.
MESH_FORMATS = {".obj": "obj", ".ply": "ply", ".stl": "stl", ".off": "off", ".glb": "glb", ".gltf": "gltf"}
WRITE_FORMATS = (".obj", ".ply", ".stl", ".off", ".glb")

# normalize() maps the bounding box into [-NORMALIZED_HALF_EXTENT, NORMALIZED_HALF_EXTENT]^3 (paper appendix).
NORMALIZED_HALF_EXTENT = 0.9

# Decimal places for coordinates in text formats (OBJ, OFF), on top of the digits the mesh's size needs.
_TEXT_DIGITS = 9


def mesh_format(path: str | os.PathLike, *, for_writing: bool = False) -> str:
    """trimesh file type for `path`'s extension; InputError when unsupported."""
    ext = Path(path).suffix.lower()
    allowed = WRITE_FORMATS if for_writing else tuple(MESH_FORMATS)
    if ext not in allowed:
        names = ", ".join(e[1:] for e in allowed)
        what = "output" if for_writing else "mesh"
        shown = ext or "(no extension)"
        raise InputError(f"{os.fspath(path)}: unsupported {what} format {shown!r}; use {names}")
    return MESH_FORMATS[ext]


def load_mesh(path: str | os.PathLike, data: bytes | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh.

    Args:
        path: mesh file; the format comes from its extension (see MESH_FORMATS).
        data: the file's bytes when they were read elsewhere (a batch worker on another machine); `path` then only
            names the file and gives its format.
    Returns:
        vertices (V, 3) float64, faces (F, 3) int64 (polygons are triangulated by the reader).
    Raises:
        InputError: missing or unreadable file, unsupported format, no triangles, non-finite coordinates,
            face indices out of range.
    """
    name = os.fspath(path)
    if data is None and not os.path.exists(name):
        raise InputError(f"{name}: no such file")
    if data is None and not os.path.isfile(name):
        raise InputError(f"{name}: not a regular file")
    file_type = mesh_format(path)
    if data is None and not os.access(name, os.R_OK):
        raise InputError(f"{name}: permission denied")
    import trimesh

    try:
        source = name if data is None else io.BytesIO(data)
        scene = trimesh.load_scene(source, file_type=file_type, process=False)
        mesh = scene.to_mesh()
        vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    except InputError:
        raise
    except Exception as exc:  # trimesh raises anything from ValueError to IndexError on malformed files
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{name}: cannot read as {file_type.upper()} ({reason})") from exc
    validate_mesh(vertices, faces, name)
    return vertices, faces


def validate_mesh(vertices: np.ndarray, faces: np.ndarray, name: str = "mesh") -> None:
    """Raise InputError unless `vertices` (V, 3), `faces` (F, 3) form a non-empty, finite, indexable mesh."""
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"{name}: expected (V, 3) vertices and (F, 3) triangles")
    if len(faces) == 0:
        raise InputError(f"{name}: contains no triangles")
    if not np.isfinite(vertices).all():
        raise InputError(f"{name}: has non-finite (NaN or infinite) vertex coordinates")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputError(f"{name}: face indices out of range (mesh has {len(vertices)} vertices)")
    used = vertices[np.unique(faces)]
    if not (used.max(axis=0) - used.min(axis=0)).any():
        raise InputError(f"{name}: all triangles collapse to a single point")


def normalize(vertices: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Centre the bounding box at the origin and scale uniformly so it fits [-0.9, 0.9]^3.

    Args:
        vertices: (V, 3) coordinates (V >= 1, finite).
    Returns:
        normalized (V, 3) float64, scale (float > 0), offset (3,) float64 with
        ``vertices == normalized * scale + offset`` (up to rounding); the longest bounding-box side
        becomes 1.8.
    Raises:
        InputError: no vertices, non-finite coordinates or a zero-size bounding box.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise InputError("cannot normalize: expected a non-empty (V, 3) vertex array")
    if not np.isfinite(v).all():
        raise InputError("cannot normalize: non-finite vertex coordinates")
    lo, hi = v.min(axis=0), v.max(axis=0)
    offset = (lo + hi) / 2.0
    extent = float((hi - lo).max())
    if not extent > 0:
        raise InputError("cannot normalize: the mesh has zero size")
    scale = extent / (2.0 * NORMALIZED_HALF_EXTENT)
    return (v - offset) / scale, scale, offset


def denormalize(vertices: np.ndarray, scale: float, offset: np.ndarray) -> np.ndarray:
    """Inverse of `normalize`: ``vertices * scale + offset`` (float64)."""
    return np.asarray(vertices, dtype=np.float64) * float(scale) + np.asarray(offset, dtype=np.float64)


def mesh_bytes(vertices: np.ndarray, faces: np.ndarray, file_type: str) -> bytes:
    """Encode a triangle mesh as `file_type` ("obj", "ply", "stl", "off", "glb"); empty meshes are allowed.

    OBJ, OFF, PLY (binary little-endian, float32 coordinates, int32 indices) and STL (binary) are written here
    with whole-array numpy and one string-formatting call per section: trimesh's writers cost ~10x as much and its
    import alone costs more than a whole decode. GLB goes through trimesh.
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if file_type in ("obj", "off"):
        # Enough decimals that rounding stays far below the float16 quantization of the decoded geometry.
        size = float(np.abs(v).max()) if len(v) else 1.0
        digits = _TEXT_DIGITS + max(0, -int(np.floor(np.log10(size)))) if size > 0 else _TEXT_DIGITS
        return (_obj_text if file_type == "obj" else _off_text)(v, f, digits)
    if file_type == "ply":
        return _ply_bytes(v, f)
    if file_type == "stl":
        return _stl_bytes(v, f)
    import trimesh

    data = trimesh.Trimesh(vertices=v, faces=f, process=False, validate=False).export(file_type=file_type)
    return data.encode("utf-8") if isinstance(data, str) else bytes(data)


def _rows_text(prefix: str, row_format: str, values: np.ndarray) -> str:
    """One line `prefix + row_format` per row of `values` (R, C), formatted by a single %-call (C speed)."""
    if not len(values):
        return ""
    return ((prefix + row_format + "\n") * len(values)) % tuple(values.ravel().tolist())


def _float_rows(prefix: str, values: np.ndarray, digits: int) -> bytes:
    """Rows of `prefix` and the values (R,C) float64 as "%.{digits}f", space-separated (ASCII bytes)."""
    if NATIVE:
        return _text_native.float_rows(np.ascontiguousarray(values, dtype=np.float64), prefix.encode(), digits)
    return _rows_text(prefix, " ".join([f"%.{digits}f"] * values.shape[1]), values).encode("ascii")


def _int_rows(prefix: str, values: np.ndarray, offset: int = 0) -> bytes:
    """Rows of `prefix` and the values (R,C) int64 plus `offset` as "%d", space-separated (ASCII bytes)."""
    if NATIVE:
        return _text_native.int_rows(np.ascontiguousarray(values, dtype=np.int64), prefix.encode(), offset)
    return _rows_text(prefix, " ".join(["%d"] * values.shape[1]), values + offset).encode("ascii")


def _obj_text(v: np.ndarray, f: np.ndarray, digits: int) -> bytes:
    if not len(f):
        return b"# empty mesh\n"  # bare 'v' / 'f' lines, or none at all, are rejected by some readers
    return _float_rows("v ", v, digits) + _int_rows("f ", f, 1)


def _off_text(v: np.ndarray, f: np.ndarray, digits: int) -> bytes:
    return f"OFF\n{len(v)} {len(f)} 0\n".encode() + _float_rows("", v, digits) + _int_rows("3 ", f)


def _ply_bytes(v: np.ndarray, f: np.ndarray) -> bytes:
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    rows = np.empty(len(f), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    rows["n"] = 3
    rows["v"] = f
    return header.encode("ascii") + v.astype("<f4").tobytes() + rows.tobytes()


def _stl_bytes(v: np.ndarray, f: np.ndarray) -> bytes:
    from tetweave_codec.geometry.triangles import face_normals

    rows = np.zeros(len(f), dtype=[("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    rows["normal"] = face_normals(v, f)
    rows["corners"] = v[f]
    return bytes(80) + np.uint32(len(f)).astype("<u4").tobytes() + rows.tobytes()


def save_mesh(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a triangle mesh; format from the extension (obj, ply, stl, off, glb); temp file + rename.

    Raises:
        InputError: unsupported extension. OSError: the destination cannot be written.
    """
    data = mesh_bytes(vertices, faces, mesh_format(path, for_writing=True))
    write_bytes_atomic(path, data)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write `data` to `path` through a temporary file in the same directory and `os.replace`.

    Either the complete file appears at `path` or, on any error, `path` is left as it was and the temporary
    file is removed. The new file gets the usual permissions (0666 minus the umask).
    """
    target = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(target))
    try:
        fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(target) + ".", suffix=".tmp", dir=directory)
    except OSError as exc:  # report the path the user asked for, not our temporary name
        raise OSError(exc.errno, f"cannot write there ({exc.strerror})", target) from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
