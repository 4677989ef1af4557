"""Where many independent evaluations run: local processes or a Dask cluster.

    ex = executor_for(jobs=4)                       # forked local processes
    ex = executor_for(scheduler="tcp://lab1:8786")  # a Dask distributed cluster
    for i, value in ex.map(fn, items, shared=model):
        results[i] = value                          # as they complete, keyed by index

``fn(shared, item)`` must be a module-level function (or a picklable callable).
``shared`` (the model, the data) travels once per worker, not once per task:
local workers are forked after it is set (they inherit it), and on a cluster it
is scattered to every worker once (``broadcast=True``, keyed by its content
hash) and each task refers to it. A task whose worker dies is run again
(``retries``); results are keyed by the item's index, so none is lost or
reported twice.

The scheduler address comes from ``--scheduler``, else the environment variable
``RIG_SCHEDULER``; with neither, local processes are used.
"""

from __future__ import annotations

import hashlib
import multiprocessing as mp
import os
import signal
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

from rig.errors import InputError

SCHEDULER_ENV = "RIG_SCHEDULER"

# shared objects of the running maps, set before the fork so local workers inherit them
_SHARED: dict[str, Any] = {}


def _ignore_sigint() -> None:
    """Local workers leave Ctrl-C to the parent, which stops the map and the pool."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _local_call(key: str, fn: Callable[[Any, Any], Any], item: Any) -> Any:
    return fn(_SHARED[key], item)


def _dask_call(fn: Callable[[Any, Any], Any], shared: Any, item: Any) -> Any:
    return fn(shared, item)


class Executor:
    """Runs ``fn(shared, item)`` for every item; yields ``(index, result)`` as they finish."""

    name = "executor"

    @property
    def workers(self) -> int:
        """How many tasks run at once."""
        return 1

    def map(self, fn: Callable[[Any, Any], Any], items: Sequence[Any], *,
            shared: Any = None) -> Iterator[tuple[int, Any]]:
        raise NotImplementedError

    def close(self) -> None:
        """Release the workers (local processes; a cluster's shared data and client)."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def describe(self) -> str:
        return self.name


class LocalExecutor(Executor):
    """Forked local processes (``jobs`` of them; 1: in this process, in order).

    The workers are forked when a map's ``shared`` is set and inherit it; later maps
    with the same ``shared`` object (a fit's Jacobian columns) reuse them until
    ``close``; a map with another ``shared`` forks fresh workers."""

    def __init__(self, jobs: int | None = None) -> None:
        self._workers = max(1, jobs if jobs is not None else (os.cpu_count() or 1))
        self.name = f"{self._workers} local process{'es' if self._workers > 1 else ''}"
        self._pool: ProcessPoolExecutor | None = None
        self._key = ""
        self._shared: Any = None

    @property
    def workers(self) -> int:
        return self._workers

    def _pool_for(self, shared: Any, n: int) -> tuple[ProcessPoolExecutor, str]:
        if self._pool is not None and self._shared is shared:
            return self._pool, self._key
        self.close()
        self._key = uuid.uuid4().hex
        self._shared = shared
        _SHARED[self._key] = shared
        self._pool = ProcessPoolExecutor(max_workers=min(self._workers, n),
                                         mp_context=mp.get_context("fork"),
                                         initializer=_ignore_sigint)
        return self._pool, self._key

    def map(self, fn: Callable[[Any, Any], Any], items: Sequence[Any], *,
            shared: Any = None) -> Iterator[tuple[int, Any]]:
        items = list(items)
        if self._workers <= 1 or len(items) <= 1:
            for i, item in enumerate(items):
                yield i, fn(shared, item)
            return
        pool, key = self._pool_for(shared, len(items))
        futs = {pool.submit(_local_call, key, fn, item): i for i, item in enumerate(items)}
        ok = False
        try:
            for f in as_completed(futs):
                yield futs[f], f.result()
            ok = True
        finally:
            if not ok:  # interrupted or failed: drop the queued tasks and the workers
                for f in futs:
                    f.cancel()
                self.close()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None
        _SHARED.pop(self._key, None)
        self._shared = None


class DaskExecutor(Executor):
    """Tasks on a Dask distributed cluster at ``address`` (or on a given client)."""

    def __init__(self, address: str | None = None, *, client: Any = None,
                 retries: int = 3) -> None:
        from distributed import Client

        if client is None:
            if not address:
                raise InputError("scheduler: expected an address such as tcp://host:8786")
            try:
                client = Client(address, timeout="10s")
            except OSError as exc:
                raise InputError(f"scheduler: cannot reach {address}: {exc}") from None
            self._own = True
        else:
            self._own = False
        self.client = client
        self.retries = retries
        self._scattered: dict[str, Any] = {}
        self.address = client.scheduler.address
        self.name = f"Dask cluster at {self.address}"

    def _scatter(self, shared: Any) -> Any:
        """``shared`` on every worker once, keyed by its content hash: later maps with the
        same content (a fit's Jacobian columns) reuse the copy the workers hold. Kept
        until ``close`` (releasing and re-scattering one key races in the scheduler)."""
        import cloudpickle

        digest = hashlib.sha256(cloudpickle.dumps(shared)).hexdigest()
        fut = self._scattered.get(digest)
        if fut is None:
            fut = self.client.scatter([shared], broadcast=True, hash=False)[0]
            self._scattered[digest] = fut
        return fut

    @property
    def workers(self) -> int:
        return max(1, sum(w.get("nthreads", 1) for w in
                          self.client.scheduler_info()["workers"].values()))

    def map(self, fn: Callable[[Any, Any], Any], items: Sequence[Any], *,
            shared: Any = None) -> Iterator[tuple[int, Any]]:
        from distributed import as_completed as dask_completed

        items = list(items)
        shared_f = self._scatter(shared)
        run = uuid.uuid4().hex[:12]
        futs = {}
        for i, item in enumerate(items):
            f = self.client.submit(_dask_call, fn, shared_f, item, key=f"rig-{run}-{i}",
                                   retries=self.retries, pure=False)
            futs[f.key] = (i, f)
        seen: set[int] = set()
        try:
            for f in dask_completed([f for _, f in futs.values()]):
                i = futs[f.key][0]
                if i in seen:  # pragma: no cover - as_completed yields each future once
                    continue
                seen.add(i)
                value = f.result()
                f.release()
                yield i, value
        finally:
            for _, f in futs.values():
                if not f.done():
                    f.cancel()

    def close(self) -> None:
        for fut in self._scattered.values():
            fut.release()
        self._scattered.clear()
        if self._own:
            self.client.close()


def executor_for(jobs: int | None = None, scheduler: str | None = None) -> Executor:
    """A Dask executor when a scheduler is given (or in ``RIG_SCHEDULER``), else local."""
    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    if address:
        return DaskExecutor(address)
    return LocalExecutor(jobs)


def run_all(ex: Executor, fn: Callable[[Any, Any], Any], items: Iterable[Any], *,
            shared: Any = None) -> list[Any]:
    """Every result, in the items' order."""
    items = list(items)
    out: list[Any] = [None] * len(items)
    for i, v in ex.map(fn, items, shared=shared):
        out[i] = v
    return out
