"""`tetweave render`: shaded previews of a mesh or a `.tw` file, several views in one PNG."""

from __future__ import annotations

import time
from pathlib import Path

import click

from tetweave_codec.cli.common import configure_torch, device_option, threads_option

VIEWS_PER_PASS = 4  # views rendered together: bounds memory for big meshes and images


@click.command(context_settings={"show_default": True})
@click.argument("mesh_or_tw", metavar="MESH_OR_TW", type=click.Path(dir_okay=False, path_type=Path))
@click.option(
    "-o",
    "--output",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Output PNG.  [default: the input's name plus .png, e.g. bunny.ply.png]",
)
@click.option(
    "--views",
    type=click.IntRange(1, 64),
    default=4,
    help="Views from directions spread evenly around the object (Fibonacci sphere).",
)
@click.option("--size", type=click.IntRange(16, 4096), default=512, help="Pixels per side of each view.")
@click.option(
    "--shading",
    type=click.Choice(["lambert", "normals"]),
    default="lambert",
    help="Grey diffuse shading under a headlight, or world-space normals as colours.",
)
@device_option
@threads_option
def render(
    mesh_or_tw: Path, output: Path | None, views: int, size: int, shading: str, device: str, threads: int
) -> None:
    """Render MESH_OR_TW (OBJ, PLY, STL, OFF, GLB, or a .tw file, decoded first) from several directions into
    one PNG of shaded views."""
    import torch

    from tetweave_codec.meshio import load_mesh, normalize
    from tetweave_codec.render import fibonacci_cameras, image_grid, mesh_edges, render_maps, save_png, shade

    output = output or mesh_or_tw.with_name(mesh_or_tw.name + ".png")
    if output.suffix.lower() != ".png":
        raise click.BadParameter(f"{output}: the output must be a .png file", param_hint="-o/--output")
    if output.exists() and output.resolve() == mesh_or_tw.resolve():
        raise click.BadParameter("the output would overwrite the input", param_hint="-o/--output")
    dev = configure_torch(threads, device)
    t0 = time.perf_counter()
    if mesh_or_tw.suffix.lower() == ".tw":
        from tetweave_codec.decoder import decode

        vertices, faces = decode(mesh_or_tw.read_bytes())
    else:
        vertices, faces = load_mesh(mesh_or_tw)
    normalized, _, _ = normalize(vertices)
    cams = fibonacci_cameras(views, device=dev)
    images = []
    with torch.no_grad():
        verts = torch.as_tensor(normalized, dtype=torch.float32, device=dev)
        tris = torch.as_tensor(faces, dtype=torch.long, device=dev)
        edges = mesh_edges(tris, len(verts))
        for start in range(0, views, VIEWS_PER_PASS):
            part = cams[start : start + VIEWS_PER_PASS]
            images.append(shade(render_maps(verts, tris, part, size, edges=edges), part, mode=shading))
    save_png(output, image_grid(torch.cat(images)))
    click.echo(
        f"wrote {output}: {views} views of {size}x{size} pixels, {len(faces):,} faces, {time.perf_counter() - t0:.1f}s"
    )
