"""`tetweave encode`: fit a TetWeave representation to a mesh and write the `.tw` file."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click
from tetweave_codec.cli.common import CountType, configure_torch, device_option, threads_option

STAGE_NAMES = {"main": "main stage", "late": "late stage"}


def _progress_bar(total: int):
    """A click progress bar on stderr fed by the fit's progress callback: stage, iteration, loss, points, ETA."""
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
        if stage == "main":
            state["main_total"] = stage_total
        position = offset + done
        loss, points = info.get("loss", 0.0), info.get("points", 0)
        text = f"{STAGE_NAMES[stage]} {done}/{stage_total}  loss {loss:.4g}  points {points}"
        bar.update(position - state["last"], current_item=text)
        state["last"] = position

    return bar, callback


@click.command(context_settings={"show_default": True})
@click.argument("mesh", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Output .tw file.  [default: MESH with the suffix .tw]",
)
@click.option(
    "--points",
    type=CountType(),
    default="16k",
    help="Grid points during the fit (k = 1024); passive points are dropped before writing, so the file stores fewer.",
)
@click.option(
    "--sh-degree",
    type=click.IntRange(0, 3),
    default=1,
    help="Degree of the directional distances: 0 is smallest, higher places vertices more freely.",
)
@click.option(
    "--quality",
    type=click.Choice(["fast", "default", "best"]),
    default="default",
    help="Iterations and render resolution of the fit.",
)
@click.option(
    "--iters",
    type=click.IntRange(min=2),
    default=None,
    help="Total iterations (main + late stage), overriding --quality's.",
)
@device_option
@click.option("--seed", type=int, default=0, help="Seed of every random choice: same seed, same bytes.")
@threads_option
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
def encode(
    mesh: Path,
    output: Path | None,
    points: int,
    sh_degree: int,
    quality: str,
    iters: int | None,
    device: str,
    seed: int,
    threads: int,
    quiet: bool,
) -> None:
    """Compress MESH (OBJ, PLY, STL, OFF, GLB) into a .tw file by fitting a TetWeave point cloud to it."""
    from tetweave_codec.encoder import encode as encode_mesh
    from tetweave_codec.fit.config import schedule_for
    from tetweave_codec.meshio import load_mesh, write_bytes_atomic

    output = output or mesh.with_suffix(".tw")
    if output.resolve() == mesh.resolve():
        raise click.BadParameter("the output would overwrite the input", param_hint="-o/--output")
    dev = configure_torch(threads, device)
    vertices, faces = load_mesh(mesh)
    schedule = schedule_for(quality, iters)
    t0 = time.perf_counter()
    if quiet:
        result = encode_mesh(
            vertices, faces, points=points, sh_degree=sh_degree, quality=quality, iters=iters, device=dev, seed=seed
        )
    else:
        bar, callback = _progress_bar(schedule.main_iters + schedule.late_iters)
        with bar:
            result = encode_mesh(
                vertices,
                faces,
                points=points,
                sh_degree=sh_degree,
                quality=quality,
                iters=iters,
                device=dev,
                seed=seed,
                progress=callback,
            )
    write_bytes_atomic(output, result.data)
    st = result.stats
    sec = st["seconds"]
    stages = ", ".join(f"{k} {v:.1f}s" for k, v in sec.items() if k != "total")
    chamfer = f"{st['chamfer']:.3g}" if st["chamfer"] is not None else "n/a"
    click.echo(
        f"wrote {output} ({st['bytes']:,} bytes): {st['points_kept']:,} points kept of {points:,}, "
        f"SH degree {sh_degree}, {st['vertices']:,} vertices, {st['faces']:,} faces"
    )
    click.echo(f"Chamfer distance to the input (normalized frame): {chamfer}")
    click.echo(f"time {time.perf_counter() - t0:.1f}s on {st['device']} ({stages})")
