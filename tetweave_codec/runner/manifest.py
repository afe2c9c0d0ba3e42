"""The batch manifest: ``DIR/manifest.jsonl``, one JSON record per input and run, appended as each file finishes.

A record (see `RECORD_FIELDS`): ``input`` (path), ``output`` (path relative to DIR: the key that identifies an
input across runs), ``sha256`` of the input's bytes, ``options`` (everything that decides the output bytes),
``status`` (``ok`` / ``failed`` / ``skipped``), ``input_bytes``, ``bytes`` (output size), ``points`` (points
stored), ``chamfer`` (decoded mesh to input, normalized frame; null when not measured), ``draco_bytes`` and
``decimate_draco_bytes`` (plain Draco and fast-simplification + Draco of the input at that Chamfer distance, the
encoder summary's context, `classical.classical_context`; null where no setting brackets it),
``unseen_area_share`` (encode: the share in [0, 1] of the decoded mesh's area that no outside view sees, the
summary's self-check, `metrics.unseen`: above 0.01 membranes or hidden parts were kept inside the solid; null when
not measured or for a decode), ``seconds`` (the file's
wall time in its worker), ``error`` (the one-line message when failed), ``attempts`` (0: not run, i.e. skipped
or unreadable; 1; 2 after a local worker died; Ray retries a dead worker itself and reports 1), ``time`` (UTC,
when recorded).

Only the driver writes the manifest, after the output file is in place: a record is appended, flushed and fsynced
per file, so an interrupted run loses at most the files in flight. A torn last line (power loss) is ignored on
reading. A re-run skips an input whose output exists and whose last record is ``ok`` or ``skipped`` with the same
input hash and options.
"""

from __future__ import annotations

import hashlib
import json
import os
from datetime import datetime, timezone
from pathlib import Path

MANIFEST_NAME = "manifest.jsonl"
OK, FAILED, SKIPPED = "ok", "failed", "skipped"
RECORD_FIELDS = (
    "input",
    "output",
    "sha256",
    "options",
    "status",
    "input_bytes",
    "bytes",
    "points",
    "chamfer",
    "draco_bytes",
    "decimate_draco_bytes",
    "unseen_area_share",
    "seconds",
    "error",
    "attempts",
    "time",
)
_HASH_CHUNK = 1 << 20


def file_sha256(path: Path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB chunks (memory stays flat for large scans)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_HASH_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def canonical(options: dict) -> dict:
    """`options` as they read back from JSON (tuples become lists, keys sorted), so that a record's options
    compare equal to the same options given again."""
    return json.loads(json.dumps(options, sort_keys=True))


def new_record(**fields) -> dict:
    """A record with every field of RECORD_FIELDS (missing ones null) and the time."""
    record = dict.fromkeys(RECORD_FIELDS)
    record.update(fields)
    record["time"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return record


def read_last_records(path: Path) -> dict[str, dict]:
    """The last record of every output key in the manifest at `path` ({} when there is none). Lines that are not
    a JSON object with an ``output`` (a torn write) are skipped."""
    last: dict[str, dict] = {}
    try:
        with open(path, encoding="utf-8") as fh:
            for line in fh:
                try:
                    record = json.loads(line)
                except ValueError:
                    continue
                if isinstance(record, dict) and isinstance(record.get("output"), str):
                    last[record["output"]] = record
    except FileNotFoundError:
        pass
    return last


class Manifest:
    """Appends records to ``DIR/manifest.jsonl`` and answers whether an input can be skipped."""

    def __init__(self, directory: Path) -> None:
        self.path = Path(directory) / MANIFEST_NAME
        self.last = read_last_records(self.path)

    def done_before(self, key: str, sha256: str, options: dict, output: Path) -> dict | None:
        """The last record of `key` when the input needs no new run: it was ok (or skipped after being ok) with
        the same input hash and options, and its output is still there; else None."""
        record = self.last.get(key)
        if record is None or record.get("status") not in (OK, SKIPPED):
            return None
        if record.get("sha256") != sha256 or record.get("options") != canonical(options):
            return None
        return record if output.is_file() else None

    def append(self, record: dict) -> None:
        """Append one record durably (flush + fsync); a torn previous line is closed first."""
        line = json.dumps(record, sort_keys=False) + "\n"
        with open(self.path, "a+b") as fh:
            if fh.tell() > 0:
                fh.seek(-1, os.SEEK_END)
                if fh.read(1) != b"\n":
                    line = "\n" + line
            fh.write(line.encode("utf-8"))
            fh.flush()
            os.fsync(fh.fileno())
        self.last[record["output"]] = record
