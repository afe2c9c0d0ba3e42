"""Options and helpers shared by several commands."""

from __future__ import annotations

import click

from tetweave_codec.fit.config import QUALITY

# More torch threads than this is a typing error, not a machine: torch would try to allocate a pool for them and
# fail deep inside the fit ("out of memory", exit 1) instead of at the command line.
MAX_THREADS = 1024

# One torch thread by default: the fit is a long chain of small tensor operations, and a second thread only adds
# synchronization (spot and igea at --size 10k on an idle 2-core CPU: two threads took 1.26x and 1.34x the wall time
# of one, the same bytes; docs/measurements/encode_speed.md, 2026-12-05). The closest-point queries use every core
# whatever this says (libigl's own threads).
threads_option = click.option(
    "--threads",
    type=click.IntRange(min=0, max=MAX_THREADS),
    default=1,
    show_default=True,
    help="CPU threads for torch (0: torch's default, every core). The fit runs fastest on one.",
)

device_option = click.option(
    "--device",
    type=click.Choice(["auto", "cpu", "cuda"]),
    default="auto",
    show_default=True,
    help="Where torch runs: auto picks CUDA when present.",
)

# The fit's schedule, shared by `encode` and `bench`: preset and total iterations.
quality_option = click.option(
    "--quality",
    type=click.Choice(list(QUALITY)),
    default="default",
    show_default=True,
    help="Iterations and render resolution of the fit.",
)
iters_option = click.option(
    "--iters",
    type=click.IntRange(min=2),
    default=None,
    help="Total iterations of the fit (main + late stage), overriding --quality's.",
)


def configure_torch(threads: int = 0, device: str = "auto"):
    """Apply --threads and resolve --device; returns a torch.device. Imports torch lazily."""
    import torch

    from tetweave_codec.encoder import resolve_device

    if threads:
        torch.set_num_threads(threads)
    return resolve_device(device)


def parse_count(text: str) -> int:
    """'16k' -> 16384, '2m' -> 2097152, '5000' -> 5000. The suffixes are binary (k = 1024), as point counts in the
    paper (8K, 16K, 64K) are powers of two. Raises click.BadParameter on anything else."""
    raw = str(text).strip().lower()
    factor = 1
    if raw.endswith("k"):
        factor, raw = 1024, raw[:-1]
    elif raw.endswith("m"):
        factor, raw = 1024 * 1024, raw[:-1]
    try:
        value = float(raw) * factor
    except ValueError:
        raise click.BadParameter(f"{text!r} is not a count (examples: 8000, 16k, 1.5k)") from None
    if not value.is_integer() or value <= 0:
        raise click.BadParameter(f"{text!r} is not a positive whole count")
    return int(value)


class CountType(click.ParamType):
    """A click parameter type for point counts with k/m suffixes (see `parse_count`)."""

    name = "count"

    def convert(self, value, param, ctx):
        if isinstance(value, int):
            return value
        try:
            return parse_count(value)
        except click.BadParameter as exc:
            self.fail(exc.message, param, ctx)


# Plain progress lines (stderr not a terminal) come at most this often, in every command.
PROGRESS_LINE_SECONDS = 10.0


def _duration(seconds: float | None) -> str:
    if seconds is None:
        return "?"
    seconds = int(seconds)
    if seconds >= 3600:
        return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
    return f"{seconds // 60}m{seconds % 60:02d}s"


def batch_progress(command: str, total: int, quiet: bool = False):
    """Progress over the files of a batch, fed by `runner.batch.run_batch`: on a terminal one bar (done, failed,
    files per hour, ETA); otherwise a plain line every PROGRESS_LINE_SECONDS and one per failed file.

    Returns (context manager, callback(record, counts)).
    """
    import contextlib
    import sys
    import time

    def failure(record) -> str:
        error = record["error"] or ""
        return f"{command}: failed: " + (error if error.startswith(record["input"]) else f"{record['input']}: {error}")

    def text(counts) -> str:
        return (
            f"{counts.done}/{counts.total} files ({counts.ok} ok, {counts.failed} failed, {counts.skipped} skipped), "
            f"{counts.files_per_hour():.0f} files/h, ETA {_duration(counts.eta_seconds())}"
        )

    if quiet:
        return contextlib.nullcontext(), lambda record, counts: None
    if sys.stderr.isatty():
        bar = click.progressbar(length=total, label=command, file=sys.stderr, width=24, show_eta=False)

        def on_bar(record, counts) -> None:
            if record["status"] == "failed":
                click.echo("\n" + failure(record), err=True)
            bar.label = f"{command}: {text(counts)}"
            bar.update(1)

        return bar, on_bar
    state = {"last": time.monotonic()}

    def on_line(record, counts) -> None:
        now = time.monotonic()
        if record["status"] == "failed":
            click.echo(failure(record), err=True)
        if now - state["last"] >= PROGRESS_LINE_SECONDS or counts.done == counts.total:
            state["last"] = now
            click.echo(f"{command}: {text(counts)}", err=True)

    return contextlib.nullcontext(), on_line
