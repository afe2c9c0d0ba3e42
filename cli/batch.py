"""Batch glue shared by `tetweave encode` and `tetweave decode` (several inputs, a directory or an @list).

The work itself is tetweave_codec.runner; this module checks the output directory, expands the inputs, shows
progress and the summary, and sets the exit status: 0 when every file is ok or skipped, 1 when any failed
(usage errors exit 2 before any work, through the CLI's error handling).
"""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path

import click

from tetweave_codec.errors import InputError

# `--ray` alone means a local Ray started for the run; `--ray auto` an existing cluster; `--ray HOST:PORT` or
# `--ray ray://HOST:PORT` a given one.
RAY_LOCAL = "local"
_ADDRESS = re.compile(r"^(auto|local|[a-z]+://\S+|[\w.-]+:\d+)$")


def jobs_option(what: str):
    return click.option(
        "--jobs",
        "-j",
        type=click.IntRange(min=1),
        default=None,
        help=f"Local worker processes {what}.  [default: CPU cores / --threads]",
    )


def ray_option(what: str):
    """`--ray [ADDRESS]` (parameter `ray_value`; see `split_ray`)."""
    return click.option(
        "--ray",
        "ray_value",
        is_flag=False,
        flag_value=RAY_LOCAL,
        default=None,
        metavar="[ADDRESS]",
        help=f"{what} on Ray, one task per file: 'auto' = an existing cluster, HOST:PORT or ray://HOST:PORT a given "
        'one, no address = a local Ray for this run. Needs pip install "tetweave[ray]".',
    )


def split_ray(value: str | None, inputs: tuple[str, ...]) -> tuple[bool, str | None, tuple[str, ...]]:
    """(use Ray, address or None for a local Ray, inputs). `--ray` takes an optional value, so `--ray mesh.ply`
    reads the input as the address: a value that does not look like an address is given back to the inputs."""
    if value is None:
        return False, None, inputs
    if value == RAY_LOCAL:
        return True, None, inputs
    if _ADDRESS.match(value) and not Path(value).exists():
        return True, value, inputs
    return True, None, (value, *inputs)


def run_files(
    command: str,
    inputs: tuple[str, ...],
    out_dir: Path | None,
    *,
    extensions: tuple[str, ...],
    suffix: str,
    options: dict,
    worker,
    executor_factory,
    use_manifest: bool,
    force: bool = False,
    carry_data: bool = False,
    quiet: bool = False,
) -> None:
    """Check `out_dir`, expand `inputs`, run `worker` on each through `executor_factory()`, print the summary and
    exit 1 when any file failed. Outputs are `out_dir / relative input path` with `suffix`."""
    from tetweave_codec.runner.batch import make_tasks, run_batch, summary_lines
    from tetweave_codec.runner.inputs import check_writable_dir, collect_inputs, output_paths
    from tetweave_codec.runner.manifest import FAILED, Manifest

    from .common import batch_progress

    if out_dir is None:
        raise InputError("several inputs, a directory or an @list need -o DIR (the outputs mirror the inputs there)")
    sources = collect_inputs(inputs, extensions)
    check_writable_dir(out_dir, create=True)
    outputs = output_paths(sources, out_dir, suffix)
    tasks = make_tasks([s.path for s in sources], outputs, out_dir, options)
    executor = executor_factory()
    manifest = Manifest(out_dir) if use_manifest else None
    bar, callback = batch_progress(command, len(tasks), quiet)
    t0 = time.perf_counter()
    with bar:
        records = run_batch(
            tasks, worker, executor, manifest=manifest, force=force, carry_data=carry_data, progress=callback
        )
    for line in summary_lines(records, time.perf_counter() - t0):
        click.echo(line)
    failures = [r for r in records if r["status"] == FAILED]
    if failures:
        where = f"; see {manifest.path}" if manifest is not None else ""
        click.echo(f"{command}: {len(failures)} of {len(records)} files failed{where}", err=True)
        sys.exit(1)
