"""The batch driver: tasks -> (skip or run on an executor) -> output files written atomically -> manifest records.

The driver is the only process that writes: each finished file's output goes through a temporary file and a
rename, then its record is appended to the manifest, so an interrupted run leaves only whole outputs, each with
its record, and a re-run resumes after them. Inputs are hashed lazily, as workers become free, so the first fits
start at once even for 100,000 files.
"""

from __future__ import annotations

import hashlib
import os
import statistics
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from tetweave_codec.errors import error_line
from tetweave_codec.runner.manifest import FAILED, OK, SKIPPED, Manifest, canonical, file_sha256, new_record
from tetweave_codec.runner.work import Task

# Result fields that reach the record unchanged (the rest, e.g. the output bytes, stay with the driver).
_RESULT_FIELDS = (
    "bytes",
    "points",
    "chamfer",
    "draco_bytes",
    "decimate_draco_bytes",
    "unseen_area_share",
    "seconds",
    "error",
    "attempts",
)
# Measured fields a skipped file's record keeps from its last run.
_KEPT_FIELDS = ("bytes", "points", "chamfer", "draco_bytes", "decimate_draco_bytes", "unseen_area_share")
# Files the batch summary names when their decoded area no outside view sees is above the warning's share.
UNSEEN_NAMES = 5


@dataclass
class Counts:
    """Files done so far: ok, failed, skipped out of total, since `started` (time.monotonic())."""

    total: int
    ok: int = 0
    failed: int = 0
    skipped: int = 0
    started: float = field(default_factory=time.monotonic)

    @property
    def done(self) -> int:
        return self.ok + self.failed + self.skipped

    def files_per_hour(self) -> float:
        """Files run (skipped ones excluded) per hour of wall time so far."""
        elapsed = time.monotonic() - self.started
        return 3600.0 * (self.ok + self.failed) / elapsed if elapsed > 0 else 0.0

    def eta_seconds(self) -> float | None:
        """Time left at the rate so far; None before the first file has run."""
        rate = self.files_per_hour()
        return 3600.0 * (self.total - self.done) / rate if rate > 0 else None


ProgressFn = Callable[[dict, Counts], None]


def make_tasks(inputs: Sequence[Path], outputs: Sequence[Path], out_dir: Path, options: dict) -> list[Task]:
    """One task per input with its output and manifest key (the output's path relative to `out_dir`)."""
    return [
        Task(str(src), str(out), Path(os.path.relpath(out, out_dir)).as_posix(), dict(options))
        for src, out in zip(inputs, outputs, strict=True)
    ]


def run_batch(
    tasks: Sequence[Task],
    worker: Callable[[Task], dict],
    executor,
    *,
    manifest: Manifest | None = None,
    force: bool = False,
    carry_data: bool = False,
    progress: ProgressFn | None = None,
) -> list[dict]:
    """Run `worker` on every task through `executor`, write each output atomically and record every file.

    manifest: where records go and what a re-run may skip (None: record nothing, skip nothing). force: run even
    what the manifest says is done. carry_data: send the input's bytes with the task (executors whose workers may
    not see this machine's files). progress(record, counts) is called after every file. Returns the records in
    the order files finished. A failing file never stops the batch.
    """
    from tetweave_codec.meshio import write_bytes_atomic

    counts = Counts(len(tasks))
    records: list[dict] = []
    facts: dict[str, dict] = {}  # key -> input path, size and hash of the tasks sent to the executor

    def emit(record: dict) -> None:
        setattr(counts, record["status"], getattr(counts, record["status"]) + 1)
        records.append(record)
        if manifest is not None:
            manifest.append(record)
        if progress is not None:
            progress(record, counts)

    def to_run() -> Iterator[Task]:
        for task in tasks:
            base = {"input": task.input, "output": task.key, "options": canonical(task.options)}
            try:
                data = Path(task.input).read_bytes() if carry_data else None
                size = os.path.getsize(task.input)
                sha = file_sha256(Path(task.input)) if data is None else hashlib.sha256(data).hexdigest()
            except OSError as exc:  # missing or unreadable: that file's failed record, the batch goes on
                emit(new_record(**base, status=FAILED, error=error_line(exc), attempts=0))
                continue
            base.update(sha256=sha, input_bytes=size)
            output = Path(task.output)
            before = None if force or manifest is None else manifest.done_before(task.key, sha, task.options, output)
            if before is not None:
                kept = {k: before.get(k) for k in _KEPT_FIELDS}
                emit(new_record(**base, **kept, status=SKIPPED, seconds=0.0, attempts=0))
                continue
            facts[task.key] = base
            yield Task(task.input, task.output, task.key, task.options, data)

    try:
        for task, result in executor.run(worker, to_run()):
            record = new_record(**facts.pop(task.key), attempts=1)
            record.update({k: result[k] for k in _RESULT_FIELDS if k in result})
            status = result.get("status", FAILED)
            if status == OK:
                try:
                    Path(task.output).parent.mkdir(parents=True, exist_ok=True)
                    write_bytes_atomic(task.output, result["data"])
                except OSError as exc:
                    status, record["error"] = FAILED, error_line(exc)
            record["status"] = status
            emit(record)
    finally:
        executor.close()
    return records


def _size(n: float) -> str:
    for unit in ("bytes", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:,.0f} {unit}" if unit == "bytes" else f"{n:,.1f} {unit}"
        n /= 1024
    raise AssertionError("unreachable")


def summary_lines(records: Sequence[dict], seconds: float) -> list[str]:
    """The end-of-batch summary: files by status, bytes in -> out and ratio (ok and skipped files), median
    Chamfer distance, time and files per hour, and a warning naming the files whose self-check warns."""
    by = {s: [r for r in records if r["status"] == s] for s in (OK, SKIPPED, FAILED)}
    done = by[OK] + by[SKIPPED]
    lines = [
        f"{len(records)} files: {len(by[OK])} ok, {len(by[SKIPPED])} skipped, {len(by[FAILED])} failed "
        f"in {seconds:.1f}s ({3600.0 * (len(by[OK]) + len(by[FAILED])) / max(seconds, 1e-9):.0f} files per hour)"
    ]
    size_in = sum(r.get("input_bytes") or 0 for r in done)
    size_out = sum(r.get("bytes") or 0 for r in done)
    if size_out and size_in:
        ratio = f"{size_in / size_out:.1f}x smaller" if size_in >= size_out else f"{size_out / size_in:.1f}x larger"
        lines.append(f"bytes in {_size(size_in)} -> out {_size(size_out)} ({ratio})")
    chamfers = [r["chamfer"] for r in done if isinstance(r.get("chamfer"), (int, float))]
    if chamfers:
        lines.append(f"median Chamfer distance {statistics.median(chamfers):.3g} over {len(chamfers)} files")
    unseen = [r for r in done if isinstance(r.get("unseen_area_share"), (int, float))]
    if unseen:  # encode batches only: a decode imports no metrics (scipy)
        lines += _unseen_lines(unseen)
    return lines


def _unseen_lines(records: Sequence[dict]) -> list[str]:
    """A warning naming the files whose decoded area no outside view sees is above metrics.unseen.WARN_SHARE
    (the encode summary's self-check), [] when none."""
    from tetweave_codec.metrics.unseen import WARN_SHARE

    flagged = sorted(r["output"] for r in records if r["unseen_area_share"] > WARN_SHARE)
    if not flagged:
        return []
    names = ", ".join(flagged[:UNSEEN_NAMES]) + (", ..." if len(flagged) > UNSEEN_NAMES else "")
    return [
        f"warning: {len(flagged)} of {len(records)} files keep over {100 * WARN_SHARE:.0f} % of their decoded area "
        f"where no outside view sees it (unseen_area_share in the manifest; try --surface visible): {names}"
    ]
