"""Meshes of assemblies: binary PLY with a part id per face, the two export forms, edge counts.

An assembly is stored as ONE binary little-endian PLY: float32 vertices (each part's own, never shared between
parts) and per face its three vertex indices and the part it belongs to (`part`, uchar). float32 is what real
exports (OBJ, FBX, glTF) hold; the welded form is made from those float32 positions, so it is the same on every
machine. numpy only: no trimesh, nothing of tetweave_codec.

    parts = read_ply(path)                 # Assembly(vertices (V,3) float64, faces (F,3), part (F,))
    v, f = parts.separate()                # the parts concatenated, unwelded (the separate-parts export)
    v, f = parts.welded()                  # vertices merged at equal positions across parts (one-mesh export)
    counts = edge_face_counts(f)           # faces per undirected edge
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Assembly:
    """vertices (V,3) float64 (float32 values), faces (F,3) int64, part (F,) int64: the part of each face; names:
    one per part (from the PLY's comments)."""

    vertices: np.ndarray
    faces: np.ndarray
    part: np.ndarray
    names: tuple[str, ...] = ()

    def separate(self) -> tuple[np.ndarray, np.ndarray]:
        """The parts concatenated without welding (each part's vertices are its own)."""
        return self.vertices, self.faces

    def welded(self) -> tuple[np.ndarray, np.ndarray]:
        """One mesh with vertices merged at equal positions across parts (as a single-mesh export writes it):
        parts that touch share those vertices and edges. Faces left degenerate by the merge are dropped."""
        return weld(self.vertices, self.faces)

    def part_meshes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Each part as its own (vertices, faces), in part order."""
        out = []
        for p in range(int(self.part.max()) + 1):
            f = self.faces[self.part == p]
            used, inverse = np.unique(f, return_inverse=True)
            out.append((self.vertices[used], inverse.reshape(-1, 3)))
        return out


def weld(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V,3) merged where their coordinates are equal (first occurrence's order), faces (F,3) mapped onto
    them, faces whose corners merged dropped."""
    v = np.asarray(vertices, dtype=np.float64)
    _, first, inverse = np.unique(v, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    f = rank[inverse.reshape(-1)][faces]
    ok = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    return v[first[order]], f[ok].astype(np.int64)


def edge_face_counts(faces: np.ndarray) -> np.ndarray:
    """(E,) the number of faces on each undirected edge of faces (F,3)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return counts


def join(meshes: list[tuple[np.ndarray, np.ndarray]], names: tuple[str, ...] = ()) -> Assembly:
    """An Assembly of the parts [(vertices (V,3), faces (F,3))], in order, each welded on its own (at equal float32
    positions: a part's faces share its vertices, parts share none)."""
    meshes = [weld(np.asarray(v, dtype=np.float32).astype(np.float64), f) for v, f in meshes]
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])
    faces = np.concatenate([np.asarray(f, dtype=np.int64) + o for (_, f), o in zip(meshes, offsets[:-1], strict=True)])
    part = np.concatenate([np.full(len(f), i, dtype=np.int64) for i, (_, f) in enumerate(meshes)])
    vertices = np.concatenate([np.asarray(v, dtype=np.float64) for v, _ in meshes]).astype(np.float32)
    return Assembly(vertices.astype(np.float64), faces, part, tuple(names))


def write_ply(path: str | Path, vertices: np.ndarray, faces: np.ndarray, part: np.ndarray | None = None,
              comments: tuple[str, ...] = ()) -> None:  # fmt: skip
    """Binary little-endian PLY: float32 x y z, faces as `list uchar ushort vertex_indices` (`uint` from 65,536
    vertices), + `uchar part`."""
    v = np.asarray(vertices, dtype="<f4")
    index = "<u2" if len(v) < 1 << 16 else "<u4"
    f = np.asarray(faces).astype(index)
    head = ["ply", "format binary_little_endian 1.0", *[f"comment {c}" for c in comments]]
    head += [f"element vertex {len(v)}", "property float x", "property float y", "property float z"]
    head += [f"element face {len(f)}", f"property list uchar {'ushort' if index == '<u2' else 'uint'} vertex_indices"]
    fields = [("n", "u1"), ("idx", index, (3,))]
    if part is not None:
        head.append("property uchar part")
        fields.append(("part", "u1"))
    head.append("end_header")
    rows = np.zeros(len(f), dtype=np.dtype(fields))
    rows["n"] = 3
    rows["idx"] = f
    if part is not None:
        rows["part"] = np.asarray(part, dtype=np.uint8)
    Path(path).write_bytes(("\n".join(head) + "\n").encode() + v.tobytes() + rows.tobytes())


def read_ply(path: str | Path) -> Assembly:
    """An Assembly from a PLY that `write_ply` wrote (part 0 for every face when it has no `part`); part names from
    comments `part NAME`."""
    data = Path(path).read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    head = data[:end].decode().splitlines()
    nv = int(next(h for h in head if h.startswith("element vertex")).split()[-1])
    nf = int(next(h for h in head if h.startswith("element face")).split()[-1])
    names = tuple(h.split(None, 2)[2] for h in head if h.startswith("comment part "))
    listed = next(h for h in head if h.endswith(" vertex_indices")).split()[3]
    index = {"ushort": "<u2", "uint": "<u4", "int": "<i4"}[listed]
    fields = [("n", "u1"), ("idx", index, (3,))]
    has_part = "property uchar part" in head
    if has_part:
        fields.append(("part", "u1"))
    v = np.frombuffer(data, dtype="<f4", count=3 * nv, offset=end).reshape(-1, 3).astype(np.float64)
    rows = np.frombuffer(data, dtype=np.dtype(fields), count=nf, offset=end + 12 * nv)
    if not (rows["n"] == 3).all():
        raise ValueError(f"{path}: only triangles are read")
    part = rows["part"].astype(np.int64) if has_part else np.zeros(nf, dtype=np.int64)
    return Assembly(v, rows["idx"].astype(np.int64), part, names)
