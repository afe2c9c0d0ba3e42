"""Worker functions for tests/test_batch.py that the runner's spawned processes import by name (a test module's
functions would pull pytest into every worker). Each takes a runner Task whose options name a scratch folder."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path


def echo(task) -> dict:
    """Returns the input's bytes after options["sleep"] seconds."""
    time.sleep(task.options.get("sleep", 0.0))
    return {"status": "ok", "data": Path(task.input).read_bytes(), "bytes": os.path.getsize(task.input)}


def die_once(task) -> dict:
    """Kills its own process (SIGKILL, as the OOM killer does) the first time it sees a task whose input name
    is in options["die_once"], every time for options["die_always"]; otherwise behaves like `echo`."""
    name = Path(task.input).name
    marker = Path(task.options["scratch"]) / f"{name}.died"
    if name in task.options.get("die_always", ()) or (name in task.options.get("die_once", ()) and not marker.exists()):
        marker.touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return echo(task)
