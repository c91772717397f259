"""Monte-Carlo sweeps run in this process or on ``dask.distributed``, the same results bit for bit
whichever runs them (:func:`run_sweep`; the executors in :func:`resolve_executor`; docs/sweeps.md).
"""

from __future__ import annotations

import os
import pickle
import re
import sys
import threading
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .stage_profile import merge_stage_totals, stage_delta, stage_totals
from .sweep_cache import SweepCache, resolve_sweep_cache

__all__ = ["SCHEDULER_ENV", "SweepExecutor", "SweepTaskError", "resolve_executor", "run_sweep"]

#: The environment variable that picks the executor of every sweep whose ``executor`` is left unset.
SCHEDULER_ENV = "HISTOSTUDY_SCHEDULER"

#: Thread-pool sizes a worker is started with (numpy's BLAS, torch's OpenMP pool, numba).
_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")
_ADDRESS = re.compile(r"^(tcp|tls)://([A-Za-z0-9._-]+|\[[0-9A-Fa-f:]+\]):(\d{1,5})$")
_SPEC_HELP = "'sequential', 'local', 'local:<workers>' or a scheduler address 'tcp://host:port'"


class SweepTaskError(RuntimeError):
    """A sweep task raised, or its workers kept dying (more than ``allowed_failures`` times).

    Args:
        index: the task's position in the sweep's ``tasks`` (kept as ``index``).
        message: what happened to it.
    """

    def __init__(self, index: int, message: str):
        super().__init__(message)
        self.index = index

    def __reduce__(self):  # raised on a worker, re-raised here
        return type(self), (self.index, str(self))


@dataclass(frozen=True)
class SweepExecutor:
    """Where :func:`run_sweep` runs its tasks.

    A worker that dies mid-sweep loses nothing: the scheduler runs its tasks again elsewhere (a task
    is a pure function of its seed), and each result is collected once, by its task's future.

    Args:
        kind: ``"sequential"`` (in this process), ``"local"`` (a ``dask.distributed.LocalCluster``
            started for the sweep and closed after it) or ``"scheduler"`` (the running cluster at
            ``address``, whose workers must have ``histostudy`` installed).
        address: the scheduler's ``"tcp://host:port"`` (or ``tls://``); only with ``"scheduler"``.
        n_workers: the LocalCluster's worker processes.
        threads_per_worker: threads per worker; also caps the torch, numba and BLAS thread pools
            inside each worker.
        allowed_failures: how many worker deaths a task survives before the sweep fails
            (LocalCluster only; a running scheduler keeps its own setting).

    Raises:
        ValueError: an unknown ``kind``, a count out of range, or an ``address`` that is not a
            scheduler address (or given with another kind).
    """

    kind: str = "sequential"
    address: str | None = None
    n_workers: int = 2
    threads_per_worker: int = 1
    allowed_failures: int = 3

    def __post_init__(self):
        if self.kind not in ("sequential", "local", "scheduler"):
            raise ValueError(f"kind must be 'sequential', 'local' or 'scheduler', got {self.kind!r}")
        for name in ("n_workers", "threads_per_worker"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        failures = self.allowed_failures
        if isinstance(failures, bool) or not isinstance(failures, (int, np.integer)) or failures < 0:
            raise ValueError(f"allowed_failures must be an integer >= 0, got {failures!r}")
        if self.kind == "scheduler":
            _check_address(self.address, "address")
        elif self.address is not None:
            raise ValueError(f"address is only for kind='scheduler', got {self.address!r} with kind={self.kind!r}")

    @classmethod
    def parse(cls, spec: str, *, name: str = "executor", **options) -> SweepExecutor:
        """The executor a string names.

        Args:
            spec: ``"sequential"``, ``"local"``, ``"local:<workers>"`` or ``"tcp://host:port"``.
            name: the argument or variable ``spec`` came from, for the message.
            **options: the other fields.

        Returns:
            The executor.

        Raises:
            TypeError: ``spec`` is not a string.
            ValueError: ``spec`` names no executor (the message names ``name``).
        """
        if not isinstance(spec, str):
            raise TypeError(f"{name} must be a string, a SweepExecutor or None, got {type(spec).__name__}: {spec!r}")
        text = spec.strip()
        if text == "sequential":
            return cls("sequential", **options)
        if text == "local":
            return cls("local", **options)
        if text.startswith("local:"):
            count = text[len("local:"):]
            if not count.isdigit() or int(count) < 1:
                raise ValueError(f"{name}: the workers of 'local:<workers>' must be an integer >= 1, got {spec!r}")
            return cls("local", **{**options, "n_workers": int(count)})
        if "://" in text:
            return cls("scheduler", address=_check_address(text, name), **options)
        raise ValueError(f"{name} must be {_SPEC_HELP}, got {spec!r}")


def resolve_executor(executor: SweepExecutor | str | None = None) -> SweepExecutor:
    """The executor of a sweep; the one place that reads :data:`SCHEDULER_ENV`.

    Args:
        executor: a :class:`SweepExecutor`; a string, parsed by :meth:`SweepExecutor.parse`
            (``"sequential"``, ``"local"``, ``"local:<workers>"``, ``"tcp://host:port"``); or None:
            the environment variable ``HISTOSTUDY_SCHEDULER`` (same strings), sequential when it is
            unset or empty, so that a study can be pointed at a cluster without editing its notebooks.

    Returns:
        The executor.

    Raises:
        TypeError: ``executor`` of another type.
        ValueError: a string (or the variable) that names no executor.
    """
    if isinstance(executor, SweepExecutor):
        return executor
    if executor is None:
        spec = os.environ.get(SCHEDULER_ENV, "").strip()
        return SweepExecutor.parse(spec, name=SCHEDULER_ENV) if spec else SweepExecutor()
    return SweepExecutor.parse(executor)


def run_sweep(task_fn: Callable[..., Any], tasks: Sequence, *, seed: int | np.random.SeedSequence | None = None,
              executor: SweepExecutor | str | None = None, shared: dict | None = None,
              chunk_size: int | None = None, progress: bool = False, cache: str | os.PathLike | None = None) -> list:
    """Run ``task_fn`` on every element of ``tasks``; the results in task order, the same bit for
    bit whatever runs them (docs/architecture.md, "Seeding and determinism").

    Task ``i`` is called ``task_fn(tasks[i], seeds[i], **shared)``, or ``task_fn(tasks[i],
    **shared)`` when ``seed`` is None (the tasks then carry all their randomness).

    Args:
        task_fn: a module-level function (importable by its module path on the workers).
        tasks: the tasks' arguments.
        seed: an int (``seeds = SeedSequence(seed).spawn(len(tasks))``), a ``SeedSequence``
            (``seed.spawn(len(tasks))``, which advances it as numpy's spawn does) or None.
        executor: where to run (:func:`resolve_executor`).
        shared: read-only inputs common to all tasks, sent once to every worker on a cluster.
        chunk_size: on a cluster, consecutive tasks per dask task (default: about 4 chunks per
            worker thread), so that tasks of milliseconds do not pay dask's overhead one by one;
            the results do not depend on it.
        progress: show a tqdm bar (per chunk on a cluster).
        cache: a folder where each finished task's result is kept under its content key and found
            again by a later sweep of the same task (:class:`.sweep_cache.SweepCache`; default:
            ``HISTOSTUDY_SWEEP_CACHE``, else nothing kept), so that a sweep stopped half-way redoes
            only what did not finish.

    Returns:
        The results, in the order of ``tasks``.

    Raises:
        TypeError: ``task_fn`` not callable, or ``seed`` of another type.
        ValueError: a bad ``chunk_size`` or executor.
        SweepTaskError: the first task that raised (by completion) or whose workers died more
            than ``allowed_failures`` times, by its index.
    """
    if not callable(task_fn):
        raise TypeError(f"task_fn must be callable, got {type(task_fn).__name__}")
    tasks = list(tasks)
    if seed is None:
        seeds = None
    elif isinstance(seed, np.random.SeedSequence):
        seeds = seed.spawn(len(tasks))
    elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        seeds = np.random.SeedSequence(int(seed)).spawn(len(tasks))
    else:
        raise TypeError(f"seed must be an int, a numpy.random.SeedSequence or None, "
                        f"got {type(seed).__name__}: {seed!r}")
    if chunk_size is not None and (isinstance(chunk_size, bool) or not isinstance(chunk_size, (int, np.integer))
                                   or chunk_size < 1):
        raise ValueError(f"chunk_size must be an integer >= 1 or None, got {chunk_size!r}")
    shared = {} if shared is None else dict(shared)
    ex = resolve_executor(executor)
    calls: list[tuple] = [(arg,) for arg in tasks] if seeds is None else [(arg, s) for arg, s in zip(tasks, seeds)]
    folder = resolve_sweep_cache(cache)
    if folder is None or not calls:
        return _run(task_fn, calls, shared, ex, chunk_size, progress, lambda i, value: None)
    store = SweepCache(folder, task_fn, shared, (ex.kind, ex.threads_per_worker if ex.kind != "sequential" else 0))
    keys = [store.key(call) for call in calls]
    found = {i: value for i, (hit, value) in enumerate(store.load(k) for k in keys) if hit}
    todo = [i for i in range(len(calls)) if i not in found]
    done = _run(task_fn, [calls[i] for i in todo], shared, ex, chunk_size, progress,
                lambda j, value: store.store(keys[todo[j]], value), [todo[j] for j in range(len(todo))])
    found.update(zip(todo, done))
    return [found[i] for i in range(len(calls))]


def _run(task_fn, calls, shared, ex, chunk_size, progress, on_result, indices=None) -> list:
    """The sweep's calls on ``ex``; ``on_result(j, value)`` as call ``j`` finishes; ``indices``: the
    calls' task numbers (errors name them)."""
    indices = list(range(len(calls))) if indices is None else indices
    if ex.kind == "sequential" or not calls:
        return _run_sequential(task_fn, calls, shared, progress, on_result, indices)
    return _run_distributed(task_fn, calls, shared, ex, chunk_size, progress, on_result, indices)


def _run_sequential(task_fn, calls, shared, progress, on_result, indices) -> list:
    results = []
    for j, args in enumerate(_progress(calls, len(calls), progress)):
        try:
            results.append(task_fn(*args, **shared))
        except Exception as exc:
            raise _task_error(task_fn, indices[j], exc) from exc
        on_result(j, results[-1])
    return results


def _run_distributed(task_fn, calls, shared, ex: SweepExecutor, chunk_size, progress, on_result, indices) -> list:
    import logging

    import dask
    from distributed import Client, LocalCluster, as_completed

    cluster, environ = None, {var: os.environ.get(var) for var in _THREAD_VARS}
    try:
        if ex.kind == "local":
            # The workers are spawned (dask's default) with their thread pools capped in their
            # environment; dask's Nanny takes these variables from this process's environment
            # (and leaves them there, also when it restarts a worker): restored at the end.
            threads = {var: str(ex.threads_per_worker) for var in _THREAD_VARS}
            os.environ.update(threads)
            with dask.config.set({"distributed.scheduler.allowed-failures": int(ex.allowed_failures),
                                  "distributed.nanny.pre-spawn-environ": {**dask.config.get(
                                      "distributed.nanny.pre-spawn-environ", {}), **threads}}):
                cluster = LocalCluster(n_workers=int(ex.n_workers), threads_per_worker=int(ex.threads_per_worker),
                                       processes=True, dashboard_address=":0", silence_logs=logging.ERROR)
        with Client(cluster if cluster is not None else ex.address, set_as_default=False) as client:
            token = f"sweep-{getattr(task_fn, '__name__', 'task')}-{uuid.uuid4().hex[:12]}"
            # Shared inputs as a task of their own, not scattered: the scheduler keeps its spec, so
            # if every worker holding them dies they are made again rather than lost; each worker
            # fetches them once from a peer.
            with dask.config.set({"distributed.admin.large-graph-warning-threshold": "2GB"}):
                shared_ref = client.submit(_identity, _dumps(shared), pure=False, key=f"shared-{token}")
            if chunk_size is None:
                chunk_size = -(-len(calls) // (4 * max(1, sum(client.nthreads().values()))))
            chunk_size = int(chunk_size)
            starts = range(0, len(calls), chunk_size)
            futures = [client.submit(_call, task_fn, _dumps(calls[a:a + chunk_size]), a, token, shared_ref,
                                     ex.threads_per_worker, pure=False, key=f"{token}-{a}") for a in starts]
            first = {f.key: a for f, a in zip(futures, starts)}
            results: dict[int, Any] = {}
            try:
                for future in _progress(as_completed(futures, loop=client.loop), len(futures), progress):
                    try:
                        values, pid, stages = pickle.loads(future.result())
                    except Exception as exc:
                        # a task that raised or killed its workers before the cancellations it caused
                        erred = [f for f in futures if f.status == "error"]
                        failed = erred[0] if erred else future
                        exc = failed.exception() if erred else exc
                        if isinstance(exc, SweepTaskError):
                            raise SweepTaskError(indices[exc.index], str(exc).replace(
                                f"sweep task {exc.index} ", f"sweep task {indices[exc.index]} ", 1)) from exc
                        raise _task_error(task_fn, indices[first[failed.key]], exc) from exc
                    if pid != os.getpid():  # a worker in this process charged this process already
                        merge_stage_totals(stages)
                    # as_completed yields each future once, re-run or not
                    for j, value in enumerate(values, start=first[future.key]):
                        results[j] = value
                        on_result(j, value)
            finally:
                client.cancel(futures)
        return [results[i] for i in range(len(calls))]
    finally:
        if cluster is not None:
            cluster.close()
        for var, value in environ.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value


def _dumps(obj) -> bytes:
    """``obj`` pickled in one piece. Data cross the cluster as such bytes, never as dask's own
    serialisation: that can hand a worker numpy arrays at byte offsets that break their element
    alignment, and numpy reduces unaligned arrays in another order (last-bit differences, measured
    on the pose sweep). Unpickled from bytes, every array owns aligned memory, as in this process."""
    import cloudpickle

    return cloudpickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)


def _identity(blob: bytes) -> bytes:
    return blob


#: Per worker process: the shared inputs of the latest sweeps, unpickled once (token -> dict).
_SHARED: dict[str, dict] = {}


def _call(task_fn, chunk: bytes, start: int, token: str, shared: bytes, threads: int) -> bytes:
    """On a worker: cap the thread pools at ``threads``, then run a chunk of tasks (the first is
    task ``start``) on their unpickled arguments and the sweep's shared inputs (unpickled once
    per process); pickled, the results, this process's id and the stage times charged here since
    the last chunk reported them (:mod:`.stage_profile`), which the caller adds to its own. A task
    that raises raises :class:`SweepTaskError`."""
    _cap_threads(threads)
    if token not in _SHARED:
        while len(_SHARED) >= 2:
            _SHARED.pop(next(iter(_SHARED)))
        _SHARED[token] = pickle.loads(shared)
    results = []
    for i, args in enumerate(pickle.loads(chunk), start=start):
        try:
            results.append(task_fn(*args, **_SHARED[token]))
        except Exception as exc:
            raise _task_error(task_fn, i, exc) from exc
    return _dumps((results, os.getpid(), _unreported_stages()))


_REPORTED_LOCK = threading.Lock()
#: Per worker process: the stage totals the chunks have reported so far.
_REPORTED: dict = {}


def _unreported_stages() -> dict:
    """The stage times charged in this process since a chunk last reported them: where a worker runs
    chunks on several threads at once, each time is reported once, by whichever chunk ends first."""
    global _REPORTED
    with _REPORTED_LOCK:
        now = stage_totals()
        delta, _REPORTED = stage_delta(_REPORTED, now), now
    return delta


def _cap_threads(threads: int) -> None:
    """Cap the thread pools at ``threads``: the variables torch, numba and BLAS read when they load,
    and, from the calling thread (their setting is per thread), the pools of torch and numba where
    they are loaded already (not while another task thread is still importing them)."""
    for var in _THREAD_VARS:
        os.environ[var] = str(threads)
    torch, numba = _loaded("torch"), _loaded("numba")
    if torch is not None and torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    if numba is not None:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


def _loaded(name: str):
    module = sys.modules.get(name)
    return None if module is None or getattr(module.__spec__, "_initializing", False) else module


def _task_error(task_fn, i: int, exc: BaseException) -> SweepTaskError:
    name = getattr(task_fn, "__name__", repr(task_fn))
    if type(exc).__name__ == "KilledWorker":
        return SweepTaskError(i, f"sweep task {i} ({name}), or one chunked with it: its worker died too often "
                                 f"({exc})")
    if type(exc).__name__ in ("CancelledError", "FutureCancelledError"):
        return SweepTaskError(i, f"sweep task {i} ({name}) was cancelled, by the scheduler or its loss ({exc})")
    return SweepTaskError(i, f"sweep task {i} ({name}) failed: {type(exc).__name__}: {exc}")


def _progress(iterable, total: int, show: bool):
    if not show:
        return iterable
    from tqdm.auto import tqdm

    return tqdm(iterable, total=total, desc="sweep")


def _check_address(address, name: str) -> str:
    match = _ADDRESS.match(address) if isinstance(address, str) else None
    if match is None or not 1 <= int(match.group(3)) <= 65535:
        raise ValueError(f"{name} must be a scheduler address 'tcp://host:port' (or tls://, port 1-65535), "
                         f"got {address!r}")
    return address
