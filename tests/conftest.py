"""Shared fixtures. numba compiles each kernel once per source version (cached on disk, see
millvib_env._numba_cache); the first test that simulates pays it, the rest reuse it.

`python -m pytest --cpu-report FILE` writes where the suite's CPU goes: each test's CPU seconds, machine-wide (every
process on the machine, so a test's fresh interpreters, pool workers and Ray daemons count; run it on an idle
machine), its own (this process) and its waited-for children's, dearest first. A measurement, never an assertion.
"""
import gc
import os
import resource
import time

os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest
from hypothesis import settings

# Property-based tests are derandomized by default (the "ci" profile): the same commit always draws the
# same examples, so a suite's verdict never depends on the draw. A longer randomized fuzz is `HYPOTHESIS_PROFILE=fuzz
# python -m pytest tests/test_reliability.py tests/test_integrate.py tests/test_bad_input.py -q`
# (every property-based test draws at least the profile's 1,000 examples through `tests._fuzz.examples`, or
# MILLVIB_FUZZ_EXAMPLES); whatever it finds becomes a fixed example (@example or a plain test) in the suite.
settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
settings.register_profile("fuzz", max_examples=1000, derandomize=False, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

from millvib_env import MillParams, PIDGains
from millvib_env.analysis.paper import PAPER_STUDIES


@pytest.fixture(scope="session")
def paper_cases():
    """The paper's nine cases: (label, MillParams, PIDGains)."""
    return [(case.label, case.params, case.gains) for study in PAPER_STUDIES for case in study.cases]


@pytest.fixture(scope="session")
def random_draws():
    """50 plants and gains drawn log-uniformly over the ranges the fast integrator must cover."""
    rng = np.random.default_rng(20261122)
    n = 50
    c1 = np.exp(rng.uniform(np.log(1.25e5), np.log(2.25e6), n))
    ct = np.exp(rng.uniform(np.log(5e-16), np.log(5e-9), n))
    kp = np.exp(rng.uniform(np.log(1e4), np.log(4e6), n))
    return ([MillParams(c1=a, Ct=b) for a, b in zip(c1, ct)], [PIDGains(k, 1e-3, 0.0) for k in kp])


@pytest.fixture
def shipped_agents_copy(tmp_path, monkeypatch):
    """A copy of the shipped agents (and their manifest) that a test may damage: MILLVIB_AGENTS points at it."""
    import shutil

    from millvib_env._paths import agents_dir

    root = tmp_path / "agents"
    shutil.copytree(agents_dir(), root)
    monkeypatch.setenv("MILLVIB_AGENTS", str(root))
    return root


# The collector's full passes walk every object alive; by the end of collection that is torch's, JAX's and Ray's
# too. Collection (imports) runs without them, and after collection and after each test what is left is collected
# once and frozen (`gc.freeze`): a later full pass walks only what was made since. A run without this made 21 full
# passes over the whole heap, 5.0 CPU-s of the pytest process's 75; with it, about 1-2 CPU-s. Every test's own
# objects are still collected, at its end.
gc.disable()


def pytest_collection_finish(session):
    gc.enable()
    gc.collect()
    gc.freeze()


def pytest_runtest_teardown(item, nextitem):
    gc.collect()
    gc.freeze()


def pytest_addoption(parser):
    parser.addoption("--cpu-report", metavar="FILE", default=None,
                     help="write each test's CPU seconds (machine-wide, this process, its children), dearest first")


def pytest_configure(config):
    path = config.getoption("--cpu-report")
    if path is not None:
        from millvib_env._paths import check_output

        try:
            check_output(path, "--cpu-report")  # before the suite runs, not after
        except ValueError as err:
            raise pytest.UsageError(str(err)) from None


def _machine_cpu_s() -> float:
    """CPU seconds every processor has spent outside idle and I/O wait since boot (/proc/stat), or this process's
    and its waited-for children's where there is no /proc/stat."""
    try:
        with open("/proc/stat", encoding="ascii") as f:
            user, nice, system, _idle, _iowait, irq, softirq = map(int, f.readline().split()[1:8])
        return (user + nice + system + irq + softirq) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError):
        own, kids = _own_cpu_s()
        return own + kids


def _own_cpu_s() -> tuple[float, float]:
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime, kids.ru_utime + kids.ru_stime


_cpu_rows: list[tuple[float, float, float, float, str]] = []


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if not item.config.getoption("--cpu-report"):
        yield
        return
    machine, (own, kids), wall = _machine_cpu_s(), _own_cpu_s(), time.perf_counter()
    yield
    own1, kids1 = _own_cpu_s()
    _cpu_rows.append((_machine_cpu_s() - machine, own1 - own, kids1 - kids, time.perf_counter() - wall, item.nodeid))


def pytest_sessionfinish(session):
    path = session.config.getoption("--cpu-report")
    if not path or not _cpu_rows:
        return
    from millvib_env._paths import write_text_atomic

    lines = ["machine_cpu_s own_cpu_s children_cpu_s wall_s test"]
    lines += ["%.2f %.2f %.2f %.2f %s" % row for row in sorted(_cpu_rows, reverse=True)]
    totals = [sum(row[k] for row in _cpu_rows) for k in range(4)]
    lines.append("%.2f %.2f %.2f %.2f (all %d tests; collection and start-up not included)" % (*totals, len(_cpu_rows)))
    write_text_atomic(path, "\n".join(lines) + "\n")
