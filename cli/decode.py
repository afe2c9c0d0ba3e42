"""`tetweave decode`: rebuild the triangle mesh stored in a `.tw` file."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import click

from tetweave_codec.errors import InputError

DEFAULT_SUFFIX = ".decoded.obj"


def default_output(path: Path) -> Path:
    """FILE.tw -> FILE.decoded.obj beside it (never the input itself)."""
    return path.with_name(path.stem + DEFAULT_SUFFIX) if path.suffix else path.with_name(path.name + DEFAULT_SUFFIX)


def read_tw_bytes(path: Path) -> bytes:
    """The bytes of a .tw file; InputError (one line) when it is missing or not a file."""
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if not path.is_file():
        raise InputError(f"{path}: not a regular file")
    return path.read_bytes()


def echo_warnings(caught: list) -> None:
    for w in caught:
        click.echo(f"tetweave: warning: {w.message}", err=True)


@click.command(context_settings={"show_default": True})
@click.argument("file", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    default=None,
    help="Output mesh; its extension picks the format (obj, ply, stl, off, glb).  "
    f"[default: FILE with the suffix {DEFAULT_SUFFIX}, beside FILE; the input is never overwritten]",
)
@click.option(
    "--delaunay",
    type=click.Choice(["file", "tetgen", "qhull"]),
    default="file",
    help="Delaunay backend: 'file' uses the one the encoder recorded, which reproduces its mesh exactly.",
)
def decode(file: Path, output: Path | None, delaunay: str) -> None:
    """Rebuild the mesh stored in FILE (a .tw file) in the original mesh's coordinates.

    The result is watertight and 2-manifold. If every point lies on the same side of the surface the mesh is
    empty: an empty mesh file is written and a warning printed.
    """
    from tetweave_codec.decoder import decode_detailed
    from tetweave_codec.meshio import mesh_format, save_mesh

    output = output or default_output(file)
    mesh_format(output, for_writing=True)  # reject an unsupported extension before any work
    if output.resolve() == file.resolve():
        raise InputError(f"{output}: the output would overwrite the input; choose another -o")
    if output.is_dir():
        raise InputError(f"{output}: is a directory; give a file name")
    if not output.resolve().parent.is_dir():
        raise InputError(f"{output}: the output directory {output.resolve().parent} does not exist")
    data = read_tw_bytes(file)
    start = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = decode_detailed(data, None if delaunay == "file" else delaunay)
    elapsed = time.perf_counter() - start
    echo_warnings(caught)
    if len(result.faces) == 0:
        click.echo(
            "tetweave: warning: all points lie on one side of the surface, the decoded mesh is empty; "
            "writing an empty mesh file",
            err=True,
        )
    save_mesh(output, result.vertices, result.faces)
    sec = result.seconds
    click.echo(f"wrote {output}: {len(result.vertices):,} vertices, {len(result.faces):,} faces")
    click.echo(
        f"decoded {result.container.num_points:,} points in {elapsed:.2f}s "
        f"(Delaunay {sec['delaunay']:.2f}s with {result.backend}, {result.num_tets:,} tets; "
        f"marching tets {sec['marching_tets']:.2f}s)"
    )
