"""The engine under ``radar4dgs batch`` and ``radar4dgs bench``: tasks on a Ray cluster.

A task is a module-level function called with one picklable item. :func:`run_tasks` submits each
item as a Ray task with declared resources (:class:`Resources`), at most ``window`` at once,
retried by Ray up to ``retries`` times when its worker dies (killed, out of memory, node lost) or
when it raises an exception the task lets through; the task itself decides how a retry resumes
(the batch and bench tasks continue from the run's last checkpoint). Every result or final
failure comes back to ``on_done`` in the calling process, in completion order; ``on_poll`` is
called while waiting (the progress view).

The cluster is a local one started in this process (``address`` None: ``ray.init`` with the
machine's CPUs, no dashboard, shut down at the end) or an existing one (``address`` ``auto`` or
``ray://HOST:10001``). On a local cluster the workers get this process's ``sys.path``, so that a
task defined in a module found there (a test, a script) imports in the workers too.

``ray`` is imported inside the functions: ``radar4dgs bench --help`` and ``radar4dgs batch --help``
do not load it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence

# How often run_tasks wakes up to call on_poll while tasks run (seconds).
POLL_SECONDS = 0.5


class EngineError(ValueError):
    """The cluster cannot run the tasks as asked (an unknown address, resources it does not have)."""


@dataclass(frozen=True)
class Resources:
    """What one task declares to Ray: CPUs, a fraction (or number) of GPUs, memory in GiB (0 =
    none declared). Ray starts a task only on a node with that much free."""

    cpus: float = 1.0
    gpus: float = 0.0
    memory_gb: float = 0.0

    def options(self) -> dict[str, Any]:
        options: dict[str, Any] = {"num_cpus": self.cpus, "num_gpus": self.gpus}
        if self.memory_gb > 0:
            options["memory"] = int(self.memory_gb * 1024**3)
        return options

    def text(self) -> str:
        memory = f", {self.memory_gb:g} GiB" if self.memory_gb > 0 else ""
        return f"{self.cpus:g} CPU, {self.gpus:g} GPU{memory}"


def one_line(exc: BaseException) -> str:
    """An exception as one line, ``Type: first line of the message``; the cause Ray wraps a task's
    exception in is unwrapped first (``RayTaskError``), a dead worker says so."""
    cause = getattr(exc, "cause", None)
    if isinstance(cause, BaseException):
        exc = cause
    text = str(exc).strip().splitlines()
    message = text[0] if text else ""
    name = type(exc).__name__
    if name == "WorkerCrashedError":
        message = "the worker died while running the task (killed, or out of memory)"
    return f"{name}: {message}" if message else name


@contextlib.contextmanager
def cluster(address: str | None = None, num_cpus: int | None = None, num_gpus: int | None = None) -> Iterator[dict]:
    """A connected Ray cluster for the block; yields its total resources (``{"CPU": 2.0, ...}``).

    ``address`` None starts a local cluster in this process with ``num_cpus`` logical CPUs (default
    the machine's) and shuts it down after; otherwise it connects to the running cluster at
    ``address`` and only disconnects. A Ray already initialised by the caller is used as it is.
    """
    import ray

    started = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "logging_level": logging.WARNING}
        if address is None:
            kwargs["num_cpus"] = int(num_cpus or os.cpu_count() or 1)
            if num_gpus is not None:
                kwargs["num_gpus"] = num_gpus
            with _worker_path():
                ray.init(**kwargs)
        else:
            try:
                ray.init(address=address, **kwargs)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise EngineError(f"--address {address}: cannot connect to a Ray cluster ({one_line(exc)})") from exc
        started = True
    try:
        yield dict(ray.cluster_resources())
    finally:
        if started:
            ray.shutdown()


@contextlib.contextmanager
def _worker_path() -> Iterator[None]:
    """PYTHONPATH set to this process's ``sys.path`` while a local cluster starts: its workers
    inherit the environment of the processes ray.init starts."""
    previous = os.environ.get("PYTHONPATH")
    paths = [p for p in sys.path if p and os.path.isdir(p)]
    os.environ["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    try:
        yield
    finally:
        if previous is None:
            del os.environ["PYTHONPATH"]
        else:
            os.environ["PYTHONPATH"] = previous


def check_resources(resources: Resources, available: dict, local: bool) -> list[str]:
    """What a task asks for that no node of the cluster has (as lines); empty when it fits. On an
    existing cluster the autoscaler may still add such a node, so the caller only warns there."""
    problems = []
    for key, asked in (("CPU", resources.cpus), ("GPU", resources.gpus),
                       ("memory", resources.memory_gb * 1024**3)):
        have = float(available.get(key, 0.0))
        if asked > have + 1e-9:
            if key == "memory":
                problems.append(f"{resources.memory_gb:g} GiB of memory per task, the cluster has "
                                f"{have / 1024**3:.1f} GiB (--memory-gb)")
            else:
                flag = "--cpus" if key == "CPU" else "--gpus"
                where = "this machine" if local else "the cluster"
                problems.append(f"{asked:g} {key} per task, {where} has {have:g} ({flag})")
    return problems


def run_tasks(function: Callable[..., Any], items: Sequence[Any], *, resources: Resources, window: int | None = None,
              retries: int = 2, retry_exceptions: bool = True, on_done: Callable[[int, Any, str | None], None],
              on_poll: Callable[[], None] | None = None, args: tuple = ()) -> None:
    """Run ``function(item, *args)`` as one Ray task per item on the connected cluster
    (:func:`cluster`), at most ``window`` at once (None: as many as the resources allow).

    ``on_done(index, result, error)`` is called as each task ends: ``error`` None and the task's
    return value, or the task's one-line failure (:func:`one_line`) once Ray's ``retries`` are
    spent. ``retry_exceptions`` also retries a task that raised (not only one whose worker died).
    """
    import ray

    remote = ray.remote(function).options(max_retries=retries, retry_exceptions=retry_exceptions,
                                          **resources.options())
    waiting = list(range(len(items)))
    running: dict[Any, int] = {}
    limit = len(items) if window is None else max(1, window)
    while waiting or running:
        while waiting and len(running) < limit:
            index = waiting.pop(0)
            running[remote.remote(items[index], *args)] = index
        ready, _ = ray.wait(list(running), num_returns=1, timeout=POLL_SECONDS)
        for ref in ready:
            index = running.pop(ref)
            try:
                result, error = ray.get(ref), None
            except Exception as exc:  # noqa: BLE001 - a task's last failure is that item's result
                result, error = None, one_line(exc)
            on_done(index, result, error)
        if on_poll is not None:
            on_poll()


def run_inline(function: Callable[..., Any], items: Sequence[Any], *, on_done: Callable[[int, Any, str | None], None],
               args: tuple = ()) -> None:
    """The same contract as :func:`run_tasks`, one item after the other in this process (no Ray:
    what ``bench --jobs 1`` does, with no start-up cost and the debugger at hand)."""
    for index, item in enumerate(items):
        try:
            result, error = function(item, *args), None
        except Exception as exc:  # noqa: BLE001 - a task's failure is that item's result
            result, error = None, one_line(exc)
        on_done(index, result, error)


def elapsed_text(seconds: float | None) -> str:
    """``75`` as ``1m15s``; ``?`` for None."""
    if seconds is None or seconds != seconds:
        return "?"
    seconds = max(0, int(round(seconds)))
    if seconds < 60:
        return f"{seconds}s"
    minutes, seconds = divmod(seconds, 60)
    if minutes < 60:
        return f"{minutes}m{seconds:02d}s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m"


def now() -> float:
    return time.time()
