"""Speed of the renderer: rasterize, forward, and forward + backward of an L1 loss on mask + depth + normals.

Meshes: a bumpy torus tessellated to exactly the requested face counts (self-occluding from most directions),
in the normalized frame. Views: Fibonacci cameras at radius 3, fov 45°. Every configuration is run `--repeats`
times after one warm-up; the table shows medians and the ratio to a baseline measured in the same run
(100K faces, 4 views, 256², forward, first device), so that tables from noisy machines stay comparable.

    python -m tetweave_codec.benchmarks.render_speed --threads 2
    python -m tetweave_codec.benchmarks.render_speed --faces 100k --sizes 128,256 --repeats 3

Modes: "rasterize" is `rasterize` alone (z-buffer, no gradient); "forward" is `render_maps` with antialiasing
under torch.no_grad() (how the encoder renders its targets); "fwd+bwd" is `render_maps` with gradients plus
an L1 loss against fixed target maps and its backward pass (one fitting iteration's rendering work).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import torch

from tetweave_codec.render import fibonacci_cameras, rasterize, render_maps

MODES = ("rasterize", "forward", "fwd+bwd")


def bumpy_torus(n_faces: int, dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """A closed torus with bumps, outward normals, (V,3) and (F,3), F = n_faces within 1%."""
    ratio = 2.0  # around the ring vs around the tube
    nv = max(3, round(math.sqrt(n_faces / (2.0 * ratio))))
    nu = max(3, round(n_faces / (2.0 * nv)))
    u = torch.arange(nu, dtype=torch.float64) / nu * 2 * math.pi
    v = torch.arange(nv, dtype=torch.float64) / nv * 2 * math.pi
    uu, vv = torch.meshgrid(u, v, indexing="ij")
    r = 0.25 * (1 + 0.15 * torch.sin(7 * uu) * torch.sin(5 * vv))
    ring = 0.6 + r * torch.cos(vv)
    verts = torch.stack([ring * torch.cos(uu), r * torch.sin(vv), ring * torch.sin(uu)], -1).reshape(-1, 3)
    i = torch.arange(nu)[:, None]
    j = torch.arange(nv)[None, :]
    a, b = i * nv + j, ((i + 1) % nu) * nv + j
    c, d = ((i + 1) % nu) * nv + (j + 1) % nv, i * nv + (j + 1) % nv
    # wound so that the normals point outwards, like the encoder's meshes
    faces = torch.cat([torch.stack([a, c, b], -1).reshape(-1, 3), torch.stack([a, d, c], -1).reshape(-1, 3)])
    return verts.to(dtype), faces


def _time(fn, repeats: int, device: torch.device) -> float:
    """Median wall time of fn() in milliseconds, after one warm-up call."""
    fn()
    times = []
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        t0 = time.perf_counter()
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def measure(n_faces: int, views: int, size: int, mode: str, device: torch.device, repeats: int) -> float:
    verts, faces = bumpy_torus(n_faces)
    verts, faces = verts.to(device), faces.to(device)
    cams = fibonacci_cameras(views, device=device)
    if mode == "rasterize":
        return _time(lambda: rasterize(verts, faces, cams, size), repeats, device)
    if mode == "forward":

        def forward():
            with torch.no_grad():
                render_maps(verts, faces, cams, size)

        return _time(forward, repeats, device)
    with torch.no_grad():
        target = render_maps(verts * 1.02, faces, cams, size)  # a slightly bigger shape

    def step():
        v = verts.clone().requires_grad_(True)
        maps = render_maps(v, faces, cams, size)
        loss = (
            (maps.mask - target.mask).abs().mean()
            + (maps.depth - target.depth).abs().mean()
            + (maps.normals - target.normals).abs().mean()
        )
        loss.backward()

    return _time(step, repeats, device)


def parse_count(text: str) -> int:
    text = text.strip().lower()
    mult = {"k": 1000, "m": 1000_000}.get(text[-1:], 1)
    return int(float(text[:-1] if mult > 1 else text) * mult)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--faces", default="100k,1M", help="comma-separated face counts (k = 1000, M = 1e6)")
    parser.add_argument("--sizes", default="256,512", help="comma-separated image sizes (pixels per side)")
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--modes", default=",".join(MODES), help=f"comma-separated subset of {MODES}")
    parser.add_argument(
        "--device", choices=["auto", "cpu", "cuda"], default="auto", help="auto: the CPU, and CUDA too when present"
    )
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per configuration (median)")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.device == "auto":
        devices = [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
    else:
        devices = [torch.device(args.device)]
    face_counts = [parse_count(t) for t in args.faces.split(",")]
    sizes = [int(s) for s in args.sizes.split(",")]
    modes = [m.strip() for m in args.modes.split(",")]
    if any(m not in MODES for m in modes):
        parser.error(f"--modes must be a subset of {MODES}")

    baseline = measure(100_000, 4, 256, "forward", devices[0], args.repeats)
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} CPU threads; baseline = 100K faces, "
        f"4 views, 256², forward on {devices[0].type}: {baseline:.1f} ms"
    )
    header = f"{'device':>6} {'faces':>9} {'views':>5} {'size':>5} {'mode':>9} {'median ms':>10} {'ratio':>7}"
    print(header)
    print("-" * len(header))
    rows = []
    for device in devices:
        for n_faces in face_counts:
            actual = bumpy_torus(n_faces)[1].shape[0]
            for size in sizes:
                for mode in modes:
                    ms = measure(n_faces, args.views, size, mode, device, args.repeats)
                    rows.append(
                        dict(
                            device=device.type,
                            faces=actual,
                            views=args.views,
                            size=size,
                            mode=mode,
                            ms=ms,
                            ratio=ms / baseline,
                        )
                    )
                    print(
                        f"{device.type:>6} {actual:>9,} {args.views:>5} {size:>5} {mode:>9} {ms:>10.1f} "
                        f"{ms / baseline:>7.2f}",
                        flush=True,
                    )
    return rows


if __name__ == "__main__":
    main()
