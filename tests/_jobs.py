"""Jobs for the worker-pool tests: importable by a spawned worker without the test modules' imports."""
import time
from pathlib import Path


def fail_or_finish_late(i: int, folder: str) -> int:
    """Job 0 fails at once; the others would write a file after 30 s."""
    if i == 0:
        raise ValueError("job 0 failed")
    time.sleep(30)
    Path(folder, f"finished-{i}").write_text("late")
    return i


def what_a_worker_sees(name: str) -> tuple:
    """A worker's view: the environment variable `name`, its working folder, whether it ignores Ctrl-C, its pid."""
    import os
    import signal

    return os.environ.get(name), os.getcwd(), signal.getsignal(signal.SIGINT) is signal.SIG_IGN, os.getpid()


def modules_a_worker_has(names: list) -> list:
    """Whether each module in `names` is imported in this worker when its job starts."""
    import sys

    return [n in sys.modules for n in names]


def tune_in_a_shared_study(storage: str, study_name: str, n_trials: int) -> dict:
    """`n_trials` trials of startup's PID study in `storage`, as a second terminal's `millvib tune --optuna` would."""
    from millvib_env.tasks import get_task
    from millvib_env.tuning.search import tune_optuna

    return tune_optuna([10100, 10101], task=get_task("startup"), storage=storage, study_name=study_name,
                       n_trials=n_trials)


def numba_in_a_worker() -> tuple:
    """At its job's start: whether this worker already holds the compiled plant function (numba's compiler
    context set up by the fork server), and whether numba's thread pool has started (it must not be inherited)."""
    from numba.np.ufunc import parallel

    from millvib_env.plant.model import plant_rhs

    return len(plant_rhs.overloads) > 0, bool(parallel._is_initialized)


def open_the_gate(i: int, gate: str, fail: bool = False, folder: str | None = None) -> tuple:
    """Opens `tests._gate`'s gate (the workers may start), then fails (`fail`), finishes after 30 s writing a file
    in `folder`, or returns at once (i, the pid of the process that ran it)."""
    import os

    Path(gate).write_text("open")
    if fail:
        raise ValueError(f"job {i} failed")
    if folder is not None:
        time.sleep(30)
        Path(folder, f"finished-{i}").write_text("late")
    return i, os.getpid()
