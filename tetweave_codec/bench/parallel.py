"""The tetweave encodes of `tetweave bench --jobs / --ray`: every fit of every mesh at once through
`tetweave_codec.runner` (local processes or Ray), then handed to the batch as methods whose bytes are ready."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from tetweave_codec.bench.methods import Method


class Precomputed(Method):
    """A method whose encodes already ran (in parallel through tetweave_codec.runner, see `precompute`): `encode`
    returns the bytes made for this mesh, found by the mesh's content (`runner.work.mesh_sha256`); labels,
    decoding and info are the wrapped method's. The worker's encode time counts as reused seconds (the look-up
    itself takes milliseconds), so the row states the encode's whole cost."""

    def __init__(self, method: Method, results: dict[str, dict]) -> None:
        self.method = method
        self.family = method.family
        self.results = results
        self._worker_seconds = 0.0

    @property
    def setting(self) -> str:
        return self.method.setting

    @property
    def curve(self) -> str:
        return self.method.curve

    def params(self) -> dict:
        return self.method.params()

    def encode(self, vertices: np.ndarray, faces: np.ndarray) -> bytes:
        from tetweave_codec.errors import TetweaveError
        from tetweave_codec.runner.work import mesh_sha256

        self._worker_seconds = 0.0
        result = self.results.get(mesh_sha256(vertices, faces))
        if result is None:
            raise TetweaveError("this mesh was not encoded by the runner")
        if result["status"] != "ok":
            raise TetweaveError(result.get("error") or "failed in its worker")
        self._worker_seconds = float(result["seconds"])
        self.method.points_used = result.get("points_target", "")
        return result["data"]

    def decode(self, data: bytes) -> tuple[np.ndarray, np.ndarray]:
        return self.method.decode(data)

    def info(self, data: bytes) -> dict:
        return self.method.info(data)

    def reused_seconds(self) -> float:
        return self._worker_seconds + self.method.reused_seconds()


def precompute(paths: Sequence[Path], methods: Sequence[Method], executor, threads: int, progress=None) -> list:
    """Run every tetweave method's encode of every mesh through `executor` (local processes or Ray) at once, and
    return `methods` with each tetweave method wrapped in `Precomputed`; other methods are returned unchanged.
    Workers use `threads` torch threads; fits use the methods' own options and seeds, so the bytes are those of
    the in-process run at the same thread count."""
    from tetweave_codec.bench.methods import TetweaveMethod
    from tetweave_codec.runner.work import EncodeOptions, Task, encode_file

    say = progress or (lambda _msg: None)
    fits = [m for m in methods if isinstance(m, TetweaveMethod)]
    tasks = []
    for path in paths:
        for k, m in enumerate(fits):
            options = EncodeOptions(
                points=m.points,
                sh_degree="auto" if m.sh_degree is None else str(m.sh_degree),
                layout=m.layout,
                holes=m.holes,
                surface=m.surface,
                quality=m.quality,
                iters=m.iters,
                size=m.size,
                device=str(m.device),
                seed=m.seed,
                threads=threads,
                measure=False,  # the benchmark measures the decoded mesh itself
            )
            tasks.append(Task(str(path), "", f"{k}", options.as_dict(), None))
    results: list[dict[str, dict]] = [{} for _ in fits]
    try:
        for done, (task, result) in enumerate(executor.run(encode_file, tasks), 1):
            if "mesh_sha256" in result:
                results[int(task.key)][result["mesh_sha256"]] = result
            outcome = f"{result['bytes']:,} bytes" if result["status"] == "ok" else f"FAILED: {result['error']}"
            say(f"tetweave encodes {done}/{len(tasks)}: {Path(task.input).name} {fits[int(task.key)].name}: {outcome}")
    finally:
        executor.close()
    wrapped = {id(m): Precomputed(m, results[k]) for k, m in enumerate(fits)}
    return [wrapped.get(id(m), m) for m in methods]
