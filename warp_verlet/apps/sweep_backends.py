"""Where the variants of a sweep run: in this process, in a local process pool, or as Ray tasks.

Every backend has ``run(fn, items)``: ``items`` are (key, payload) pairs, ``fn(payload, slot)`` runs one of them on
``slot`` (a :class:`Slot`: the device, the CPU threads it may use, and whether it sees the driver's disk), and
``run`` yields an :class:`Outcome` per item as each finishes, in finishing order. An exception in ``fn`` is an
outcome ("error"); an item whose worker process dies is run once more, and is "killed" when its worker dies again;
the other items go on. Every item that was run again says so (``Outcome.retries``, ``retry_reason``), so that a
summary records which variants lost a worker even when their second run succeeded. Closing the generator
(or a KeyboardInterrupt inside it) stops the work in flight. Nothing here schedules: the pool hands out the
next item when a worker is free, and Ray places tasks by their ``num_gpus`` / ``num_cpus``.

- :class:`InlineBackend`: one item at a time in this process (isolated timings, easy debugging).
- :class:`LocalBackend`: ``concurrent.futures.ProcessPoolExecutor`` with the spawn start method, one item per
  device slot: on CUDA one worker per GPU by default, on the CPU a set number of workers. Needs nothing beyond
  the base install.
- :class:`RayBackend`: each item one Ray task with ``num_gpus`` (CUDA) or ``num_cpus`` (CPU) set; an optional
  extra (``pip install 'warp-verlet[ray]'``).
"""

from __future__ import annotations

import os
import signal
import time
import traceback
from collections import deque
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterable, Iterator

from ..errors import WarpVerletError

RAY_MISSING = "--ray needs Ray, an optional extra: pip install 'warp-verlet[ray]'"
STOP_GRACE_S = 10.0  # how long interrupted workers get to close their caches before they are killed


@dataclass(frozen=True)
class Slot:
    device: str  # "cpu", "cuda", "cuda:N"
    threads: int | None = None  # CPU relaxation threads (None: the simulator chooses)
    local: bool = True  # False: a Ray node that does not share the driver's disk
    verbose: bool = False  # show Warp's start-up messages in the worker (warp-verlet sweep -v)


@dataclass(frozen=True)
class Outcome:
    key: Any
    status: str  # "done", "error", "killed", "interrupted"
    value: Any = None
    error: str | None = None
    latency: float = 0.0  # seconds from dispatch to the result's arrival in the driver
    retries: int = 0  # times it was run again because its worker died
    retry_reason: str | None = None  # how its worker died, when it was run again


def _error_text(exc: BaseException) -> str:
    """One line for the summary: the exception and where it was raised."""
    tb = traceback.extract_tb(exc.__traceback__)
    where = f" (at {os.path.basename(tb[-1].filename)}:{tb[-1].lineno})" if tb else ""
    return f"{type(exc).__name__}: {exc}{where}"


def cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def _note(text: str) -> None:
    import sys

    print(f"note: {text}", file=sys.stderr)


def quiet_warp(verbose: bool = False, device: str = "cpu") -> None:
    """Start Warp in a worker as ``warp-verlet run`` does (warp_setup.start_warp): unless ``verbose``, without its
    banner and module-load lines, and on the CPU without its CUDA-driver warning. Tasks call it first."""
    from ..core.warp_setup import start_warp

    start_warp(verbose=verbose, cpu=not device.startswith("cuda"), note=_note)


def cuda_devices(verbose: bool = False) -> int:
    """The CUDA devices Warp sees (none on a machine without the driver: its warning is shown only if verbose)."""
    import warp as wp

    from ..core.warp_setup import start_warp

    start_warp(verbose=verbose, cpu=True, note=_note)
    return wp.get_cuda_device_count()


def device_slots(device: str | None, workers: int | None, threads: int | None = None,
                 verbose: bool = False) -> list[Slot]:
    """The slots of a local run: ``device`` None means CUDA when present, else the CPU. On "cuda", one slot per GPU
    (``workers`` more or fewer slots go round the GPUs); on "cuda:N", ``workers`` (default 1) on that GPU; on the
    CPU, ``workers`` (default: the cores) with ``threads`` each (default: the cores shared among the workers).
    ``verbose``: the workers show Warp's start-up messages."""
    if workers is not None and workers < 1:
        raise WarpVerletError(f"expected at least 1 worker, got {workers}")
    if device is None:
        device = "cuda" if cuda_devices(verbose) else "cpu"
    if device == "cpu":
        n = workers or cpu_count()
        return [Slot("cpu", threads or max(1, cpu_count() // n), verbose=verbose)] * n
    if threads is not None:
        raise WarpVerletError("--threads sets CPU relaxation threads and does not apply to CUDA")
    gpus = cuda_devices(verbose)
    if device == "cuda":
        if not gpus:
            raise WarpVerletError("device 'cuda' asked for, but no CUDA device is present")
        n = workers or gpus
        return [Slot(f"cuda:{i % gpus}", verbose=verbose) for i in range(n)]
    if device.startswith("cuda:") and device[5:].isdigit():
        if int(device[5:]) >= gpus:
            raise WarpVerletError(f"device {device!r} asked for, but {gpus} CUDA device(s) are present")
        return [Slot(device, verbose=verbose)] * (workers or 1)
    raise WarpVerletError(f"expected a device cpu, cuda or cuda:N, got {device!r}")


def _describe_slots(slots: list[Slot]) -> str:
    devices = sorted({s.device for s in slots})
    threads = {s.threads for s in slots}
    each = f", {threads.pop()} relaxation thread(s) each" if len(threads) == 1 and None not in threads else ""
    return f"{len(slots)} at once on {', '.join(devices)}{each}"


class InlineBackend:
    """Each item in this process, one after another: timings are isolated (nothing else of the sweep runs)."""

    parallel = 1

    def __init__(self, device: str = "cpu", threads: int | None = None):
        self.slot = Slot(device, threads)
        self.description = f"in this process, one variant at a time on {device}"
        self.timing_note = f"isolated: one variant at a time on {device}"

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        pass

    def run(self, fn: Callable, items: Iterable[tuple[Any, Any]]) -> Iterator[Outcome]:
        for key, payload in items:
            t0 = time.perf_counter()
            try:
                value = fn(payload, self.slot)
            except Exception as exc:  # noqa: BLE001 - recorded, and the rest go on
                yield Outcome(key, "error", error=_error_text(exc), latency=time.perf_counter() - t0)
                continue
            yield Outcome(key, "done", value, latency=time.perf_counter() - t0)


def _call(fn: Callable, payload: Any, slot: Slot) -> Any:
    return fn(payload, slot)


def _signal_name(code: int | None) -> str:
    if code is None:
        return "its exit status is unknown"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}" + (" (out of memory?)" if -code == signal.SIGKILL else "")
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit status {code}"


class LocalBackend:
    """A process pool on this machine (spawn start method), one variant per slot at a time.

    Only as many items are submitted as there are slots, so every submitted item is running. A worker that
    dies breaks a ProcessPoolExecutor and fails everything in it: the items that were running are then run
    again, each alone in a fresh one-worker pool, so that the one that kills its worker is found and recorded
    ("killed", with the signal) while the others finish normally. Each of them is an outcome with ``retries`` 1
    and the worker's death as its ``retry_reason``."""

    def __init__(self, slots: list[Slot]):
        self._packages: tuple = ()
        if not slots:
            raise WarpVerletError("a local sweep needs at least one worker")
        self.slots = list(slots)
        self.parallel = len(self.slots)
        self.description = f"local process pool (spawn), {_describe_slots(self.slots)}"
        devices = {s.device for s in self.slots}
        if self.parallel == 1:
            self.timing_note = f"isolated: one variant at a time on {self.slots[0].device}"
        elif len(devices) == len(self.slots) and all(d.startswith("cuda") for d in devices):
            self.timing_note = (f"one variant per GPU ({len(devices)} GPUs at once): each GPU ran one variant at a "
                                "time, the host's CPUs were shared")
        else:
            self.timing_note = (f"in parallel: up to {self.parallel} variants at once on one machine, so wall times "
                                "include contention and are not isolated timings")

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        pass  # each run() shuts its pools down

    def _pool(self, workers: int):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        return ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                                   initializer=_worker_init, initargs=(self._packages,))

    def run(self, fn: Callable, items: Iterable[tuple[Any, Any]]) -> Iterator[Outcome]:
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        self._packages = _package_of(fn)
        queue = deque(items)
        suspects: deque = deque()  # (key, payload, slot) that were running when a worker died
        death = ""  # how that worker died
        while queue or suspects:
            if suspects:
                key, payload, slot = suspects.popleft()
                yield from self._alone(fn, key, payload, slot, death)
                continue
            pool = self._pool(len(self.slots))
            workers: dict = {}  # pid -> every worker process the pool started, to tell how one died
            free = list(self.slots)
            running: dict = {}  # future -> (key, payload, slot, t0)
            finished = False

            def submit() -> None:
                while queue and free:
                    key, payload = queue.popleft()
                    slot = free.pop()
                    running[pool.submit(_call, fn, payload, slot)] = (key, payload, slot, time.perf_counter())
                    workers.update(getattr(pool, "_processes", None) or {})

            try:
                while queue or running:
                    submit()
                    done, _ = wait(list(running), return_when=FIRST_COMPLETED)
                    broken, ready = False, []
                    for future in done:
                        key, payload, slot, t0 = running.pop(future)
                        free.append(slot)
                        exc = future.exception()
                        latency = time.perf_counter() - t0
                        if isinstance(exc, BrokenProcessPool):
                            broken = True
                            suspects.append((key, payload, slot))
                        elif isinstance(exc, KeyboardInterrupt):
                            ready.append(Outcome(key, "interrupted", error="interrupted in its worker", latency=latency))
                        elif exc is not None:
                            ready.append(Outcome(key, "error", error=_error_text(exc), latency=latency))
                        else:
                            ready.append(Outcome(key, "done", future.result(), latency=latency))
                    if broken:
                        for future, (key, payload, slot, t0) in running.items():
                            suspects.append((key, payload, slot))
                        running.clear()
                        death = (f"a worker process died ({_signal_name(_died(workers.values()))}) while it ran, "
                                 "which stops the whole pool")
                    else:  # hand the free workers their next variants before the driver handles these results
                        submit()
                    yield from ready
                    if broken:
                        break
                finished = True
            finally:
                _stop(pool, running if not finished else {})

    def _alone(self, fn: Callable, key, payload, slot: Slot, death: str) -> Iterator[Outcome]:
        """Run one item again, alone in a new pool, after ``death`` (how a worker died while it ran)."""
        from concurrent.futures.process import BrokenProcessPool

        pool = self._pool(1)
        t0 = time.perf_counter()
        future = pool.submit(_call, fn, payload, slot)
        processes = list(getattr(pool, "_processes", {}).values())
        try:
            exc = future.exception()  # waits; a KeyboardInterrupt here is the driver's own
            latency = time.perf_counter() - t0
            if isinstance(exc, BrokenProcessPool):
                code = _died(processes)  # waits out the pool's own thread, which may reap the worker first
                outcome = Outcome(key, "killed", error=f"its worker process died ({_signal_name(code)}), twice: "
                                  "once beside others, once alone", latency=latency)
            elif isinstance(exc, KeyboardInterrupt):
                outcome = Outcome(key, "interrupted", error="interrupted in its worker", latency=latency)
            elif exc is not None:
                outcome = Outcome(key, "error", error=_error_text(exc), latency=latency)
            else:
                outcome = Outcome(key, "done", future.result(), latency=latency)
        finally:
            _stop(pool, {future: None} if not future.done() else {})
        yield replace(outcome, retries=1, retry_reason=death)


def _died(processes) -> int | None:
    """The exit code of the worker that broke a pool: the pool then terminates the others (SIGTERM), so it is the
    one that ended otherwise (None when none did, or none could be read)."""
    processes = list(processes)
    for p in processes:
        p.join(timeout=5)
    # The pool's own thread reaps them too: the one of the two that loses the race for the exit status reads it
    # a moment later, once the other has stored it.
    deadline = time.monotonic() + 5
    codes = [p.exitcode for p in processes]
    while None in codes and time.monotonic() < deadline:
        time.sleep(0.01)
        codes = [p.exitcode for p in processes]
    died = [c for c in codes if c not in (None, 0, -signal.SIGTERM)]
    return died[0] if died else None


def _package_of(fn: Callable) -> tuple:
    """Where this process loaded ``fn``'s top-level package from, unless it is warp_verlet (installed): (name,
    its __init__ file, its search locations). A package this process loaded from a file (the tests load the
    repository's bench/ so) is loaded from the same file in each worker."""
    import sys

    top = (getattr(fn, "__module__", None) or "").split(".")[0]
    module = sys.modules.get(top)
    spec = getattr(module, "__spec__", None)
    if not top or top in ("warp_verlet", "__main__") or spec is None or not spec.origin or not os.path.isfile(spec.origin):
        return ()
    return ((top, spec.origin, list(spec.submodule_search_locations or [])),)


def _worker_init(packages: tuple) -> None:
    """In a new worker: load each of the driver's packages from the file it came from, unless already there."""
    import importlib.util
    import sys

    for name, origin, locations in packages:
        if name in sys.modules:
            continue
        spec = importlib.util.spec_from_file_location(name, origin, submodule_search_locations=locations or None)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)


def _stop(pool, running: dict) -> None:
    """Shut a pool down. Items still running are interrupted (SIGINT: the run closes its cache, as Ctrl-C does
    for ``warp-verlet run``), given STOP_GRACE_S to finish, then killed."""
    from concurrent.futures import wait

    if running:
        for future in running:
            future.cancel()
        processes = list(getattr(pool, "_processes", {}).values())
        for p in processes:
            if p.is_alive():
                try:
                    os.kill(p.pid, signal.SIGINT)
                except OSError:
                    pass
        wait(list(running), timeout=STOP_GRACE_S)
        for p in processes:
            if p.is_alive():
                p.terminate()
    pool.shutdown(wait=True, cancel_futures=True)


# ---------------------------------------------------------------------------------------------- Ray

def import_ray():
    """``ray``, or one WarpVerletError saying how to install it."""
    try:
        import ray
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.split(".")[0] == "ray":
            raise WarpVerletError(RAY_MISSING) from None
        raise
    return ray


def _pickle_by_value(ray, fn: Callable) -> None:
    """Send ``fn``'s package to the workers with the task, unless it is warp_verlet's (installed on every node):
    a script's or a benchmark's module (``bench.work_precision``) need not be importable where the task runs."""
    import sys

    top = (getattr(fn, "__module__", None) or "").split(".")[0]
    if top and top != "warp_verlet" and top != "__main__" and top in sys.modules:
        ray.cloudpickle.register_pickle_by_value(sys.modules[top])


def _driver_node() -> str:
    """The Ray node this driver runs on: a task on another node does not see the driver's disk."""
    import ray

    return ray.get_runtime_context().get_node_id()


def _ray_call(fn: Callable, payload: Any, device: str, threads: int | None, driver_node: str,
              verbose: bool = False) -> Any:
    import ray

    local = ray.get_runtime_context().get_node_id() == driver_node
    return fn(payload, Slot(device, threads, local, verbose))


class RayBackend:
    """Each item one Ray task: ``num_gpus`` per task on CUDA (default 1: one variant per GPU), ``num_cpus`` on the
    CPU (default 1). Results stream back as tasks finish (``ray.wait``). A task's exception is an "error"
    outcome. A task whose worker dies is submitted once more from here (``max_retries=0`` and a second task,
    rather than Ray's own retry, which a driver cannot see when it succeeds), then "killed"; either way its
    outcome records the retry. A task on a node that does not share the driver's disk sends its output back
    through the object store.

    Unless ``verbose``, Ray logs only errors and the workers' output is not forwarded to the driver's console
    (the workers start Warp quietly, as ``run`` does).

    ``address``: None or "local" starts a local Ray instance (shut down at the end); "auto" joins the cluster
    started on this machine with ``ray start``; anything else is a cluster address (``ray://host:10001``). When
    Ray is already initialised in this process (a test's ``ray.init(num_cpus=2)``), that connection is used."""

    def __init__(self, address: str | None = None, device: str = "cpu", gpus_per_task: float | None = None,
                 cpus_per_task: float | None = None, threads: int | None = None, verbose: bool = False,
                 **init_kwargs):
        ray = import_ray()
        if device not in ("cpu", "cuda"):
            raise WarpVerletError(f"on Ray the device is 'cpu' or 'cuda' (Ray assigns each task its GPU), got {device!r}")
        self.device = device
        self.verbose = verbose
        self.started = False
        if not ray.is_initialized():
            import logging

            kwargs = {"include_dashboard": False, "logging_level": logging.INFO if verbose else logging.ERROR,
                      "log_to_driver": verbose, **init_kwargs}
            if address not in (None, "local"):
                kwargs["address"] = address
            ray.init(**kwargs)
            self.started = True
        if device == "cuda":
            self.resources = {"num_gpus": gpus_per_task or 1, "num_cpus": cpus_per_task or 1}
            self.threads = None
        else:
            if gpus_per_task:
                raise WarpVerletError("--gpus-per-variant applies to device cuda")
            cpus = cpus_per_task or 1
            self.resources = {"num_cpus": cpus}
            self.threads = threads or max(1, int(cpus))
        total = ray.cluster_resources()
        nodes = len([n for n in ray.nodes() if n.get("Alive")])
        per = self.resources.get("num_gpus") if device == "cuda" else self.resources["num_cpus"]
        have = total.get("GPU" if device == "cuda" else "CPU", 0)
        if have < per:
            self.close()
            raise WarpVerletError(f"the Ray cluster has {have:g} {'GPU' if device == 'cuda' else 'CPU'}s, and each "
                                  f"variant asks for {per:g}")
        self.parallel = max(1, int(have // per))
        what = ", ".join(f"{k} = {v:g}" for k, v in self.resources.items())
        self.description = (f"Ray {ray.__version__}, {nodes} node(s), {have:g} {'GPU' if device == 'cuda' else 'CPU'}s; "
                            f"one task per variant with {what}, up to {self.parallel} at once")
        if device == "cuda" and self.resources["num_gpus"] >= 1:
            self.timing_note = f"one variant per GPU (num_gpus = {self.resources['num_gpus']:g}): up to {self.parallel} at once, host CPUs shared"
        elif self.parallel == 1:
            self.timing_note = "isolated: the cluster fits one variant at a time"
        else:
            self.timing_note = (f"in parallel: up to {self.parallel} variants at once across the cluster's "
                                f"{nodes} node(s), so wall times include contention and are not isolated timings")

    def run(self, fn: Callable, items: Iterable[tuple[Any, Any]]) -> Iterator[Outcome]:
        ray = import_ray()
        import ray.exceptions as ray_errors
        from ray.exceptions import RayTaskError, TaskCancelledError

        # What the death of a task's worker (or of its node, or of the result it had stored there) looks like
        # here: the task runs once more, then it is "killed".
        died_errors = tuple(getattr(ray_errors, name) for name in
                            ("WorkerCrashedError", "OutOfMemoryError", "NodeDiedError", "ObjectLostError")
                            if hasattr(ray_errors, name))
        _pickle_by_value(ray, fn)
        task = ray.remote(_ray_call).options(max_retries=0, **self.resources)
        driver_node = _driver_node()
        pending: dict = {}  # ref -> (key, payload, t0, retry_reason: None on the first run)
        queue = iter(items)
        # Enough tasks in flight to keep every slot busy and show an autoscaler the demand, not the whole sweep
        # at once (a sweep of 100 000 variants would otherwise pickle every scene up front).
        window = max(4 * self.parallel, 256)

        def launch(key, payload, t0: float, reason: str | None) -> None:
            ref = task.remote(fn, payload, self.device, self.threads, driver_node, self.verbose)
            pending[ref] = (key, payload, t0, reason)

        def submit() -> None:
            for key, payload in queue:
                launch(key, payload, time.perf_counter(), None)
                if len(pending) >= window:
                    return

        submit()
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    key, payload, t0, reason = pending.pop(ref)
                    retried = {"retries": 1, "retry_reason": reason} if reason is not None else {}
                    try:
                        value = ray.get(ref)
                    except RayTaskError as exc:
                        cause = exc.cause if getattr(exc, "cause", None) is not None else exc
                        status = "interrupted" if isinstance(cause, KeyboardInterrupt) else "error"
                        text = _error_text(cause) if cause is not exc else str(exc).strip().splitlines()[-1]
                        yield Outcome(key, status, error=text, latency=time.perf_counter() - t0, **retried)
                    except died_errors as exc:
                        died = f"{type(exc).__name__}: {str(exc).strip().splitlines()[0]}"
                        if reason is None:  # once more, in a new worker
                            launch(key, payload, t0, f"its Ray worker died ({died})")
                            continue
                        yield Outcome(key, "killed", error=f"its Ray worker died, and again when retried: {died}",
                                      latency=time.perf_counter() - t0, **retried)
                    except TaskCancelledError:
                        yield Outcome(key, "interrupted", error="cancelled", latency=time.perf_counter() - t0,
                                      **retried)
                    else:
                        yield Outcome(key, "done", value, latency=time.perf_counter() - t0, **retried)
                submit()
        finally:
            for ref in pending:  # closed early (Ctrl-C): stop what is queued and running
                try:
                    ray.cancel(ref)
                except Exception:  # noqa: BLE001 - best effort
                    pass
            if pending:
                ray.wait(list(pending), num_returns=len(pending), timeout=STOP_GRACE_S)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Shut down the Ray instance this backend started (a connection it found is left alone)."""
        if self.started:
            import ray

            ray.shutdown()
            self.started = False


def make_backend(device: str | None = None, workers: int | None = None, threads: int | None = None,
                 ray: str | None = None, gpus_per_task: float | None = None, cpus_per_task: float | None = None,
                 verbose: bool = False):
    """The backend the command line asks for: Ray when ``ray`` is given (None: local pool). ``verbose``: Warp's
    and Ray's start-up messages are shown (``sweep -v``)."""
    if ray is not None:
        if workers is not None:
            raise WarpVerletError("--workers is for the local pool; on Ray, set --cpus-per-variant or "
                                  "--gpus-per-variant and let Ray place the tasks")
        if device is None:
            device = "cuda" if cuda_devices(verbose) else "cpu"
        return RayBackend(ray, device, gpus_per_task, cpus_per_task, threads, verbose=verbose)
    if gpus_per_task is not None or cpus_per_task is not None:
        raise WarpVerletError("--gpus-per-variant and --cpus-per-variant are Ray's; the local pool takes --workers")
    return LocalBackend(device_slots(device, workers, threads, verbose))
