"""Where `neumat fit-many`'s jobs run: as Ray tasks (a local Ray instance, or a cluster by address), or one
after another in this process. Both yield each job's row as it finishes, so the caller can save the results
after every row, and report the run's progress (done / failed / running, ETA)."""
from __future__ import annotations

import os
import socket
import time
from typing import Callable, Iterator

from rich.console import Console

from ..core.errors import InputError
from .fit_job import error_row

RAY_HINT = "pip install 'neumat[ray]' (or pip install ray)"
#: the local Ray instance's object store (rows and jobs are small; Ray's default takes 30 % of the memory)
OBJECT_STORE_BYTES = 200 * 2 ** 20


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


class RunProgress:
    """Prints one line per finished job and, at most every `every` seconds while jobs run, a status line:
    done / failed / running of the total and the ETA (elapsed time per finished job x jobs left)."""

    def __init__(self, total: int, console: Console, slots: int = 1, quiet: bool = False):
        self.total, self.console, self.slots, self.quiet = total, console, slots, quiet
        self.done = self.failed = 0
        self.t0 = time.perf_counter()

    def status(self) -> str:
        finished = self.done + self.failed
        running = min(self.slots, self.total - finished)
        elapsed = time.perf_counter() - self.t0
        eta = f", ETA {_duration(elapsed / finished * (self.total - finished))}" if 0 < finished < self.total else ""
        return (f"[{finished}/{self.total}: {self.done} done, {self.failed} failed, {running} running, "
                f"{_duration(elapsed)} elapsed{eta}]")

    def finished(self, row: dict) -> None:
        if row["status"] == "ok":
            self.done += 1
            what = f"ok in {row['seconds']:.1f} s on {row['worker']}"
        else:
            self.failed += 1
            what = f"[red]failed[/]: {row['error']}"
        if not self.quiet:
                self.console.print(f"{self.status()} {row['name']} ({row['model']}): {what}", highlight=False,
                               soft_wrap=True)


def run_local(jobs: list, task: Callable[[object], dict], progress: RunProgress) -> Iterator[dict]:
    """Run the jobs one after another in this process."""
    for job in jobs:
        row = task(job)
        progress.finished(row)
        yield row


def run_ray(jobs: list, task: Callable[[object], dict], progress: RunProgress, *, workers: int | None,
            address: str | None, gpus_per_task: float, retries: int, log: Callable[[str], None],
            lost: Callable[[object, BaseException], dict] = error_row, poll_seconds: float = 30.0) -> Iterator[dict]:
    """Run every job as a Ray task (1 CPU and `gpus_per_task` GPUs each) on the cluster at `address` (or
    $RAY_ADDRESS), else on a local Ray instance of `workers` CPUs (default: all of this machine's), started for
    this run and stopped after it. A task whose worker dies is retried up to `retries` times; a task lost for
    good (worker killed every time, Ray's out-of-memory killer) yields `lost(job, error)`. Rows are dicts with at
    least status ("ok" or "error"), name, model, seconds, worker and error (as `task` and `lost` return them)."""
    import ray

    address = address or os.environ.get("RAY_ADDRESS") or None
    started = not ray.is_initialized()
    if started:
        if address:
            check_ray_address(address)
            try:
                ray.init(address=address, log_to_driver=False)
            except ConnectionError as e:  # "auto" with no Ray instance on this machine
                raise InputError(f"--address {address}: no Ray cluster answers ({str(e).splitlines()[0]})") from None
        else:
            ray.init(num_cpus=workers or os.cpu_count(), include_dashboard=False, log_to_driver=False,
                     object_store_memory=OBJECT_STORE_BYTES)
    try:
        resources = ray.cluster_resources()
        cpus, gpus = int(resources.get("CPU", 0)), resources.get("GPU", 0)
        if gpus_per_task > gpus:
            raise InputError(f"--device cuda: the Ray cluster ({address or 'local'}) has no GPU")
        where = address or f"a local Ray instance started for this run ({ray.get_runtime_context().gcs_address})"
        log(f"Ray: {where}; {len(ray.nodes())} node(s), {cpus} CPU(s), {gpus:g} GPU(s); "
            f"{len(jobs)} task(s) of 1 CPU{f' + {gpus_per_task:g} GPU' if gpus_per_task else ''}")
        progress.slots = int(gpus // gpus_per_task) if gpus_per_task else cpus
        remote = ray.remote(_run_task).options(num_cpus=1, num_gpus=gpus_per_task, max_retries=retries,
                                          retry_exceptions=False)
        pending = {remote.remote(task, job): job for job in jobs}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=poll_seconds)
            if not ready:
                if not progress.quiet:
                    progress.console.print(progress.status(), highlight=False, soft_wrap=True)
                continue
            job = pending.pop(ready[0])
            try:
                row = ray.get(ready[0])
            except ray.exceptions.RayError as e:  # the task's worker died (every retry) or Ray killed it
                row = lost(job, e)
            progress.finished(row)
            yield row
    finally:
        if started:
            ray.shutdown()


def check_ray_address(address: str, timeout: float = 5.0) -> None:
    """InputError within `timeout` seconds when nothing accepts connections at a HOST:PORT or ray://HOST:PORT
    address (Ray itself retries for minutes, printing warnings); other forms ("auto") are left to Ray."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as e:
        raise InputError(f"--address {address}: no Ray cluster answers at that address "
                         f"({e.strerror or type(e).__name__})") from None


def _run_task(task: Callable[[object], dict], job) -> dict:
    """The Ray task: `task(job)` (a function, or any picklable callable object)."""
    return task(job)


def _duration(seconds: float) -> str:
    m, s = divmod(int(round(seconds)), 60)
    return f"{m // 60}h{m % 60:02d}m" if m >= 60 else f"{m}m{s:02d}s"



def add_engine_arguments(parser, unit: str) -> None:
    """The --engine / --workers / --address options of a benchmark whose `unit` (e.g. "(material, model) pair")
    is one job."""
    parser.add_argument("--engine", choices=("local", "ray"), default="local",
                        help=f"local: one {unit} after another here; ray: each {unit} a Ray task")
    parser.add_argument("--workers", type=int, default=None, help="--engine ray: CPUs of the local Ray instance")
    parser.add_argument("--address", default=None,
                        help="--engine ray: Ray cluster address (default $RAY_ADDRESS, else a local instance)")


def run_jobs(args, jobs: list, task: Callable[[object], dict], progress: RunProgress, *, gpus_per_task: float,
             lost: Callable[[object, BaseException], dict], log: Callable[[str], None]) -> Iterator[dict]:
    """The rows of `jobs` run by `task` on the engine the benchmark's arguments (`add_engine_arguments`) chose."""
    if args.engine == "ray":  # every job a Ray task: the tables can come from a cluster
        return run_ray(jobs, task, progress, workers=args.workers, address=args.address,
                       gpus_per_task=gpus_per_task, retries=2, log=log, lost=lost)
    return run_local(jobs, task, progress)
