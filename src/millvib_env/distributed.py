"""Run independent jobs (training seeds, benchmark chunks, sweep chunks) locally or on a Ray cluster.

`run_jobs(fn, jobs, ray=...)` returns `[fn(**job) for job in jobs]`, in order, computed

* locally: in `processes` worker processes (or in this process with processes=1), each started afresh from a
  server process that imported the package once (`_pool_context`);
* on Ray (``ray=""`` or ``"local"``: a local cluster with this machine's CPUs; ``ray="auto"`` or
  ``"ray://host:10001"``/``"host:6379"``: a running cluster), each job a Ray task asking for
  `num_cpus` CPUs. Ray is optional (``pip install -e ".[ray]"``); without it the same commands run
  in local processes.

Each job's result depends only on its arguments (every random draw comes from seeds in them), so
the local and the Ray runs give the same numbers.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing as mp
import os
import signal
import threading
from typing import Any, Callable, Iterator, Sequence

__all__ = ["run_jobs", "ray_available", "expect_modules"]


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """A HOST:PORT address must answer within `timeout_s` (Ray itself waits minutes for a dead one)."""
    import socket

    target = address.split("://", 1)[-1]
    host, sep, port = target.rpartition(":")
    if address == "auto" or not sep or not port.isdigit():
        return  # "auto" or a form Ray resolves itself
    try:
        socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout_s).close()
    except OSError as err:
        raise ValueError(f"--ray {address}: no Ray cluster answers there within {timeout_s:g} s "
                         f"({err.strerror or err})") \
            from None


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def _init_ray(address: str):
    if not ray_available():
        raise ValueError("--ray needs Ray: pip install -e \".[ray]\" (or run without --ray: local processes)")
    import ray

    if ray.is_initialized():
        return ray
    env = {"env_vars": {"MILLVIB_NUM_THREADS": os.environ.get("MILLVIB_NUM_THREADS", "1")}}
    if address in ("", "local"):
        ray.init(num_cpus=os.cpu_count(), include_dashboard=False, log_to_driver=False, runtime_env=env)
    else:
        _check_reachable(address)
        try:
            ray.init(address=address, log_to_driver=False, runtime_env=env)
        except (ConnectionError, RuntimeError, ValueError) as err:
            raise ValueError(f"--ray {address}: cannot connect to a Ray cluster there ({err})") from None
    return ray


def _call(fn: Callable, kwargs: dict) -> Any:
    return fn(**kwargs)


def _start_worker(environ: dict[str, str]) -> None:
    """A worker leaves Ctrl-C to its parent, which stops every worker and says so in one line; and it runs in
    the parent's environment as it is now (a fork server keeps the one it started with)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for key in set(os.environ) - set(environ):
        del os.environ[key]
    os.environ.update(environ)


#: the modules the running fork server imported (`_pool_context`); empty before this process's first pool
_server_modules: set[str] = set()
#: modules that this process's later pools will need (`expect_modules`): the fork server imports them at its start
_expected: set[str] = set()


@contextlib.contextmanager
def expect_modules(*names: str) -> Iterator[None]:
    """Within the block, the fork server imports `names` too when it starts: a command of several pools
    (`millvib reproduce --jobs N`) declares every pool's module before the first, so the workers of a later pool
    whose function lives in another module (the solver study, after the stability maps) do not each import it and
    what it imports (scipy.signal and scipy.stats there: about 0.7 CPU-s a worker)."""
    added = set(names) - _expected
    _expected.update(added)
    try:
        yield
    finally:
        _expected.difference_update(added)


def _pool_context(fn: Callable, preload: Sequence[str] = ()):
    """How the workers start: from multiprocessing's fork server where the platform has one (POSIX), else spawned.

    A spawned worker is a new interpreter that imports the package, numpy, scipy and numba again: 1-3 CPU-s each,
    at every pool (`millvib reproduce --jobs N` starts three). The fork server is one clean process, started by
    the first pool of this process, that imports once the package, the module of the pool's function, the
    modules in `preload` (torch for training) and those a command declared (`expect_modules`), and sets up
    numba's compiler context (`millvib_env._fork_server`); every worker
    after that is a fork of it, so it starts with those modules imported and inherits no thread pool, torch
    state or open file of this process (the server runs none). A later pool that asks for a module the server
    has not imported (training after a benchmark of baselines, in one session) restarts it with every module
    asked for so far, so that its workers do not each import torch; a later pool's own function module, if
    not declared, is imported by each of its workers. A worker runs in this process's current environment
    (`_start_worker`) and working folder; a variable read when a module is imported (NUMBA_*) is the server's,
    i.e. this process's when it started."""
    if "forkserver" not in mp.get_all_start_methods():
        return mp.get_context("spawn")
    from multiprocessing import forkserver

    ctx = mp.get_context("forkserver")
    preload = [*preload, *sorted(_expected)]
    if _server_modules and not set(preload) <= _server_modules:
        stop = getattr(forkserver._forkserver, "_stop", None)  # CPython's own (3.8-3.13); else workers import
        if stop is not None:
            stop()  # the next pool's first worker starts a new server; running workers are not touched
    # millvib_env._fork_server sets up numba's compiler context in the server, so no worker pays it
    _server_modules.update(["millvib_env", "millvib_env._fork_server", fn.__module__, *preload])
    ctx.set_forkserver_preload(sorted(_server_modules))  # read when the server starts
    return ctx


def _run_pool(fn: Callable, jobs: list, processes: int, bar, preload: Sequence[str] = ()) -> list:
    """The jobs in worker processes (`_pool_context`). Whatever ends the run early (a job's error, Ctrl-C,
    SIGTERM) stops the other workers at once instead of waiting for their jobs, then goes on up.

    A terminal's Ctrl-C reaches the whole process group, and a worker still importing would print a
    traceback. So the workers start with Ctrl-C ignored: the pool starts them (and the fork server, at the first
    pool) while this process ignores it, and an ignored signal is inherited through exec and kept by the fork
    server for its forks (a blocked mask is not inherited by either); a Ctrl-C in those few milliseconds is not
    seen."""
    n_workers = min(processes, len(jobs))
    main_thread = threading.current_thread() is threading.main_thread()
    pool = None
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main_thread else None
        try:
            pool = cf.ProcessPoolExecutor(max_workers=n_workers, initializer=_start_worker,
                                          initargs=(dict(os.environ),), mp_context=_pool_context(fn, preload))
            futures = [pool.submit(_call, fn, job) for job in jobs[:n_workers]]  # each starts its worker
        finally:
            if main_thread:
                signal.signal(signal.SIGINT, previous)
        futures += [pool.submit(_call, fn, job) for job in jobs[n_workers:]]
        for done in cf.as_completed(futures):
            done.result()  # a job's error ends the run now, not after the others
            if bar is not None:
                bar.update(1)
        out = [f.result() for f in futures]
    except BaseException:
        if pool is not None:
            workers = list((getattr(pool, "_processes", None) or {}).values())
            manager = getattr(pool, "_executor_manager_thread", None)
            pool.shutdown(wait=False, cancel_futures=True)
            for proc in workers:
                proc.terminate()
            for proc in workers:
                proc.join(timeout=5)
            # The pool's own thread also joins (reaps) the workers; until it has recorded their exit, a
            # worker that it reaped first still reads as alive here.
            if manager is not None:
                manager.join(timeout=5)
        raise
    pool.shutdown()
    return out


def run_jobs(fn: Callable, jobs: Sequence[dict], *, ray: str | None = None, processes: int = 1,
             num_cpus: float = 1.0, progress: bool = False, desc: str = "jobs", preload: Sequence[str] = ()) -> list:
    """`[fn(**job) for job in jobs]`, locally or on Ray (module docstring). `fn` must be importable
    (a module-level function). `preload`: modules the local workers need that `fn`'s module does not import
    (imported once by the fork server, if this is the process's first pool)."""
    jobs = list(jobs)
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=len(jobs), desc=desc, unit="job")
    try:
        if ray is not None:
            rt = _init_ray(ray)
            remote = rt.remote(num_cpus=num_cpus)(_call)
            refs = [remote.remote(fn, job) for job in jobs]
            pending = list(refs)
            while pending:
                done, pending = rt.wait(pending, num_returns=1)
                if bar is not None:
                    bar.update(len(done))
            return rt.get(refs)
        if processes <= 1 or len(jobs) <= 1:
            out = []
            for job in jobs:
                out.append(fn(**job))
                if bar is not None:
                    bar.update(1)
            return out
        return _run_pool(fn, jobs, processes, bar, preload)
    finally:
        if bar is not None:
            bar.close()
