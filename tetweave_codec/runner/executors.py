"""Where a batch's tasks run: local worker processes or a Ray cluster, behind one interface.

An executor's ``run(worker, tasks)`` yields ``(task, result)`` as tasks finish (any order), where ``worker`` is a
module-level function Task -> result dict (see `runner.work`) that never raises for a bad input. A worker
process that dies (killed, out of memory) is retried once; a second death gives a failed result with
``attempts = 2``. ``close()`` releases the workers (also on Ctrl-C).
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from tetweave_codec.errors import InputError, error_line
from tetweave_codec.runner.work import Task

Worker = Callable[[Task], dict]
# How often the driver looks for finished tasks when none has finished (seconds).
_POLL_S = 1.0
# A file whose worker died is run once more; the second death is final.
MAX_ATTEMPTS = 2
RAY_MISSING = '--ray needs the optional Ray dependency: pip install "tetweave[ray]"'


def require_ray() -> None:
    """InputError (one line, exit 2) unless the optional ray package can be imported."""
    try:
        import ray  # noqa: F401
    except ImportError:
        raise InputError(RAY_MISSING) from None


def available_cores() -> int:
    """CPU cores this process may use (the affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)


def default_jobs(threads: int) -> int:
    """--jobs' default: cores / --threads, at least 1."""
    return max(1, available_cores() // max(1, threads))


def worker_died(attempts: int, detail: str = "") -> dict:
    """The result of a file whose worker process died on its last attempt."""
    reason = f" ({detail})" if detail else ""
    return {
        "status": "failed",
        "error": f"the worker process died {attempts} times (killed or out of memory){reason}",
        "attempts": attempts,
    }


class LocalExecutor:
    """`jobs` worker processes on this machine (a spawn-context process pool: torch and fork do not mix).

    At most `jobs` tasks are submitted at once, so every submitted task is running: when a worker dies the pool
    breaks (and stops its other workers), and every task in flight is a suspect; the rest go on in a new pool.
    Each suspect is run again after the others, alone in a pool of its own, so a second death is its own and an
    innocent bystander of the first death simply finishes there.
    """

    def __init__(self, jobs: int) -> None:
        import multiprocessing

        self.jobs = max(1, int(jobs))
        self._context = multiprocessing.get_context("spawn")
        self._pools: list[ProcessPoolExecutor] = []

    def _pool(self, workers: int) -> ProcessPoolExecutor:
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=self._context)
        self._pools.append(pool)
        return pool

    def run(self, worker: Worker, tasks: Iterable[Task]) -> Iterator[tuple[Task, dict]]:
        suspects: list[Task] = []
        yield from self._run_pool(worker, _Feed(tasks), self.jobs, suspects)
        for task in suspects:  # alone, one at a time: a death now is this task's
            died: list[Task] = []
            for done, result in self._run_pool(worker, _Feed([task]), 1, died):
                yield done, {**result, "attempts": MAX_ATTEMPTS}
            for dead in died:
                yield dead, worker_died(MAX_ATTEMPTS)

    def _run_pool(self, worker: Worker, feed: _Feed, workers: int, died: list[Task]) -> Iterator[tuple[Task, dict]]:
        """Run the tasks of `feed` on a pool of `workers`, a new pool after each break; tasks in flight at a
        break go to `died`. Tasks are taken from `feed` only when a worker is free."""
        pool = self._pool(workers)
        in_flight: dict[Future, Task] = {}
        broken = False
        finished = False
        try:
            while not feed.empty() or in_flight:
                if broken and not in_flight:
                    self._discard(pool, kill=True)
                    pool, broken = self._pool(workers), False
                while not broken and len(in_flight) < workers and (task := feed.next()) is not None:
                    try:
                        in_flight[pool.submit(worker, task)] = task
                    except BrokenProcessPool:
                        feed.push(task)
                        broken = True
                if not in_flight:
                    continue
                done, _ = wait(in_flight, timeout=_POLL_S, return_when=FIRST_COMPLETED)
                for future in done:
                    task = in_flight.pop(future)
                    try:
                        result = future.result()
                    except BrokenProcessPool:
                        broken = True
                        died.append(task)
                        continue
                    except Exception as exc:  # e.g. a result that cannot be pickled: a bug, recorded
                        result = {"status": "failed", "error": error_line(exc)}
                    yield task, result
            finished = True
        finally:
            self._discard(pool, kill=not finished)

    def _discard(self, pool: ProcessPoolExecutor, kill: bool) -> None:
        """Shut a pool down. With `kill` (Ctrl-C, an early stop, a broken pool) workers still fitting are
        terminated rather than left to finish files nobody will record."""
        if kill:
            processes = list(getattr(pool, "_processes", None) or {})  # pids; private, so looked up defensively
            pool.shutdown(wait=False, cancel_futures=True)
            for pid in processes:
                try:
                    os.kill(pid, signal.SIGTERM)
                except OSError:
                    pass
        else:
            pool.shutdown(wait=True)
        if pool in self._pools:
            self._pools.remove(pool)

    def close(self) -> None:
        for pool in list(self._pools):
            self._discard(pool, kill=True)


class _Feed:
    """Tasks taken one at a time from an iterable (so that the driver can hash and skip files lazily), with
    room to put one back."""

    def __init__(self, tasks: Iterable[Task]) -> None:
        self._it = iter(tasks)
        self._back: list[Task] = []
        self._done = False

    def next(self) -> Task | None:
        if self._back:
            return self._back.pop()
        task = None if self._done else next(self._it, None)
        self._done = task is None
        return task

    def push(self, task: Task) -> None:
        self._back.append(task)

    def empty(self) -> bool:
        """True once the iterable is exhausted and nothing was put back."""
        if self._back:
            return False
        if not self._done:
            task = self.next()
            if task is not None:
                self._back.append(task)
        return self._done and not self._back


class RayExecutor:
    """One Ray task per file on the cluster at `address` ("auto": an existing cluster; None: a local Ray started
    for this run with `local_cpus` CPUs). Each task asks for `threads` CPUs and, with `gpus`, that many GPUs.
    Ray retries a task whose worker or node died once (max_retries=1). At most `in_flight` tasks are submitted
    at a time (default: twice the cluster's CPUs / threads), so memory stays bounded for 100,000 files.
    """

    def __init__(
        self,
        address: str | None,
        *,
        threads: int = 1,
        gpus: float = 0.0,
        local_cpus: int | None = None,
        in_flight: int | None = None,
    ) -> None:
        try:
            import ray
        except ImportError:
            raise InputError(RAY_MISSING) from None
        import logging

        self._ray = ray
        self._started = not ray.is_initialized()
        if self._started:
            kwargs = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
            try:
                if address:
                    ray.init(address=address, **kwargs)
                else:
                    ray.init(num_cpus=local_cpus or available_cores(), **kwargs)
            except Exception as exc:  # no cluster at that address, a version mismatch, ...
                where = f"the Ray cluster at {address}" if address else "a local Ray"
                raise InputError(f"cannot start or reach {where}: {' '.join(str(exc).split())[:300]}") from None
        self.threads = max(1, int(threads))
        self.gpus = gpus
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.in_flight = in_flight or max(1, 2 * cpus // self.threads)

    def run(self, worker: Worker, tasks: Iterable[Task]) -> Iterator[tuple[Task, dict]]:
        ray = self._ray
        remote = ray.remote(num_cpus=self.threads, num_gpus=self.gpus, max_retries=MAX_ATTEMPTS - 1)(worker)
        feed = _Feed(tasks)
        refs: dict = {}
        try:
            while not feed.empty() or refs:
                while len(refs) < self.in_flight and (task := feed.next()) is not None:
                    refs[remote.remote(task)] = task
                if not refs:
                    continue
                done, _ = ray.wait(list(refs), num_returns=1, timeout=_POLL_S)
                for ref in done:
                    task = refs.pop(ref)
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayTaskError as exc:  # raised inside the worker: a bug, recorded
                        cause = exc.cause if isinstance(exc.cause, BaseException) else exc
                        result = {"status": "failed", "error": error_line(cause)}
                    except ray.exceptions.RayError as exc:  # the worker or its node died on both attempts
                        detail = " ".join(str(exc).split())[:200]
                        result = worker_died(MAX_ATTEMPTS, f"{type(exc).__name__}: {detail}")
                    yield task, result
        finally:
            for ref in refs:
                ray.cancel(ref, force=True)

    def close(self) -> None:
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()


def make_executor(jobs: int, ray_address: str | None, use_ray: bool, threads: int, gpus: float = 0.0):
    """LocalExecutor(jobs), or a RayExecutor when `use_ray` (address None: a local Ray with jobs * threads CPUs)."""
    if use_ray:
        return RayExecutor(ray_address, threads=threads, gpus=gpus, local_cpus=jobs * max(1, threads))
    return LocalExecutor(jobs)
