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

from millvib_env.threads import THREADS_ENV, usable_cores

__all__ = ["run_jobs", "ray_available", "expect_modules", "start_workers"]


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


def _worker_environ(n_workers: int) -> dict[str, str]:
    """The environment a pool's workers run in: this process's, with MILLVIB_NUM_THREADS set to the usable cores
    over the workers where the user has not set it, so that `n_workers` workers of threaded plant batches do not
    each start a thread per core (as joblib's process workers limit their threads). The numbers do not depend
    on the threads (`threads`)."""
    environ = dict(os.environ)
    if not environ.get(THREADS_ENV, "").strip():
        environ[THREADS_ENV] = str(max(1, usable_cores() // max(1, n_workers)))
    return environ


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
    what it imports (scipy.signal and scipy.stats there)."""
    added = set(names) - _expected
    _expected.update(added)
    try:
        yield
    finally:
        _expected.difference_update(added)


def _pool_context(fn: Callable, preload: Sequence[str] = ()):
    """How the workers start: from multiprocessing's fork server where the platform has one (POSIX), else spawned.

    A spawned worker is a new interpreter that imports the package, numpy, scipy and numba again, at every pool
    (`millvib reproduce --jobs N` starts three). The fork server is one clean process, started by the first pool
    of this process, that imports once the package, the module of the pool's function, the
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


@contextlib.contextmanager
def _ctrl_c_ignored(ignore: bool = True) -> Iterator[None]:
    """Ctrl-C ignored within the block, where this is the main thread (only it may set a handler)."""
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if ignore and main_thread else None
    try:
        yield
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _start_server(ctx) -> bool:
    """Start `ctx`'s fork server if it is not running, without waiting for its imports; False where `ctx` has
    none (spawned workers). The server starts while this process ignores Ctrl-C: an ignored signal is inherited
    through exec, and the server hands its own start's handler to every worker it forks, so that a terminal's
    Ctrl-C (sent to the whole process group) reaches none of them (a worker still importing would print a
    traceback): it is the parent's to handle (`_run_pool`)."""
    if ctx.get_start_method() != "forkserver":
        return False
    from multiprocessing import forkserver

    with _ctrl_c_ignored():
        forkserver.ensure_running()
    return True


def start_workers(fn: Callable, preload: Sequence[str] = ()) -> None:
    """Start the fork server that `run_jobs(fn, ..., preload=preload)`'s local workers will come from, without
    waiting for it: it imports the package and `preload` (torch and SB3 for agents: the longest of its imports,
    docs/performance.md) while this process goes on with its own work, and the pool then finds it running (the
    same modules: no restart). Nothing where the platform has no fork server."""
    _start_server(_pool_context(fn, preload))


def _report(on_result: Callable | None, index: int, result: Any) -> None:
    if on_result is not None:
        on_result(index, result)


def _submit_meanwhile(pool, fn: Callable, jobs: list, n_workers: int, meanwhile: Sequence[int], here: dict,
                      futures: dict, on_result: Callable | None, bar) -> None:
    """Submit `jobs` to `pool` in order on a thread of their own, and meanwhile run jobs of `meanwhile` here, from
    the last: the first submissions wait for the fork server's imports (seconds, with a core to spare), and this
    process would only wait with them. It stops taking jobs once `n_workers` are submitted (the workers are up);
    the job it is running then ends first. An error here stops the submissions."""
    lock = threading.Lock()
    given: set[int] = set()
    up, stop = threading.Event(), threading.Event()
    failed: list[BaseException] = []

    def submit_all() -> None:
        try:
            for i in range(len(jobs)):
                with lock:
                    if stop.is_set():
                        return
                    if i in given:
                        continue
                    given.add(i)
                futures[i] = pool.submit(_call, fn, jobs[i])
                if len(futures) >= n_workers:
                    up.set()
        except BaseException as err:  # the pool shut down (this process's error or Ctrl-C) or failed to start
            failed.append(err)
        finally:
            up.set()

    submitter = threading.Thread(target=submit_all, name="millvib-submit", daemon=True)
    submitter.start()
    try:
        spare = sorted(set(meanwhile), reverse=True)
        while not up.is_set():
            with lock:
                i = next((k for k in spare if k not in given), None)
                if i is None:
                    break
                given.add(i)
            here[i] = fn(**jobs[i])
            _report(on_result, i, here[i])
            if bar is not None:
                bar.update(1)
    except BaseException:
        stop.set()
        raise
    finally:
        submitter.join()  # within the server's start at the most (an error above then goes on up)
    if failed:
        raise failed[0]


def _run_pool(fn: Callable, jobs: list, processes: int, bar, preload: Sequence[str] = (),
              on_result: Callable | None = None, meanwhile: Sequence[int] = ()) -> list:
    """The jobs in worker processes (`_pool_context`). Whatever ends the run early (a job's error, Ctrl-C,
    SIGTERM) stops the other workers at once instead of waiting for their jobs, then goes on up.

    A terminal's Ctrl-C reaches the whole process group, and a worker still importing would print a
    traceback. So the workers start with Ctrl-C ignored: forked from a fork server started while this process
    ignored it (`_start_server`), or, spawned, started by the pool while this process ignores it (a blocked mask
    is not inherited); a Ctrl-C in those few milliseconds is not seen. With a fork server, the jobs of `meanwhile`
    (those that need none of `preload`) may run here while the workers start (`_submit_meanwhile`)."""
    n_workers = min(processes, len(jobs))
    ctx = _pool_context(fn, preload)
    forked = _start_server(ctx)
    pool = None
    here: dict[int, Any] = {}
    futures: dict[int, cf.Future] = {}
    try:
        pool = cf.ProcessPoolExecutor(max_workers=n_workers, initializer=_start_worker,
                                      initargs=(_worker_environ(n_workers),), mp_context=ctx)
        if forked and meanwhile:
            _submit_meanwhile(pool, fn, jobs, n_workers, meanwhile, here, futures, on_result, bar)
        else:
            with _ctrl_c_ignored(not forked):
                futures.update((i, pool.submit(_call, fn, jobs[i])) for i in range(n_workers))  # start the workers
            futures.update((i, pool.submit(_call, fn, jobs[i])) for i in range(n_workers, len(jobs)))
        index = {f: i for i, f in futures.items()}
        for done in cf.as_completed(futures.values()):
            _report(on_result, index[done], done.result())  # a job's error ends the run now, not after the others
            if bar is not None:
                bar.update(1)
        out = [here[i] if i in here else futures[i].result() for i in range(len(jobs))]
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
             num_cpus: float = 1.0, progress: bool = False, desc: str = "jobs", preload: Sequence[str] = (),
             on_result: Callable[[int, Any], None] | None = None, meanwhile: Sequence[int] = ()) -> list:
    """`[fn(**job) for job in jobs]`, locally or on Ray (module docstring). `fn` must be importable
    (a module-level function). `preload`: modules the local workers need that `fn`'s module does not import
    (imported once by the fork server, if this is the process's first pool). `on_result(i, result)` is called in
    this process as each job's result comes in (in the order they finish), so that it can work on them while
    the others run; an error it raises ends the run as a job's would. `meanwhile`: the indices of jobs that this
    process may run itself while its local workers start (jobs that need none of `preload`; `_submit_meanwhile`).
    Every job's result is the same wherever it runs."""
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
            index = {ref: i for i, ref in enumerate(refs)}
            while pending:
                done, pending = rt.wait(pending, num_returns=1)
                for ref in done:
                    if on_result is not None:
                        on_result(index[ref], rt.get(ref))
                if bar is not None:
                    bar.update(len(done))
            return rt.get(refs)
        if processes <= 1 or len(jobs) <= 1:
            out = []
            for i, job in enumerate(jobs):
                out.append(fn(**job))
                _report(on_result, i, out[-1])
                if bar is not None:
                    bar.update(1)
            return out
        return _run_pool(fn, jobs, processes, bar, preload, on_result, meanwhile)
    finally:
        if bar is not None:
            bar.close()
