"""`tetweave encode`: fit a TetWeave representation to a mesh and write the `.tw` file."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from tetweave_codec.cli.batch import jobs_option, ray_option, run_files, split_ray
from tetweave_codec.cli.common import (
    PROGRESS_LINE_SECONDS,
    CountType,
    configure_torch,
    device_option,
    iters_option,
    quality_option,
    threads_option,
)
from tetweave_codec.runner.inputs import is_batch

STAGE_NAMES = {"main": "main stage", "late": "late stage"}
# --threads in a batch when not given: one torch thread per worker, --jobs defaults to one worker per core.
BATCH_THREADS = 1


def _progress_bar(total: int, late_ratio: float):
    """A click progress bar on stderr fed by the fit's progress callback: stage, iteration, loss, points, ETA.
    total: the iterations expected; the bar resizes when a stage announces its own (the point count, and so the
    scaled schedule, may be chosen from the input: then the late stage is guessed as `late_ratio` x the main)."""
    bar = click.progressbar(
        length=total,
        label="fitting",
        show_eta=True,
        show_percent=True,
        file=sys.stderr,
        item_show_func=lambda info: info,
        width=24,
    )
    state = {"last": 0}

    def callback(stage: str, done: int, stage_total: int, info: dict) -> None:
        if stage not in STAGE_NAMES:
            return
        offset = 0 if stage == "main" else state.get("main_total", 0)
        if stage not in state:  # a stage's first report: its real length
            state[stage] = True
            bar.length = offset + stage_total + (round(late_ratio * stage_total) if stage == "main" else 0)
        if stage == "main":
            state["main_total"] = stage_total
        position = offset + done
        loss, points = info.get("loss", 0.0), info.get("points", 0)
        text = f"{STAGE_NAMES[stage]} {done}/{stage_total}  loss {loss:.4g}  points {points}"
        bar.update(position - state["last"], current_item=text)
        state["last"] = position

    return bar, callback


def _progress_lines(every_s: float = PROGRESS_LINE_SECONDS):
    """Progress for logs (stderr not a terminal): one plain line per ~10 s with stage, iteration and ETA."""
    state = {"t0": time.perf_counter(), "last": 0.0, "main_total": 0}

    def callback(stage: str, done: int, stage_total: int, info: dict) -> None:
        now = time.perf_counter() - state["t0"]
        if stage == "main":
            state["main_total"] = stage_total
        if stage not in STAGE_NAMES or (now - state["last"] < every_s and done != stage_total):
            return
        state["last"] = now
        text = f"{STAGE_NAMES[stage]} {done}/{stage_total}, loss {info.get('loss', 0.0):.4g}, {now:.0f}s elapsed"
        if stage == "main" and done:
            text += f", main stage ETA {now / done * (stage_total - done):.0f}s"
        click.echo(f"tetweave encode: {text}", err=True)

    return callback


@click.command(context_settings={"show_default": True})
@click.argument("inputs", nargs=-1, required=True, metavar="MESH...")
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    default=None,
    help="Output .tw file; with several inputs, a directory or an @list: the output directory, where the outputs "
    "mirror the inputs' relative paths and manifest.jsonl records every file.  [default: MESH with the suffix .tw]",
)
@click.option(
    "--points",
    type=CountType(),
    default=None,
    help="Grid points during the fit (k = 1024); passive points are dropped before writing, so the file stores fewer. "
    "[default: without --size or --max-error, chosen from the input: up to 16k, fewer for inputs whose decoded mesh "
    "would get more than about 2x their faces]",
)
@click.option(
    "--sh-degree",
    type=click.Choice(["auto", "none", "0", "1", "2", "3"]),
    default="auto",
    help="Degree of the directional distances: none stores only s; higher places vertices more freely; auto: 1, "
    "none on CAD parts (sharp creases bounding every face), where the coefficients cost more than they buy.",
)
@click.option(
    "--layout",
    type=click.Choice(["fit", "grid", "best"]),
    default="fit",
    show_default=True,
    help="Where the points come from: fit = placed by the fit, then snapped to the position grid; grid = the "
    "cells of a lattice in a band around the input, whose s the fit then tunes (cheaper points, no placement: "
    "smaller files on evenly detailed scans, larger on most other meshes, half the encode time, slower decode; "
    "docs/measurements/grid_layout.md); best = both, keeping the lower error (--size) or the smaller file "
    "(--max-error), at the time of both. With grid, --points sets the cell size; grid and best choose their own "
    "quantization.",
)
@click.option(
    "--holes",
    type=click.Choice(["close", "keep"]),
    default="close",
    show_default=True,
    help="What becomes of an open input's holes: close = the decoded mesh spans them (always watertight); keep = "
    "the file lists the faces that span them (a few bytes) and the decoder removes them, so the mesh keeps the "
    "input's boundary (2-manifold with boundary, no self-intersections) and its error is not that of the caps. "
    "Closed inputs decode closed either way.",
)
@click.option(
    "--surface",
    type=click.Choice(["auto", "visible", "all"]),
    default="auto",
    show_default=True,
    help="What the fit takes as the input's surface: all = every face; visible = the faces offscreen renders see "
    "from outside, each turned towards its views (hidden parts, inner walls and the insides of overlapping parts "
    "drop out; face orientation does not matter); auto = visible when the input needs it (faces with "
    "inconsistent orientation, or over 1 % of its area hidden from every view), else all (the same file). A "
    "cavity no outside view sees (the inside of a closed box) is not part of the visible surface. The Chamfer "
    "distance, --size and --max-error measure against the surface fitted.",
)
@quality_option
@iters_option
@click.option(
    "--size",
    type=CountType(),
    default=None,
    help="Rate control: write at most this many bytes (k = 1024, M = 1024k) and at least 85 % of it; "
    "points and quantization are chosen to fit.",
)
@click.option(
    "--max-error",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="Rate control: the smallest file whose decoded mesh has a Chamfer distance to the input of at most this "
    "(symmetric point-to-surface mean, input's bounding box scaled into [-0.9, 0.9]^3).",
)
@click.option(
    "--format-version",
    type=click.Choice(["1", "2"]),
    default="2",
    help="Container: 2 = quantized and entropy-coded, 1 = raw float16 (128 bits per point at SH degree 1).",
)
@click.option(
    "--position-bits",
    type=click.FloatRange(6, 16),
    default=None,
    help="v2: grid cells per axis = 2^bits over [-1.2, 1.2]^3; a fraction (e.g. 8.5, in steps of 1/8) stores a "
    "grid between two.  [default: 8 at 4k points, one more per 4x points]",
)
@click.option(
    "--s-step",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="v2: quantization step of s (normalized frame).  [default: 5e-4 at 4k points, 2e-4 at 16k]",
)
@click.option(
    "--c-step",
    type=click.FloatRange(min=0, min_open=True),
    default=None,
    help="v2: quantization step of the SH coefficients (every band).  [default: 0.3 at 4k points, 0.2 at 16k]",
)
@click.option(
    "--smoothing",
    type=click.IntRange(0, 3),
    default=None,
    help="v2: Taubin smoothing steps the decoder applies to the surface (the fit optimizes the smoothed surface; "
    "0 = none).  [default: 1; 3 steps that keep the creases for CAD parts (sharp creases bounding every face); 0 with "
    "--format-version 1]",
)
@click.option(
    "--subdivision",
    type=click.IntRange(0, 2),
    default=None,
    help="v2: Loop subdivision levels the decoder applies after the smoothing (each makes 4x the faces; the fit "
    "optimizes the subdivided surface; 0 = none).  [default: 1; 0 for CAD parts and with "
    "--format-version 1]",
)
@click.option(
    "--keep-creases/--round-creases",
    default=None,
    help="v2: the decoder's smoothing and subdivision keep the surface's creases (vertices on edges whose faces turn "
    "by more than 30 degrees move only along the crease, corners stay) or round them like the rest.  [default: "
    "keep for inputs with sharp creases]",
)
@device_option
@click.option("--seed", type=int, default=0, help="Seed of every random choice: same seed, same bytes.")
@threads_option
@jobs_option("(batch)")
@ray_option("Batch")
@click.option("--force", is_flag=True, help="Batch: encode again the files the manifest says are done.")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
def encode(
    inputs: tuple[str, ...],
    output: Path | None,
    points: int,
    sh_degree: str,
    layout: str,
    holes: str,
    surface: str,
    quality: str,
    iters: int | None,
    size: int | None,
    max_error: float | None,
    format_version: str,
    position_bits: float | None,
    s_step: float | None,
    c_step: float | None,
    smoothing: int | None,
    subdivision: int | None,
    keep_creases: bool | None,
    device: str,
    seed: int,
    threads: int,
    jobs: int | None,
    ray_value: str | None,
    force: bool,
    quiet: bool,
) -> None:
    """Compress MESH (OBJ, PLY, STL, OFF, GLB) into a .tw file by fitting a TetWeave point cloud to it.

    Several MESH arguments, directories (searched recursively) and @list.txt files (one path per line) make a
    batch: -o DIR is required, files run in parallel (--jobs local processes, or --ray), a re-run skips the files
    already done with the same input and options, and the exit status is 1 when any file failed.

    Every encode checks its decoded mesh against something it did not fit to: the summary (and a batch's
    manifest, unseen_area_share) gives the share of the decoded area that no outside view sees (32 renders of the
    decoded mesh, 0.1-1.2 s, under 2 % of a default encode) and warns above 1 %: membranes or hidden parts kept
    inside the solid.
    """
    from tetweave_codec.options import EncodeOptions

    use_ray, ray_address, inputs = split_ray(ray_value, inputs)
    batch = is_batch(inputs) or use_ray or jobs is not None
    opts = EncodeOptions(
        points=points,
        sh_degree=sh_degree,
        layout=layout,
        holes=holes,
        surface=surface,
        quality=quality,
        iters=iters,
        size=size,
        max_error=max_error,
        format_version=int(format_version),
        position_bits=position_bits,
        s_step=s_step,
        c_step=c_step,
        smoothing=smoothing,
        subdivision=subdivision,
        keep_creases=keep_creases,
        device=device,
        seed=seed,
        threads=threads or (BATCH_THREADS if batch else 0),
    )
    if batch:
        _encode_batch(inputs, output, opts, jobs, use_ray, ray_address, force, quiet)
        return
    _encode_one(Path(inputs[0]), output, opts, quiet)


def _encode_batch(inputs, output, opts, jobs, use_ray, ray_address, force, quiet) -> None:
    """Several files through tetweave_codec.runner (see cli/batch.py)."""
    from tetweave_codec.meshio import MESH_FORMATS
    from tetweave_codec.runner.executors import default_jobs, make_executor, require_ray
    from tetweave_codec.runner.work import encode_file

    if use_ray:
        require_ray()
    jobs = jobs or default_jobs(opts.threads)
    gpus = 1.0 if opts.device == "cuda" else 0.0
    run_files(
        "tetweave encode",
        inputs,
        output,
        extensions=tuple(MESH_FORMATS),
        suffix=".tw",
        options=opts.as_dict(),
        worker=encode_file,
        executor_factory=lambda: make_executor(jobs, ray_address, use_ray, opts.threads, gpus),
        use_manifest=True,
        force=force,
        carry_data=use_ray,
        quiet=quiet,
    )


def _encode_one(mesh: Path, output: Path | None, opts, quiet: bool) -> None:
    """One file in this process, with the fit's own progress bar."""
    from tetweave_codec.encoder import DEFAULT_POINTS
    from tetweave_codec.encoder import encode as encode_mesh
    from tetweave_codec.fit.config import scaled_schedule, schedule_for
    from tetweave_codec.meshio import load_mesh, write_bytes_atomic
    from tetweave_codec.runner.inputs import check_output_file

    output = output or mesh.with_suffix(".tw")
    if output.resolve() == mesh.resolve():
        raise click.BadParameter("the output would overwrite the input", param_hint="-o/--output")
    check_output_file(output)  # before minutes of fitting
    configure_torch(opts.threads, opts.device)
    vertices, faces = load_mesh(mesh)
    schedule = schedule_for(opts.quality, opts.iters)
    late_ratio = schedule.late_iters / max(schedule.main_iters, 1)
    if opts.iters is None:  # the encoder scales the preset's iterations for smaller fits, as here
        schedule = scaled_schedule(schedule, opts.points or DEFAULT_POINTS)
    size, max_error = opts.size, opts.max_error
    t0 = time.perf_counter()
    if quiet:
        result = encode_mesh(vertices, faces, options=opts)
    elif sys.stderr.isatty() and size is None and max_error is None:  # rate control runs several fits
        # the grid layout runs the late stage only (its point count is about --points)
        iterations = schedule.late_iters + (schedule.main_iters if opts.layout != "grid" else 0)
        bar, callback = _progress_bar(iterations, late_ratio)
        with bar:
            result = encode_mesh(vertices, faces, options=opts, progress=callback)
    else:
        result = encode_mesh(vertices, faces, options=opts, progress=_progress_lines())
    write_bytes_atomic(output, result.data)
    st = result.stats
    sec = st["seconds"]
    stages = ", ".join(f"{k} {v:.1f}s" for k, v in sec.items() if k != "total")
    chamfer = f"{st['chamfer']:.3g}" if st["chamfer"] is not None else "n/a"
    click.echo(
        f"wrote {output} ({st['bytes']:,} bytes, {8 * st['bytes'] / max(st['points_kept'], 1):.1f} bits per point, "
        f".tw v{st['container_version']}): {st['points_kept']:,} points kept of {st['points_target']:,}, "
        f"SH degree {'none' if st['sh_degree'] < 0 else st['sh_degree']}, "
        + (f"{st['layout']} layout, " if st.get("layout", "fit") != "fit" else "")
        + f"{st['vertices']:,} vertices, {st['faces']:,} faces"
        + (f", the input's holes kept open ({st['hole_faces']:,} faces removed)" if st.get("hole_faces") else "")
    )
    if st.get("surface") == "visible":
        click.echo(f"fitted the surface a viewer sees, from renders ({st['surface_reason']})")
        click.echo(f"Chamfer distance to the input's visible surface (normalized frame): {chamfer}")
    else:
        if st.get("surface_reason"):
            click.echo(f"fitted every face of the input ({st['surface_reason']})")
        click.echo(f"Chamfer distance to the input (normalized frame): {chamfer}")
    check = _self_check_lines(result)
    click.echo(_context_line(result, len(faces)))
    if "target_bytes" in st:
        click.echo(f"size target {st['target_bytes']:,} bytes: wrote {st['bytes']:,} ({st['rate_control']})")
    if "target_error" in st:
        click.echo(f"error target {st['target_error']:.3g}: reached {chamfer} ({st['rate_control']})")
    if check is not None:
        stages += f", self-check {check.seconds:.1f}s"
    click.echo(f"time {time.perf_counter() - t0:.1f}s on {st['device']} ({stages})")


def _self_check_lines(result):
    """Print the share of the decoded area no outside view sees (metrics.unseen, on the decoded mesh: not the
    surface the fit took) and its warning above 1 %; returns the metrics.unseen.SelfCheck, None when not measured."""
    from tetweave_codec.metrics.unseen import self_check

    check = self_check(result.vertices, result.faces)
    if check is not None:
        click.echo(check.line())
        warning = check.warning(result.stats.get("surface"))
        if warning:
            click.echo(warning)
    return check


def _context_line(result, input_faces: int) -> str:
    """The file in context: the decoded faces against the input's, then plain Draco and fast-simplification + Draco
    of the input at the same Chamfer distance (measured with the summary's own metric, `classical`), saying
    plainly when either is smaller."""
    st = result.stats
    faces = f"decoded faces {st['faces']:,} = {st['faces'] / max(input_faces, 1):.2f}x the input's {input_faces:,}"
    try:
        from tetweave_codec.classical import encode_context
    except ImportError:  # DracoPy and fast-simplification are dependencies; a broken install only loses the lines
        return faces
    context = encode_context(result)
    if context is None:
        return faces
    return "\n".join([f"{faces}; {context['lines'][0]}", context["lines"][1]])
