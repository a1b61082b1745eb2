"""Where many independent jobs run: this process, an embedded Dask cluster, or a real one.

:func:`open_pool` gives a :class:`Pool` for one of three places:

- ``workers=1``: plain in-process, one job after the other (no Dask at all);
- no ``scheduler``: an embedded ``distributed.LocalCluster`` of worker *processes* on
  127.0.0.1, ``workers`` of them (default: one per CPU this process may use), one thread
  each (the numba kernels are single-threaded per recording), closed on exit;
- ``scheduler="tcp://HOST:PORT"``: an existing cluster started with ``dask scheduler``
  and ``dask worker tcp://HOST:PORT``; the workers must see the same files at the same
  paths (a shared file system) and have margtrack installed.

:meth:`Pool.map` yields each job's result or error as it finishes. Jobs are submitted with
``retries``: a job that raised is run again, and a job whose worker died (``kill -9``,
out of memory) is rescheduled on another worker by the scheduler itself.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["Pool", "default_workers", "mapper_of", "open_pool"]

#: how long to wait for an existing scheduler to answer, s
CONNECT_TIMEOUT_S = 10.0


def default_workers() -> int:
    """One worker per CPU this process may run on (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


@dataclass
class Pool:
    """A place to run jobs: ``client`` is a ``distributed.Client`` or None (in-process).

    description : one line for people ("in-process", "local Dask cluster, 2 workers",
        "Dask scheduler tcp://127.0.0.1:8786, 2 workers").
    """

    client: Any
    description: str

    @property
    def n_workers(self) -> int:
        """Workers that take jobs (1 in-process)."""
        if self.client is None:
            return 1
        return max(1, len(self.client.scheduler_info().get("workers", {})))

    def map(
        self,
        job: Callable[..., Any],
        items: Sequence[Any],
        shared: Any = None,
        *,
        retries: int = 2,
        key_prefix: str = "margtrack",
    ) -> Iterator[tuple[int, Any, BaseException | None]]:
        """Run ``job(shared, item)`` for each item; yield ``(index, result, error)`` as done.

        ``error`` is None for a job that returned; otherwise the exception it raised (after
        ``retries`` further attempts) or the cluster's (``KilledWorker`` when the workers
        running it kept dying). ``shared`` is sent to the workers once, not per job.
        """
        if self.client is None:
            for i, item in enumerate(items):
                try:
                    yield i, job(shared, item), None
                except Exception as exc:  # reported to the caller per job
                    yield i, None, exc
            return
        from distributed import as_completed

        shared_ref = shared
        if shared is not None:
            # one future for the whole object, copied to every worker once
            shared_ref = self.client.scatter([shared], broadcast=True, hash=False)[0]
        index = {}
        futures = []
        for i, item in enumerate(items):
            fut = self.client.submit(
                job, shared_ref, item, retries=retries, pure=False, key=f"{key_prefix}-{i}-"
                + os.urandom(4).hex(),
            )
            index[fut.key] = i
            futures.append(fut)
        try:
            for fut in as_completed(futures):
                i = index[fut.key]
                try:
                    yield i, fut.result(), None
                except Exception as exc:  # a failed job is one row, not the end
                    yield i, None, exc
                fut.release()
        finally:
            for fut in futures:
                fut.cancel()


@contextlib.contextmanager
def open_pool(workers: int | None = None, scheduler: str | None = None) -> Iterator[Pool]:
    """The :class:`Pool` for ``workers`` / ``scheduler`` (see the module), closed on exit.

    Raises ``ValueError`` for ``workers < 1``, for ``workers`` given with ``scheduler``
    (an existing cluster has the workers it was started with), and when the scheduler
    does not answer within :data:`CONNECT_TIMEOUT_S`.
    """
    if workers is not None and workers < 1:
        raise ValueError(f"--workers must be 1 or more, got {workers}")
    if scheduler is not None:
        if workers is not None:
            raise ValueError(
                "--workers applies to the embedded cluster only; an existing scheduler uses "
                "the workers started for it (dask worker ADDRESS --nworkers N)"
            )
        yield from _connected(scheduler)
        return
    n = default_workers() if workers is None else workers
    if n == 1:
        yield Pool(None, "in-process")
        return
    from distributed import Client, LocalCluster

    with (
        LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
            silence_logs=logging.ERROR,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield Pool(client, f"local Dask cluster, {n} worker processes")


def _connected(address: str) -> Iterator[Pool]:
    from distributed import Client

    if "://" not in address:
        raise ValueError(
            f"--scheduler takes an address like tcp://127.0.0.1:8786, got {address!r}"
        )
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise ValueError(
            f"cannot reach the Dask scheduler at {address} within {CONNECT_TIMEOUT_S:g} s "
            f"({exc}); start one with `dask scheduler` and workers with `dask worker "
            f"{address}`, or drop --scheduler to use a local cluster"
        ) from None
    with client:
        try:
            client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError):
            raise ValueError(
                f"the Dask scheduler at {address} has no worker after {CONNECT_TIMEOUT_S:g} s; "
                f"start some with `dask worker {address}`"
            ) from None
        n = len(client.scheduler_info().get("workers", {}))
        yield Pool(client, f"Dask scheduler {address}, {n} workers")


def mapper_of(pool: Pool) -> Callable[..., Iterator[tuple[int, Any]]]:
    """``pool`` as a :data:`margtrack.bench.tune.Mapper`: results in, errors raised."""

    def mapper(
        job: Callable[..., Any], items: Sequence[Any], shared: Any
    ) -> Iterator[tuple[int, Any]]:
        for i, result, error in pool.map(job, items, shared, key_prefix="margtrack-tune"):
            if error is not None:
                raise error
            yield i, result

    return mapper
