"""Before / after pictures of issue 46 (visible_surface.md): `tetweave render` of the --surface all and auto files
of two messy inputs, from outside and cut open.

Reads the files `benchmarks/visible_mlab.py --save DIR --before` wrote (DIR/spot_KIND.ply, DIR/spot_KIND_5k_SURFACE.tw)
and writes docs/measurements/visible_KIND.png: top row --surface all (before), bottom row auto (after); left two
views from outside (`tetweave render --views 2`), right two of the decoded mesh cut open by a plane through the
hidden ball's centre (hidden) or the box's centre (overlap), keeping the faces on one side (`tetweave render` of
that half as a PLY, normals as colours): surfaces left inside the solid show through the cut. 32-colour PNGs.

    python docs/measurements/visible_pictures.py DIR
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parent
SIZE = 256


def cut(vertices: np.ndarray, faces: np.ndarray, point: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The faces whose centroid lies on the negative side of the plane (point, normal)."""
    return faces[(vertices[faces].mean(axis=1) - point) @ normal < 0]


def render(mesh: Path, png: Path, views: int, shading: str = "lambert") -> None:
    command = [sys.executable, "-m", "tetweave_codec.cli.main", "render", str(mesh), "-o", str(png)]
    command += ["--views", str(views), "--size", str(SIZE), "--shading", shading, "--threads", "1"]
    subprocess.run(command, check=True)


def main() -> None:
    from PIL import Image

    from tetweave_codec.decoder import decode
    from tetweave_codec.meshio import load_mesh, save_mesh

    folder = Path(sys.argv[1])
    for kind in ("hidden", "overlap"):
        mv, mf = load_mesh(folder / f"spot_{kind}.ply")
        if kind == "hidden":  # the second copy of spot's vertices: the hidden part
            point = mv[len(mv) // 2 :].mean(axis=0)
        else:  # the box: the last 8 vertices of the messy input
            point = mv[-8:].mean(axis=0)
        normal = np.array([1.0, 0.0, 0.0])
        rows = []
        with tempfile.TemporaryDirectory() as tmp:
            for surface in ("all", "auto"):
                tw = folder / f"spot_{kind}_5k_{surface}.tw"
                v, f = decode(tw.read_bytes())
                half = Path(tmp) / f"{surface}_cut.ply"
                save_mesh(half, v, cut(v, f, point, normal))
                render(tw, Path(tmp) / f"{surface}_out.png", 2)
                # normals as colours: a lit (headlight) surface inside the cut stands out from the dark back faces
                render(half, Path(tmp) / f"{surface}_cut.png", 2, "normals")
                row = [Image.open(Path(tmp) / f"{surface}_{part}.png").convert("RGB") for part in ("out", "cut")]
                rows.append(np.concatenate([np.asarray(im) for im in row], axis=1))
        picture = Image.fromarray(np.concatenate(rows, axis=0))
        picture.quantize(colors=32).save(OUT / f"visible_{kind}.png", optimize=True)
        print(OUT / f"visible_{kind}.png", picture.size)


if __name__ == "__main__":
    main()
