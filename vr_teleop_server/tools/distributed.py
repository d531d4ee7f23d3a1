"""Work items to results, in this process or on a Dask cluster: the one place that knows about Dask.

`Workers()` (the default, `--workers 1`) runs the items one after another in this process, as the tools always
have. `Workers(count=K)` starts a local Dask cluster of K single-threaded worker processes for the batch;
`Workers(scheduler="tcp://HOST:8786")` sends the items to a running cluster whose workers have this package
installed (the same version: checked on every worker before anything is submitted).

Each item is one task, under a key of its own (`name(item)` and a token for the batch), so each result is taken
once. A task lost with its worker (killed, out of memory, its machine gone) is run again on another one by the
scheduler, up to its `distributed.scheduler.allowed-failures` (3 by default; a local cluster's is set here); a
task that raises is not retried (a trial is deterministic for its seed: it would raise again) and its error is
raised here.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.metadata
import logging
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from tqdm import tqdm

T = TypeVar("T")
R = TypeVar("R")

PACKAGE = "vr-teleop-server"
ALLOWED_FAILURES = 3  # a local cluster's task is rerun after this many of its workers died running it


class WorkersError(RuntimeError):
    """A scheduler that cannot be reached, workers that cannot run the work, or a task lost too often."""


@dataclass(frozen=True)
class Workers:
    """Where work runs: `count` local processes (1: this process, no Dask), or an existing Dask scheduler."""
    count: int = 1
    scheduler: str | None = None
    connect_timeout_s: float = 10.0

    @property
    def in_process(self) -> bool:
        return self.count == 1 and self.scheduler is None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Workers:
        return cls(count=args.workers, scheduler=args.scheduler)

    def describe(self) -> str:
        if self.scheduler is not None:
            return f"the Dask scheduler at {self.scheduler}"
        return "this process" if self.in_process else f"a local Dask cluster of {self.count} worker processes"


def add_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """--workers K | --scheduler ADDRESS, for the commands that run batches."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=positive, default=1, metavar="K",
                       help=f"run the {what} on a local Dask cluster of K processes (default 1: one after another "
                            "in this process, no Dask)")
    where.add_argument("--scheduler", default=None, metavar="tcp://HOST:8786",
                       help=f"send the {what} to a running Dask cluster, whose workers have this package installed "
                            "(the same version)")


def positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: at least one")
    return value


def package_version() -> str:
    """This package's version where it runs (sent to every worker as the import check)."""
    try:
        return importlib.metadata.version(PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        return "unknown (not installed)"


def run_all(fn: Callable[[T], R], items: Sequence[T], workers: Workers, *, name: Callable[[T], str],
            progress: bool = True, unit: str = "item") -> Iterator[tuple[T, R]]:
    """Yields (item, fn(item)) for every item once, as each finishes (in order in this process). `fn` and the
    items must pickle (a module-level function, plain data) when `workers` is a cluster."""
    with tqdm(total=len(items), unit=unit, disable=not progress, file=sys.stderr, dynamic_ncols=True) as bar:
        for item, result in (_in_process(fn, items) if workers.in_process else
                             _on_dask(fn, items, workers, name)):
            bar.set_postfix_str(name(item), refresh=False)
            bar.update()
            yield item, result


def _in_process(fn: Callable[[T], R], items: Sequence[T]) -> Iterator[tuple[T, R]]:
    for item in items:
        yield item, fn(item)


def _on_dask(fn: Callable[[T], R], items: Sequence[T], workers: Workers,
             name: Callable[[T], str]) -> Iterator[tuple[T, R]]:
    from distributed import as_completed

    with _client(workers) as client:
        check_workers(client)
        batch = uuid.uuid4().hex[:8]
        futures = {client.submit(fn, item, key=f"{name(item)}-{batch}", pure=False): item for item in items}
        for future in as_completed(futures):
            item = futures[future]
            if future.status == "error" and _lost(future):
                raise WorkersError(f"{name(item)} was lost with its worker too many times: {future.exception()}")
            yield item, future.result()  # a task's own error is raised here, as in this process


def _lost(future: Any) -> bool:
    from distributed.scheduler import KilledWorker

    return isinstance(future.exception(), KilledWorker)


@contextlib.contextmanager
def _client(workers: Workers) -> Iterator[Any]:
    import dask
    from distributed import Client, LocalCluster

    if workers.scheduler is None:
        with dask.config.set({"distributed.scheduler.allowed-failures": ALLOWED_FAILURES}), \
                LocalCluster(n_workers=workers.count, threads_per_worker=1, processes=True, dashboard_address=None,
                             silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
            yield client
        return
    try:
        client = Client(workers.scheduler, timeout=workers.connect_timeout_s)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise WorkersError(f"cannot reach the Dask scheduler at {workers.scheduler}: {exc}") from None
    with client:
        try:
            client.wait_for_workers(1, timeout=workers.connect_timeout_s)
        except TimeoutError:
            raise WorkersError(f"the Dask scheduler at {workers.scheduler} has no workers (none joined within "
                               f"{workers.connect_timeout_s:g} s)") from None
        yield client


def check_workers(client: Any) -> None:
    """Every worker imports this package, at the client's version: otherwise a clear error naming the worker.
    The check is a function of this package, so a worker without it fails to unpickle it."""
    want = package_version()
    answers = client.run(package_version, on_error="return")
    problems = []
    for address, answer in sorted(answers.items()):
        if isinstance(answer, BaseException):
            problems.append(f"worker {address} cannot import {PACKAGE} ({answer}); "
                            f"install it there: pip install {PACKAGE}=={want}")
        elif answer != want:
            problems.append(f"worker {address} has {PACKAGE} {answer}, this client {want}: install the same version")
    if problems:
        raise WorkersError("; ".join(problems))
