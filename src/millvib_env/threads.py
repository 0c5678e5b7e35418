"""How the compiled kernels use threads: by measurement, with one documented knob.

* Small batches (fewer than `MIN_PARALLEL` plants: the single env, small vector envs) run serially
  and never start a thread pool.
* Larger batches use numba's threads (`prange` over plants); their number is numba's, i.e. every
  core, unless ``MILLVIB_NUM_THREADS`` says otherwise (the knob: an integer >= 1; 1 = always serial).
* Fork-based vectorisation (``gym.make_vec(..., vectorization_mode="async")``, SB3's
  ``SubprocVecEnv(start_method="fork")``) works after the parent has stepped a threaded batch and
  run torch: its workers step single environments, which run serially and never touch the
  parent's OpenMP pool (a forked child that did would abort: "fork() called from a process already
  using GNU OpenMP"). The threading layer stays numba's default (OpenMP here): measured on 64 valve
  envs it stepped 75k env steps/s against 45k for the fork-safe ``workqueue`` layer.
  ``NUMBA_THREADING_LAYER=workqueue`` chooses the latter where a forked child must run large
  batches itself.
* Idle OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE``, set when the package is imported unless
  the user set a policy): spinning threads made a loaded machine step slower than serial (docs/performance.md).
* `millvib train` runs the plant serially (MILLVIB_NUM_THREADS unset means 1 there): the learner
  takes most of the wall time and idle numba threads slow torch.
"""

from __future__ import annotations

import os

from millvib_env._checks import shown

__all__ = ["MIN_PARALLEL", "usable_cores", "use_threads", "numba_threads", "configured_threads", "set_num_threads",
           "serial_unless_set", "THREADS_ENV", "passive_waiting", "one_blas_thread", "one_xla_thread", "XLA_ONE_THREAD",
           "one_torch_thread"]

THREADS_ENV = "MILLVIB_NUM_THREADS"
#: batches smaller than this run serially
MIN_PARALLEL = 8

_override: int | None = None


def passive_waiting() -> None:
    """Make idle OpenMP threads sleep instead of spin (OMP_WAIT_POLICY=PASSIVE), unless the user set a
    policy: called when the package is imported, before numba's thread pool (GNU OpenMP here) starts.
    Measured by `python scripts/thread_bench.py` (docs/performance.md)."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


#: XLA's CPU flags for one thread per learner (sbx): measured with SAC on the gain-schedule env
#: (docs/performance.md), 1,264 against 1,164 steps/s idle and 801 against 759 beside a 2-core hog
XLA_ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def one_xla_thread() -> None:
    """Run JAX's CPU computations on one thread (``XLA_FLAGS``), unless the user set XLA flags: a
    learner's networks are small, and two trainings share a 2-core machine. Takes effect only before
    JAX's first computation, so `catalog.agents.algo_class` calls it before importing sbx."""
    os.environ.setdefault("XLA_FLAGS", XLA_ONE_THREAD)


def one_torch_thread() -> None:
    """Run torch on one thread where a trained agent acts (`catalog.agents.AgentPolicy`), unless the user set
    OMP_NUM_THREADS: an agent's network is small, and waking torch's other threads for each of its products costs
    more than they give. Measured on the rolling student, 40 plants in one process (`docs/performance.md`): 2.2 s
    against 2.9-3.5 s with torch's default two threads here. How a product is split over threads can round its
    float32 sums differently: the rolling rows were the same bit for bit, the startup student's on 6 plants moved
    by 2e-6 relative. Torch's default is the core count, so one thread also makes an agent's actions independent
    of the machine's cores. Training sets one thread itself (`training.train`, `distill`, `finetune`)."""
    if "OMP_NUM_THREADS" in os.environ:
        return
    import torch

    if torch.get_num_threads() != 1:
        torch.set_num_threads(1)


class one_blas_thread:
    """Context: BLAS on one thread (threadpoolctl) around small dense solves (the LQR's 4 x 4 Riccati
    equation: OpenBLAS's threads cost it tens of times more on a loaded machine; docs/performance.md). The
    libraries are inspected once per process, not per solve."""

    _controller = None

    def __enter__(self):
        from threadpoolctl import ThreadpoolController

        if one_blas_thread._controller is None:
            one_blas_thread._controller = ThreadpoolController()
        self._ctx = one_blas_thread._controller.limit(limits=1, user_api="blas")
        return self

    def __exit__(self, *exc) -> None:
        self._ctx.restore_original_limits()


def usable_cores() -> int:
    """The cores this process may run on (its affinity where the platform says, else every core)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def configured_threads() -> int | None:
    """The knob's value (None: not set), from `set_num_threads` or MILLVIB_NUM_THREADS."""
    if _override is not None:
        return _override
    raw = os.environ.get(THREADS_ENV)
    if raw is None or raw.strip() == "":
        return None
    try:
        value = int(raw)
    except ValueError:
        raise ValueError(f"{THREADS_ENV} = {shown(raw)} is invalid: an integer >= 1") from None
    if value < 1:
        raise ValueError(f"{THREADS_ENV} = {shown(raw)} is invalid: an integer >= 1")
    return value


def set_num_threads(n: int | None) -> None:
    """Set the knob from code (None: back to MILLVIB_NUM_THREADS / numba's default)."""
    global _override
    if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
        raise ValueError(f"threads = {shown(n)} is invalid: an integer >= 1 or None")
    _override = n


def use_threads(n_plants: int, purpose: str = "") -> bool:
    """Whether a batch of `n_plants` runs on threads (and with how many: numba's setting)."""
    wanted = configured_threads()
    if wanted == 1 or n_plants < MIN_PARALLEL:
        return False
    import numba

    if wanted is not None:
        numba.set_num_threads(min(wanted, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    return numba.get_num_threads() > 1


def numba_threads() -> int:
    """How many threads a threaded batch runs on now (numba's setting, after `use_threads`)."""
    import numba

    return numba.get_num_threads()


class serial_unless_set:
    """Context: run the plant serially inside, unless the knob is set; restores the knob after."""

    def __enter__(self):
        self._saved = _override
        if configured_threads() is None:
            set_num_threads(1)
        return self

    def __exit__(self, *exc) -> None:
        set_num_threads(self._saved)
