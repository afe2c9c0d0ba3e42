"""`tetweave bench`: compress every mesh of a folder with tetweave, Draco and decimation + Draco (fast-simplification
and MeshLab), and report.

Writes into --out: results.csv (one row per mesh, method and setting), summary.md (verdict at matched Chamfer
distance and a table per mesh), rd_<mesh>.png (bytes against Chamfer distance) and side_by_side_<mesh>.png.
Results are rewritten after every mesh, so an interrupted run still leaves the meshes done so far.
"""

from __future__ import annotations

import shlex
import time
from pathlib import Path

import click

from tetweave_codec.bench.baselines import DECIMATE_BITS, DECIMATE_KEEP, DRACO_BITS, MLAB_BITS, MLAB_KEEP
from tetweave_codec.bench.batch import ADAPTIVE, SWEEPS
from tetweave_codec.bench.methods import DECIMATE_DRACO, DRACO, FAMILIES, MLAB_DRACO, TETWEAVE
from tetweave_codec.cli.batch import jobs_option, ray_option, split_ray
from tetweave_codec.cli.common import (
    configure_torch,
    device_option,
    iters_option,
    parse_count,
    quality_option,
    threads_option,
)
from tetweave_codec.errors import TetweaveError
from tetweave_codec.geometry.sh import SH_DEGREE_MAX
from tetweave_codec.meshio import write_bytes_atomic
from tetweave_codec.options import SURFACES

ADAPTIVE_NOTE = (
    "Classical settings: the adaptive sweep (`--sweep adaptive`) measured, on each curve, only the settings around "
    "each tetweave file's Chamfer distance; rows with a Chamfer distance alone were measured for it only, the two "
    "settings around each tetweave point on each family's front carry every metric. `--sweep full` measures every "
    "setting."
)


def _joined(values) -> str:
    """Values as one comma-separated option value (floats in %g): the defaults built from the baselines' tuples,
    and the regenerating command line of summary.md."""
    return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in values)


def _split(text: str) -> list[str]:
    return [t.strip() for t in str(text).split(",") if t.strip()]


def _sizes(ctx, param, value: str) -> list[int]:
    return _counts(ctx, param, value) if value.strip() else []


def _counts(ctx, param, value: str) -> list[int]:
    out = []
    for token in _split(value):
        try:
            out.append(parse_count(token))
        except click.BadParameter as exc:
            raise click.BadParameter(exc.message, ctx=ctx, param=param) from None
    if not out:
        raise click.BadParameter("give at least one value", ctx=ctx, param=param)
    return out


def _ints(low: int, high: int):
    def convert(ctx, param, value: str) -> list[int]:
        try:
            out = [int(t) for t in _split(value)]
        except ValueError:
            raise click.BadParameter(f"{value!r} is not a comma-separated list of integers") from None
        bad = [x for x in out if not low <= x <= high]
        if bad or not out:
            raise click.BadParameter(f"values must be integers in {low}..{high}, got {value!r}")
        return out

    return convert


def _degrees(ctx, param, value: str) -> list[int | None]:
    """--sh-degree: comma-separated degrees 0..SH_DEGREE_MAX, "auto" -> None (the encoder's choice)."""
    out: list[int | None] = []
    for token in _split(value):
        if token == "auto":
            out.append(None)
        elif token.isdigit() and int(token) <= SH_DEGREE_MAX:
            out.append(int(token))
        else:
            raise click.BadParameter(f"SH degrees are 0-{SH_DEGREE_MAX} or auto, got {token!r}")
    if not out:
        raise click.BadParameter("give at least one SH degree (0-3 or auto)")
    return out


def _encoder_choices(constant: str, what: str):
    """A click callback for a comma-separated list of choices the encoder names in `encoder.<constant>` (LAYOUTS,
    HOLES): duplicates dropped, order kept, BadParameter on anything else."""

    def callback(ctx, param, value: str) -> list[str]:
        from tetweave_codec import encoder

        allowed = getattr(encoder, constant)
        out = list(dict.fromkeys(_split(value)))
        if not out or any(x not in allowed for x in out):
            raise click.BadParameter(f"{what} are {', '.join(allowed)}, comma-separated; got {value!r}")
        return out

    return callback


def _fractions(ctx, param, value: str) -> list[float]:
    try:
        out = [float(t.rstrip("%")) / (100.0 if t.endswith("%") else 1.0) for t in _split(value)]
    except ValueError:
        raise click.BadParameter(f"{value!r} is not a comma-separated list of fractions (0.1 or 10%)") from None
    if not out or any(not 0.0 < x <= 1.0 for x in out):
        raise click.BadParameter(f"fractions must be in (0, 1], got {value!r}")
    return out


def _methods(ctx, param, value: str) -> list[str]:
    out = _split(value)
    bad = [m for m in out if m not in FAMILIES]
    if bad or not out:
        raise click.BadParameter(f"choose among {', '.join(FAMILIES)} (comma-separated), got {value!r}")
    return list(dict.fromkeys(out))


def _fit_progress(say, label: str, steps: int = 4):
    """A fit progress callback that reports each stage `steps` times (not every iteration) through `say`."""
    last: dict[str, int] = {}

    def callback(stage: str, done: int, total: int, info: dict) -> None:
        if total <= 0 or stage not in ("main", "late"):
            return
        step = done * steps // total
        if step != last.get(stage):
            last[stage] = step
            loss = f", loss {info['loss']:.4g}" if "loss" in info else ""
            pts = f", {info['points']:,} points" if "points" in info else ""
            say(f"  {label}: {stage} stage {done}/{total}{loss}{pts}")

    return callback


def _file_name(setting: str) -> str:
    """A method setting as a file name: "size 5120 sh auto" -> "size-5120-sh-auto.tw"."""
    return "".join(ch if ch.isalnum() or ch in "._+" else "-" for ch in setting.strip()) + ".tw"


def _write_files(result, folder: Path, say) -> None:
    """The mesh's tetweave files as FOLDER/MESH/SETTING.tw, for `tetweave info` and lossless coding studies
    (benchmarks/entropy_coding.py) without another fit."""
    for setting, data in result.files.items():
        path = folder / result.name / _file_name(setting)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(path, data)
        except OSError as exc:  # a file must not cost the numbers
            say(f"{result.name}: could not write {path}: {exc}")


def _command_line(p: dict) -> str:
    """The full `tetweave bench` command that regenerates a run, from the command's resolved parameters `p`
    (every option explicit, for summary.md)."""
    methods = p["methods"]
    args = [str(p["mesh_dir"]), "--out", str(p["out_dir"]), "--methods", ",".join(methods)]
    if TETWEAVE in methods:
        args += [
            "--points",
            _joined(p["points"]),
            *(["--sizes", _joined(p["sizes"])] if p["sizes"] else []),
            "--sh-degree",
            ",".join("auto" if d is None else str(d) for d in p["sh_degrees"]),
            *(["--layout", ",".join(p["layouts"])] if p["layouts"] != ["fit"] else []),
            *(["--holes", ",".join(p["holes"])] if p["holes"] != ["close"] else []),
            "--quality",
            p["quality"],
        ]
        args += ["--iters", str(p["iters"])] if p["iters"] else []
        args += ["--device", p["device"]]
    if DRACO in methods:
        args += ["--draco-bits", _joined(p["draco_bits"])]
    if DECIMATE_DRACO in methods:
        args += ["--decimate", _joined(p["keep"]), "--decimate-bits", _joined(p["decimate_bits"])]
    if MLAB_DRACO in methods:
        args += ["--mlab", _joined(p["mlab_keep"]), "--mlab-bits", _joined(p["mlab_bits"])]
    args += ["--sweep", p["sweep"]] if any(m != TETWEAVE for m in methods) else []
    args += ["--surface", p["surface"]] if p["surface"] != "auto" else []  # the target of every method's metrics
    args += ["--samples", str(p["samples"]), "--seed", str(p["seed"])]
    args += [] if p["pictures"] else ["--no-pictures"]
    args += ["--threads", str(p["threads"])] if p["threads"] else []
    return "tetweave bench " + " ".join(shlex.quote(a) for a in args)


@click.command(context_settings={"show_default": True})
@click.argument("mesh_dir", type=click.Path(exists=True, path_type=Path))
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("bench-results"),
    help="Folder for results.csv, summary.md and the pictures (created if missing).",
)
@click.option(
    "--methods",
    default=",".join(FAMILIES),
    callback=_methods,
    help=f"Comma-separated methods among: {', '.join(FAMILIES)} (mlab+draco needs pymeshlab: "
    '"tetweave[bench]"; left out of the default when it is missing).',
)
@click.option(
    "--points",
    default="8k,16k,32k",
    callback=_sizes,
    help="tetweave grid point counts, comma-separated (k = 1024); empty for none (then give --sizes).",
)
@click.option(
    "--sizes",
    default="",
    callback=_sizes,
    help="tetweave target file sizes in bytes (rate control, k = 1024), comma-separated; run besides --points.",
)
@click.option(
    "--sh-degree",
    "sh_degrees",
    default="auto",
    callback=_degrees,
    help="tetweave SH degrees, comma-separated, 0-3 or auto (the encoder's choice: 1, none on CAD parts); every "
    "degree runs at every --points.",
)
@click.option(
    "--layout",
    "layouts",
    default="fit",
    callback=_encoder_choices("LAYOUTS", "layouts"),
    help="tetweave layouts, comma-separated: fit, grid, best (see tetweave encode --layout; best only with --sizes); "
    "each is its own curve.",
)
@click.option(
    "--holes",
    "holes",
    default="close",
    callback=_encoder_choices("HOLES", "holes"),
    help="tetweave's treatment of open inputs' holes, comma-separated: close, keep (see tetweave encode --holes); "
    "each is its own curve.",
)
@click.option(
    "--surface",
    type=click.Choice(SURFACES),
    default="auto",
    help="tetweave's --surface (see tetweave encode --surface). Every method, the classical ones too, is measured "
    "against the surface it resolves to on each mesh (the visible surface or the whole input; summary.md says "
    "which); the classical methods always compress every face of the input.",
)
@quality_option
@iters_option
@click.option(
    "--draco-bits",
    default=_joined(DRACO_BITS),
    callback=_ints(1, 30),
    help="Draco position quantization bits, comma-separated.",
)
@click.option(
    "--decimate",
    "keep",
    default=_joined(DECIMATE_KEEP),
    callback=_fractions,
    help="decimate+draco: fractions of the faces kept (0.1 or 10%), comma-separated.",
)
@click.option(
    "--decimate-bits",
    default=_joined(DECIMATE_BITS),
    callback=_ints(1, 30),
    help="decimate+draco: Draco quantization bits after decimation, comma-separated.",
)
@click.option(
    "--mlab",
    "mlab_keep",
    default=_joined(MLAB_KEEP),
    callback=_fractions,
    help="mlab+draco (MeshLab quadric edge collapse, optimal placement): fractions of the faces kept.",
)
@click.option(
    "--mlab-bits",
    default=_joined(MLAB_BITS),
    callback=_ints(1, 30),
    help="mlab+draco: Draco quantization bits after decimation, comma-separated.",
)
@click.option(
    "--sweep",
    type=click.Choice(SWEEPS),
    default=ADAPTIVE,
    help="Classical settings measured: adaptive measures, on each curve of --draco-bits, --decimate and --mlab, "
    "only those around each tetweave file's Chamfer distance (the sizes at matched error are the full sweep's "
    "while error and bytes are monotone along a curve; every setting without tetweave); full measures all of them.",
)
@click.option(
    "--samples",
    type=click.IntRange(min=1000),
    default=200_000,
    help="Surface samples per mesh for the Chamfer-type metrics.",
)
@click.option("--seed", type=int, default=0, help="Seed of the tetweave fits and of the metric samples.")
@click.option("--pictures/--no-pictures", default=True, help="Render the side-by-side pictures.")
@device_option
@threads_option
@jobs_option("for the tetweave encodes, which then all run first, in parallel")
@ray_option("Run the tetweave encodes")
def bench(
    mesh_dir: Path,
    out_dir: Path,
    methods: list[str],
    points: list[int],
    sizes: list[int],
    sh_degrees: list[int | None],
    layouts: list[str],
    holes: list[str],
    surface: str,
    quality: str,
    iters: int | None,
    draco_bits: list[int],
    keep: list[float],
    decimate_bits: list[int],
    mlab_keep: list[float],
    mlab_bits: list[int],
    sweep: str,
    samples: int,
    seed: int,
    pictures: bool,
    device: str,
    threads: int,
    jobs: int | None,
    ray_value: str | None,
) -> None:
    """Compare tetweave with Draco on every mesh in MESH_DIR (a folder, or one mesh file).

    Every method's output is decoded and measured against its input in the input's normalized frame (against the
    input's visible surface where --surface resolves to it: the same target as the fit; Chamfer and Hausdorff
    distances, normal consistency, F1, edge metrics, triangle quality, watertightness,
    self-intersections); sizes are compared at matched Chamfer distance. A failing mesh or method is recorded
    in its rows and the batch goes on.
    """
    from tetweave_codec.bench import report
    from tetweave_codec.bench.baselines import (
        MLAB_MISSING,
        decimate_draco_methods,
        draco_methods,
        mlab_available,
        mlab_draco_methods,
    )
    from tetweave_codec.bench.batch import find_meshes, run_batch
    from tetweave_codec.bench.methods import TetweaveMethod
    from tetweave_codec.bench.pictures import plot_rate_distortion, side_by_side
    from tetweave_codec.bench.sweep import adaptive_sweep  # noqa: F401  (loaded now; batch.run_mesh uses it)
    from tetweave_codec.metrics.common import MetricOptions

    paths = find_meshes(mesh_dir)
    t_start = time.perf_counter()

    def say(message: str) -> None:
        click.echo(f"[{time.perf_counter() - t_start:7.1f}s] {message}", err=True)

    ctx = click.get_current_context()
    if MLAB_DRACO in methods and not mlab_available():
        if ctx.get_parameter_source("methods") != click.core.ParameterSource.DEFAULT:
            raise TetweaveError(MLAB_MISSING)
        methods = [m for m in methods if m != MLAB_DRACO]
        ctx.params["methods"] = methods
        say(f"{MLAB_MISSING}; running without it")

    if TETWEAVE in methods:
        device = str(configure_torch(threads, device))
    elif threads and pictures:  # only the renderer uses torch; the baselines never import it
        import torch

        torch.set_num_threads(threads)
    if TETWEAVE in methods and not points and not sizes:
        raise click.BadParameter("give tetweave --points or --sizes", param_hint="--points")
    method_list = []
    if DRACO in methods:
        method_list += draco_methods(draco_bits)
    if DECIMATE_DRACO in methods:
        method_list += decimate_draco_methods(keep, decimate_bits)
    if MLAB_DRACO in methods:
        method_list += mlab_draco_methods(mlab_keep, mlab_bits)
    if TETWEAVE in methods:
        # A run is a point count, or a target size (rate control picks the points).
        runs = [(n, None, f"{n} pts") for n in points] + [(0, s, f"size {s}") for s in sizes]
        method_list += [
            TetweaveMethod(
                n,
                d,
                quality=quality,
                iters=iters,
                device=device,
                seed=seed,
                progress=_fit_progress(say, f"tetweave {label} {'sh auto' if d is None else f'sh{d}'} {layout}"),
                size=s,
                layout=layout,
                holes=h,
                surface=surface,
            )
            for layout in layouts
            for h in holes
            for d in sh_degrees
            for n, s, label in runs
        ]
    out_dir.mkdir(parents=True, exist_ok=True)
    options = MetricOptions.for_samples(samples, seed=seed)
    command = _command_line(ctx.params)
    rows: list[dict] = []
    images: dict[str, list[str]] = {}
    targets: dict[str, str] = {}
    notes = [ADAPTIVE_NOTE] if sweep == ADAPTIVE and TETWEAVE in methods and len(method_list) > 0 else []

    def on_mesh(result) -> None:
        rows.extend(result.rows)
        _write_files(result, out_dir / "files", say)
        names = []
        jobs = [
            (
                f"rd_{result.name}.png",
                lambda p: plot_rate_distortion(result.rows, p, title=result.name),
            )
        ]
        if pictures:
            jobs.append((f"side_by_side_{result.name}.png", lambda p: side_by_side(result, result.rows, p)))
        for name, job in jobs:
            try:
                if job(out_dir / name):
                    names.append(name)
            except Exception as exc:  # a picture must not cost the numbers
                say(f"{result.name}: could not write {name}: {type(exc).__name__}: {exc}")
        images[result.name] = names
        targets[result.name] = result.target
        report.write_csv(rows, out_dir / "results.csv")
        report.write_summary(rows, out_dir / "summary.md", command=command, images=images, notes=notes, targets=targets)

    say(f"{len(paths)} mesh(es) x {len(method_list)} method setting(s) -> {out_dir}")
    use_ray, ray_address, _ = split_ray(ray_value, ())
    if TETWEAVE in methods and (use_ray or jobs is not None):  # the fits first, in parallel, through the runner
        from tetweave_codec.bench.parallel import precompute
        from tetweave_codec.runner.executors import default_jobs, make_executor, require_ray

        if use_ray:
            require_ray()
        workers = threads or 1
        executor = make_executor(jobs or default_jobs(workers), ray_address, use_ray, workers)
        method_list = precompute(paths, method_list, executor, workers, progress=say)
    all_rows = run_batch(paths, method_list, options, progress=say, on_mesh=on_mesh, sweep=sweep, surface=surface)
    # meshes that could not be loaded never reach on_mesh: their rows are only in all_rows
    report.write_csv(all_rows, out_dir / "results.csv")
    report.write_summary(all_rows, out_dir / "summary.md", command=command, images=images, notes=notes, targets=targets)
    failures = sum(1 for r in all_rows if r.get("error"))
    say(
        f"done: {out_dir / 'results.csv'}, {out_dir / 'summary.md'}"
        + (f"; {failures} failed row(s), see the error column" if failures else "")
    )
