"""`tetweave decode`: rebuild the triangle mesh stored in a `.tw` file."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import click

from tetweave_codec.cli.batch import jobs_option, run_files
from tetweave_codec.errors import InputError
from tetweave_codec.runner.inputs import is_batch

DEFAULT_SUFFIX = ".decoded.obj"
TW_SUFFIX = ".tw"
# --threads in a batch when not given: one thread per worker, --jobs defaults to one worker per core (as encode's)
BATCH_THREADS = 1
# --threads' bound, cli.common.MAX_THREADS (not imported from there: cli/common.py imports the fit's settings, ~15
# ms of dataclasses that a decode never uses)
MAX_THREADS = 1024


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
@click.argument("files", nargs=-1, required=True, metavar="FILE...")
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    default=None,
    help="Output mesh; its extension picks the format (obj, ply, stl, off, glb); with several inputs, a directory "
    "or an @list: the output directory, where the outputs mirror the inputs' relative paths.  "
    f"[default: FILE with the suffix {DEFAULT_SUFFIX}, beside FILE; the input is never overwritten]",
)
@click.option(
    "--delaunay",
    type=click.Choice(["file", "exact", "tetgen", "qhull"]),
    default="file",
    help="Delaunay backend: 'file' uses the one the encoder recorded, which reproduces its mesh exactly.",
)
@click.option(
    "--format",
    "mesh_format_name",
    default="obj",
    help="Batch: format of the decoded meshes (obj, ply, stl, off, glb).",
)
@click.option(
    "--level",
    type=click.Choice(["control", "smoothed", "full"]),
    default="full",
    help="How much of the file's filter to apply: 'control' is the marching-tets mesh of the stored points, "
    "'smoothed' adds the file's Taubin smoothing without its Loop subdivision (4^L times fewer faces), 'full' the "
    "whole filter. Every level is watertight, 2-manifold and free of self-intersections; `tetweave info` shows "
    "the faces of each.",
)
@click.option(
    "--threads",
    type=click.IntRange(min=0, max=MAX_THREADS),
    default=0,
    help="Threads of the self-intersection check, a decode's largest part after Delaunay (0: every core). The mesh "
    "is the same bytes on any count. Batch: per worker, 1 unless given.",
)
@jobs_option("(batch)")
@click.option("--quiet", "-q", is_flag=True, help="Batch: no progress.")
def decode(
    files: tuple[str, ...],
    output: Path | None,
    delaunay: str,
    mesh_format_name: str,
    level: str,
    threads: int,
    jobs: int | None,
    quiet: bool,
) -> None:
    """Rebuild the mesh stored in FILE (a .tw file) in the original mesh's coordinates.

    The result is watertight and 2-manifold. If every point lies on the same side of the surface the mesh is
    empty: an empty mesh file is written and a warning printed. Several FILEs, directories (searched for .tw
    files) or @list.txt files decode in parallel (--jobs processes) into -o DIR; exit status 1 when any failed.
    """
    if is_batch(files) or jobs is not None:
        _decode_batch(files, output, delaunay, mesh_format_name, jobs, quiet, level, threads or BATCH_THREADS)
        return
    _decode_one(Path(files[0]), output, delaunay, level, threads)


def _decode_batch(
    files, output, delaunay: str, fmt: str, jobs: int | None, quiet: bool, level: str = "full", threads: int = 1
) -> None:
    """Several .tw files through tetweave_codec.runner (numpy only, like one file), `threads` per worker."""
    from tetweave_codec.meshio import mesh_format
    from tetweave_codec.runner.executors import LocalExecutor, default_jobs
    from tetweave_codec.runner.work import decode_file

    try:  # an unsupported format: one line, before any work
        fmt = mesh_format(f"decoded.{fmt}", for_writing=True)
    except InputError:
        raise InputError(f"--format {fmt}: use obj, ply, stl, off or glb") from None
    workers = jobs or default_jobs(threads)
    run_files(
        "tetweave decode",
        files,
        output,
        extensions=(TW_SUFFIX,),
        suffix=f".{fmt}",
        options={"format": fmt, "delaunay": delaunay, "level": level, "threads": threads},
        worker=decode_file,
        executor_factory=lambda: LocalExecutor(workers),
        use_manifest=False,
        quiet=quiet,
    )


def _decode_one(file: Path, output: Path | None, delaunay: str, level: str = "full", threads: int = 0) -> None:
    """One file in this process, its crossing checks on `threads` threads (0: every core)."""
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
        result = decode_detailed(data, None if delaunay == "file" else delaunay, level=level, threads=threads)
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
    if "delaunay" in sec:  # the Python pipeline (files of earlier encoders): its stages
        stages = (
            f"Delaunay {sec['delaunay']:.2f}s with {result.backend}, {result.num_tets:,} tets; "
            f"marching tets {sec['marching_tets']:.2f}s"
        )
    else:  # the decoder core, one call
        stages = f"the C decoder core, exact Delaunay, {result.num_tets:,} tets"
    click.echo(f"decoded {result.header.num_points:,} points in {elapsed:.2f}s ({stages}{_smoothing_note(result)})")


def _smoothing_note(result) -> str:
    """'; smoothing ...' / '; subdivision ...' for files that ask for them (with the vertices the
    self-intersection check put back)."""
    steps, levels = result.smoothing, result.subdivision
    skipped = _skipped_note(result)
    if not steps and not levels:
        return skipped
    creases = " keeping creases" if result.header.creases else ""
    parts = [f"{steps} smoothing step{'s' if steps > 1 else ''}{creases}"] if steps else []
    parts += [f"{levels} subdivision level{'s' if levels > 1 else ''}"] if levels else []
    back = f", {result.restored:,} vertices kept unsmoothed" if result.restored else ""
    took = f" {result.seconds['smoothing']:.2f}s" if "smoothing" in result.seconds else ""
    return f"; {' + '.join(parts)}{took}{back}{skipped}"


def _skipped_note(result) -> str:
    """'; level control: ... not applied' when --level left out part of the file's filter."""
    steps = result.header.smoothing - result.smoothing
    levels = result.header.subdivision - result.subdivision
    parts = [f"{steps} smoothing step{'s' if steps > 1 else ''}"] if steps else []
    parts += [f"{levels} subdivision level{'s' if levels > 1 else ''}"] if levels else []
    return f"; level {result.level}: the file's {' + '.join(parts)} not applied" if parts else ""
