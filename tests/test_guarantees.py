"""Result folders never lose a user's data: what is refused, what is replaced, what is cleaned up."""
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from millvib_env._paths import RESULT_MARKER, atomic_folder, check_result_folder, clean_debris
from millvib_env.cli import main as cli_main

QUICK = ["benchmark", "--controllers", "pid-paper", "--reference", "pid-paper", "--episodes", "2", "--quiet",
         "--no-scenarios"]


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_folder_with_a_users_files_is_refused_and_left_as_it_was(tmp_path, capsys):
    out = tmp_path / "results"
    (out / "older_run").mkdir(parents=True)
    (out / "notes.txt").write_text("mine")
    assert cli_main(QUICK + ["--out", str(out)]) == 2
    assert "notes.txt" in _one_line_error(capsys)
    assert (out / "notes.txt").read_text() == "mine" and (out / "older_run").is_dir()


@pytest.mark.slow  # seconds of work: the full suite runs it, the quick subset does not
def test_a_previous_result_of_the_same_command_is_replaced_but_not_once_a_user_adds_a_file(tmp_path, capsys):
    out = tmp_path / "results"
    assert cli_main(QUICK + ["--out", str(out)]) == 0
    marker = json.loads((out / RESULT_MARKER).read_text())
    assert marker["command"] == "benchmark" and "benchmark.json" in marker["entries"]
    assert list(out.glob("*.png"))
    # its own previous result, replaced as a whole: without figures (--no-figures) the earlier ones are gone
    assert cli_main(QUICK + ["--out", str(out), "--no-figures"]) == 0
    assert not list(out.glob("*.png")) and (out / "benchmark.json").exists()
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert cli_main(QUICK + ["--out", str(out)]) == 2
    assert "notes.txt" in _one_line_error(capsys) and (out / "notes.txt").exists()
    with pytest.raises(ValueError, match="millvib benchmark"):
        check_result_folder(out.parent / "results", "--out", "sweep")  # another command's result


def test_a_full_disk_is_one_line_and_the_previous_result_stays(tmp_path, capsys, monkeypatch):
    """An OS fault while the result is written (here ENOSPC at the final rename) is one line, exit 2, no
    traceback, and the previous result is still there whole."""
    import errno

    out = tmp_path / "results"
    assert cli_main(QUICK + ["--out", str(out), "--no-figures"]) == 0  # the data files are enough here
    before = (out / "benchmark.json").read_bytes()
    capsys.readouterr()

    def full(src, dst):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(dst))

    monkeypatch.setattr(os, "replace", full)
    monkeypatch.setattr(os, "rename", full)
    assert cli_main(QUICK + ["--out", str(out), "--no-figures"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0] and "Traceback" not in err[0], err
    monkeypatch.undo()
    assert (out / "benchmark.json").read_bytes() == before


def test_a_failing_job_stops_the_other_workers_instead_of_waiting_for_them(tmp_path):
    """A job's error (as Ctrl-C or SIGTERM would) ends a local pool at once: the other workers are stopped,
    their jobs never finish, and no worker outlives the call."""
    import multiprocessing as mp

    from millvib_env.distributed import run_jobs
    from tests._jobs import fail_or_finish_late

    with pytest.raises(ValueError, match="job 0 failed"):
        run_jobs(fail_or_finish_late, [{"i": i, "folder": str(tmp_path)} for i in range(3)], processes=2)
    assert not [p for p in mp.active_children() if p.is_alive()]
    assert not list(tmp_path.glob("finished-*"))


def test_the_caller_runs_jobs_itself_while_its_workers_start_with_the_same_results(tmp_path, monkeypatch):
    """While the fork server imports (torch, for agents: seconds), `run_jobs` runs jobs of `meanwhile` in the calling
    process, from the last, and submits the others from the first: here the server's import waits until a job has
    run (`tests._gate`), so the last job is the caller's and the first a worker's. The results are in the jobs'
    order, and `on_result` hears of each job once."""
    import multiprocessing as mp

    from millvib_env.distributed import run_jobs
    from tests._jobs import open_the_gate

    gate = tmp_path / "gate"
    monkeypatch.setenv("MILLVIB_TEST_GATE", str(gate))
    heard = []
    out = run_jobs(open_the_gate, [{"i": i, "gate": str(gate)} for i in range(6)], processes=2,
                   preload=("tests._gate",), meanwhile=range(6), on_result=lambda i, r: heard.append((i, r)))
    assert [i for i, _ in out] == list(range(6)) and sorted(heard) == list(enumerate(out))
    assert out[-1][1] == os.getpid() and out[0][1] != os.getpid()
    assert not [p for p in mp.active_children() if p.is_alive()]


def test_a_job_that_fails_in_the_caller_stops_the_workers_too(tmp_path, monkeypatch):
    """A job of `meanwhile` that fails in the calling process ends the run as a worker's failure does: the workers
    are stopped and their jobs never finish."""
    import multiprocessing as mp

    from millvib_env.distributed import run_jobs
    from tests._jobs import open_the_gate

    gate = tmp_path / "gate"
    monkeypatch.setenv("MILLVIB_TEST_GATE", str(gate))
    jobs = [{"i": 0, "gate": str(gate), "folder": str(tmp_path)}, {"i": 1, "gate": str(gate), "folder": str(tmp_path)},
            {"i": 2, "gate": str(gate), "fail": True}]
    with pytest.raises(ValueError, match="job 2 failed"):
        run_jobs(open_the_gate, jobs, processes=2, preload=("tests._gate", "xml.dom.expatbuilder"), meanwhile=[2])
    assert not [p for p in mp.active_children() if p.is_alive()]
    assert not list(tmp_path.glob("finished-*"))


def test_a_pool_that_asks_for_more_modules_gets_workers_that_have_them_imported():
    """A later pool whose `preload` the running fork server lacks (torch, after a pool of baselines) restarts it:
    its workers start with the module imported instead of each importing it. So do the modules a command of
    several pools declares (`expect_modules`, `millvib reproduce --jobs N`), and only within its block."""
    from millvib_env import distributed
    from tests._jobs import modules_a_worker_has

    asked, declared = "xml.dom.minidom", "xml.dom.pulldom"  # imported by neither the package nor the tests
    distributed.run_jobs(modules_a_worker_has, [{"names": [asked]}] * 2, processes=2)  # a server without them
    with distributed.expect_modules(declared):
        assert distributed.run_jobs(modules_a_worker_has, [{"names": [asked, declared]}] * 2, processes=2,
                                    preload=(asked,)) == [[True, True]] * 2
    assert declared not in distributed._expected


def test_a_worker_starts_with_numbas_compiler_context_but_no_thread_pool():
    """The fork server loads one serial compiled function (`millvib_env._fork_server`), so a worker does not set up
    numba's compiler context again; numba's thread pool is never started in the server, so none is inherited."""
    from millvib_env.distributed import run_jobs
    from tests._jobs import numba_in_a_worker

    assert run_jobs(numba_in_a_worker, [{}] * 2, processes=2) == [(True, False)] * 2


def test_a_worker_runs_in_the_callers_environment_and_folder_as_they_are_at_each_pool(tmp_path, monkeypatch):
    """The workers are forks of a fork server that started with the first pool (`distributed._pool_context`):
    each still sees the caller's environment variables and working folder of the moment, and ignores Ctrl-C."""
    from millvib_env.distributed import run_jobs
    from tests._jobs import what_a_worker_sees

    monkeypatch.setenv("MILLVIB_TEST_MARK", "first")
    first = run_jobs(what_a_worker_sees, [{"name": "MILLVIB_TEST_MARK"}] * 2, processes=2)
    monkeypatch.setenv("MILLVIB_TEST_MARK", "second")
    monkeypatch.chdir(tmp_path)
    second = run_jobs(what_a_worker_sees, [{"name": "MILLVIB_TEST_MARK"}] * 2, processes=2)
    monkeypatch.delenv("MILLVIB_TEST_MARK")
    third = run_jobs(what_a_worker_sees, [{"name": "MILLVIB_TEST_MARK"}] * 2, processes=2)
    assert [r[0] for r in first + second + third] == ["first"] * 2 + ["second"] * 2 + [None] * 2
    assert [r[1] for r in second + third] == [str(tmp_path)] * 4
    assert all(r[2] for r in first + second + third)  # Ctrl-C is the parent's to handle
    assert os.getpid() not in {r[3] for r in first + second + third}


def test_workers_share_the_cores_unless_the_user_set_the_threads(monkeypatch):
    """A pool's workers run their plant batches on the usable cores over the workers (MILLVIB_NUM_THREADS, as
    joblib's workers limit theirs), and on the user's setting where there is one."""
    from millvib_env.distributed import run_jobs
    from millvib_env.threads import THREADS_ENV, usable_cores
    from tests._jobs import what_a_worker_sees

    monkeypatch.delenv(THREADS_ENV, raising=False)
    shared = run_jobs(what_a_worker_sees, [{"name": THREADS_ENV}] * 2, processes=2)
    assert [r[0] for r in shared] == [str(max(1, usable_cores() // 2))] * 2
    monkeypatch.setenv(THREADS_ENV, "3")
    assert [r[0] for r in run_jobs(what_a_worker_sees, [{"name": THREADS_ENV}] * 2, processes=2)] == ["3"] * 2
    assert THREADS_ENV not in os.environ or os.environ[THREADS_ENV] == "3"


@pytest.mark.parametrize("json_at", ["inside", "same"])
def test_another_output_of_the_run_inside_the_result_folder_is_refused(tmp_path, capsys, json_at):
    out = tmp_path / "D"
    js = out / "summary.json" if json_at == "inside" else out
    assert cli_main(QUICK + ["--json", str(js), "--out", str(out)]) == 2
    assert "--json" in _one_line_error(capsys)
    assert not out.exists()


def test_the_working_directory_is_never_a_result_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine.txt").write_text("x")
    for out in (".", str(tmp_path.parent)):
        assert cli_main(QUICK + ["--out", out]) == 2
        assert "working directory" in _one_line_error(capsys)
    assert (tmp_path / "mine.txt").exists()


def test_training_refuses_a_save_dir_that_overlaps_its_log_dir(tmp_path, capsys):
    out = str(tmp_path / "out")
    assert cli_main(["train", "--algo", "ppo", "--quiet", "--log-dir", out, "--save-dir", out]) == 2
    assert "--log-dir" in _one_line_error(capsys)


def test_debris_of_a_killed_write_is_removed_and_a_live_writers_is_kept(tmp_path):
    out = tmp_path / "results"
    with atomic_folder(out, command="benchmark") as tmp:
        (tmp / "a.txt").write_text("run 1")
    dead = tmp_path / ".results.killed.tmp"
    dead.mkdir()
    (dead / ".owner").write_text("999999999")  # no such process
    live = tmp_path / ".results.running.tmp"
    live.mkdir()
    (live / ".owner").write_text(str(os.getpid()))
    clean_debris(out)
    assert not dead.exists() and live.exists()


def test_a_writer_that_finishes_while_another_swaps_in_is_moved_aside_not_an_error(tmp_path, monkeypatch):
    """Two writers of one folder: the other one's result lands at the path between this one's two renames
    (ENOTEMPTY for a plain rename). It is moved aside in turn; the path holds this writer's files, whole,
    and nothing is left beside it."""
    real_replace = os.replace
    path = tmp_path / "out"
    path.mkdir()
    (path / "first.txt").write_text("the first result")
    raced = []

    def racing_replace(src, dst):
        if str(src).endswith(".tmp") and not raced:  # the other writer finishes first
            raced.append(True)
            other = tmp_path / "other"
            other.mkdir()
            (other / "other.txt").write_text("the other writer's")
            real_replace(other, dst)
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", racing_replace)
    with atomic_folder(path) as tmp:
        (tmp / "mine.txt").write_text("mine")
    assert raced and sorted(p.name for p in path.iterdir()) == ["mine.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_run_killed_between_the_two_renames_gets_its_old_result_back(tmp_path):
    out = tmp_path / "results"
    old = tmp_path / ".results.killed.old"
    (old / "x").mkdir(parents=True)
    (old / "x" / "a.txt").write_text("run 1")
    (old / ".owner").write_text("999999999")
    clean_debris(out)
    assert (out / "a.txt").read_text() == "run 1" and not old.exists()


def test_a_shipped_name_loads_the_shipped_agent_whatever_lies_in_the_working_directory(tmp_path, monkeypatch):
    import shutil

    from millvib_env._paths import agents_dir
    from millvib_env.catalog.factory import load_controller

    monkeypatch.chdir(tmp_path)
    # e.g. from train --save-dir ppo-gain-pf
    shutil.copytree(agents_dir() / "ppo-gain-pf" / "seed-0", tmp_path / "ppo-gain-pf")
    (tmp_path / "ppo-gain-pf" / "card.json").write_text(
        '{"algo": "ppo", "env_id": "MillVib-GainSchedule-v0", "seed": 7}')
    agent = load_controller("ppo-gain-pf")
    assert agent.shipped and agent.seed == 0
    assert not load_controller("./ppo-gain-pf").shipped  # a path is a path


def test_an_agent_is_refused_on_another_task_and_a_card_cannot_change_the_plants(tmp_path):
    import json
    import shutil

    from millvib_env._paths import agents_dir
    from millvib_env.catalog.factory import load_controller

    with pytest.raises(ValueError, match="trained on task 'startup', not 'rolling'"):
        load_controller("ppo-gain-pf", task="rolling")
    folder = tmp_path / "agent"
    shutil.copytree(agents_dir() / "ppo-gain-pf" / "seed-0", folder)
    card = json.loads((folder / "card.json").read_text())
    card["env_kwargs"] = {"randomize": {}}
    (folder / "card.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match="randomize"):
        load_controller(str(folder))
    card["env_kwargs"], card["normalize"] = {}, "false"
    (folder / "card.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match="normalize"):
        load_controller(str(folder))


def test_a_seed_folder_that_lost_its_card_is_an_error_not_a_silent_fallback(shipped_agents_copy):
    from millvib_env.catalog.factory import load_controller

    root = shipped_agents_copy
    (root / "ppo-gain-pf" / "seed-0" / "card.json").unlink()
    with pytest.raises(ValueError, match="card.json"):
        load_controller("ppo-gain-pf")


@pytest.mark.parametrize("t_start", [-0.5, 2.0, float("nan")])
def test_a_severity_window_outside_the_run_is_refused(t_start):
    from millvib_env import MillParams, PIDGains
    from millvib_env.plant.integrate import simulate

    run = simulate(MillParams(), PIDGains(1e5, 1e-3), 0.5)
    with pytest.raises(ValueError, match="t_start"):
        run.severity(t_start=t_start)


@pytest.mark.parametrize("call, name", [
    (lambda: __import__("millvib_env.plant.integrate", fromlist=["x"]).simulate(None, None, "1"), "t_end"),
    (lambda: __import__("millvib_env.severity", fromlist=["x"]).vibration_severity([0.0] * 5000, "a"), "fs"),
    (lambda: __import__("millvib_env.severity", fromlist=["x"]).iso_zone("3"), "severity_mm_s"),
    (lambda: __import__("millvib_env.catalog.factory", fromlist=["x"]).load_controller("ppo-gain-pf", seed="0"),
     "seed"),
    (lambda: __import__("millvib_env.evaluation.benchmark", fromlist=["x"]).run_benchmark("pid-paper", episodes=2,
                                                                                        progress=False),
     "controllers"),
    (lambda: __import__("millvib_env.plant.integrate", fromlist=["x"]).simulate(x0=-0.15), "x0"),
    (lambda: __import__("millvib_env.plant.integrate", fromlist=["x"]).simulate(t_end=10 ** 400), "t_end"),
    (lambda: __import__("millvib_env.plant.integrate", fromlist=["x"]).simulate(
        __import__("millvib_env").MillParams(dp_reg=1e300)), "dp_reg"),
    (lambda: __import__("millvib_env").MillParams(c1=10 ** 400), "c1"),
    (lambda: __import__("gymnasium").make("MillVib-GainSchedule-v1", config="rolling", reward={"w_offset": 1e308}),
     "w_offset"),
    (lambda: __import__("gymnasium").make("MillVib-Valve-v1", config="rolling",
                                          reward={"vibration_scale_mm_s": 1e-300}), "vibration_scale_mm_s"),
    (lambda: __import__("millvib_env").PIDGains(1.0, 10 ** 400, 0.0), "ki"),
])
def test_api_arguments_of_the_wrong_type_are_a_valueerror_naming_them(call, name):
    with pytest.raises(ValueError, match=name):
        call()


def _damage_card(card: dict, how: str):
    if how == "env_kwargs null":
        card["env_kwargs"] = None
    elif how == "env_kwargs a list":
        card["env_kwargs"] = [1, 2]
    elif how == "seed beyond a float":
        return json.dumps(card).replace('"seed": 0', '"seed": 1e400')
    elif how == "nested deeply":
        return '{"algo": "ppo", "env_id": "MillVib-GainSchedule-v0", "x": ' + "[" * 100000 + "]" * 100000 + "}"
    elif how == "not an object":
        return "[1, 2]"
    return json.dumps(card)


@pytest.mark.parametrize("how", ["env_kwargs null", "env_kwargs a list", "seed beyond a float", "nested deeply",
                                 "not an object", "a folder"])
def test_a_damaged_card_is_refused_in_one_line_naming_it(tmp_path, how):
    """An agent's card is data: each way of damaging it is a ValueError of one line naming card.json."""
    import shutil

    from millvib_env._paths import agents_dir
    from millvib_env.catalog.factory import load_controller

    folder = tmp_path / "agent"
    shutil.copytree(agents_dir() / "ppo-gain-pf" / "seed-0", folder)
    path = folder / "card.json"
    card = json.loads(path.read_text())
    path.unlink()
    if how == "a folder":
        path.mkdir()
    else:
        path.write_text(_damage_card(card, how))
    with pytest.raises(ValueError) as info:
        load_controller(str(folder))
    assert "card.json" in str(info.value) and "\n" not in str(info.value), str(info.value)


@pytest.mark.parametrize("key, value", [("clip_obs", 0.0), ("clip_obs", -1.0), ("epsilon", -1e-8),
                                        ("epsilon", float("nan")), ("count", float("inf"))])
def test_damaged_normalisation_statistics_are_refused_not_run(tmp_path, key, value):
    """clip_obs <= 0 would feed the policy constant observations (a silently wrong result); each is refused in
    one line naming the file."""
    import shutil

    import numpy as np

    from millvib_env._paths import agents_dir
    from millvib_env.catalog.factory import load_controller

    folder = tmp_path / "agent"
    shutil.copytree(agents_dir() / "ppo-gain-pf" / "seed-0", folder)
    path = folder / "vecnormalize.npz"
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays[key] = np.float64(value)
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    with pytest.raises(ValueError, match=key) as info:
        load_controller(str(folder))
    assert "vecnormalize.npz" in str(info.value) and "\n" not in str(info.value)


def _default_ctrl_c() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _millvib(*args: str, **popen) -> subprocess.Popen:
    """The command in a child whose Ctrl-C is the default even where the suite runs with it ignored (a
    non-interactive shell's `cmd &` ignores SIGINT, and a child inherits that: Python then keeps it ignored)."""
    return subprocess.Popen([sys.executable, "-c", "import sys; from millvib_cli import main; sys.exit(main())",
                             *args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_ctrl_c, **popen)


def _process_table() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, command line) of every process readable now."""
    table = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            cmdline = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # gone meanwhile
            continue
        table[int(stat.parent.name)] = (int(fields[1]), cmdline)
    return table


def _descendants(pid: int, table: dict[int, tuple[int, str]] | None = None) -> list[int]:
    """Every process below `pid`: the pool's workers, multiprocessing's resource tracker and fork server."""
    table = _process_table() if table is None else table
    found, frontier = [], [pid]
    while frontier:
        kids = [p for p, (ppid, _) in table.items() if ppid in frontier]
        found += kids
        frontier = kids
    return found


def _workers(pid: int) -> list[int]:
    """The pool's workers below `pid` (spawned ones are its children; a fork server's, its grandchildren)."""
    table = _process_table()
    return [p for p in _descendants(pid, table) if p in table and "resource_tracker" not in table[p][1]
            and not (table[p][0] == pid and "forkserver" in table[p][1])]


def _ignores_ctrl_c(pid: int) -> bool:
    """Whether process `pid` ignores SIGINT now (the SigIgn mask of /proc/<pid>/status)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    ignored = next((line.split()[1] for line in status.splitlines() if line.startswith("SigIgn:")), "0")
    return bool(int(ignored, 16) >> (signal.SIGINT - 1) & 1)


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _assert_ended(workers: list[int]) -> None:
    end = time.monotonic() + 30
    while any(_alive(w) for w in workers):  # stopped by the parent before it left, or being reaped
        assert time.monotonic() < end, f"workers {[w for w in workers if _alive(w)]} outlived the command"
        time.sleep(0.02)


def _wait_for(condition, proc, what: str, limit_s: float = 300.0) -> None:
    end = time.monotonic() + limit_s
    while not condition():
        assert proc.poll() is None, f"the command ended before {what}"
        assert time.monotonic() < end, f"no {what} within {limit_s} s"
        time.sleep(0.02)


def test_ctrl_c_while_the_package_loads_is_one_line_not_a_traceback():
    """The launcher (`millvib_cli`) catches Ctrl-C before anything heavy loads: here it arrives while numpy
    and the package import (raised by an import hook, so the moment is certain)."""
    import subprocess
    import sys

    hook = ("import sys\n"
            "class Interrupt:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name == 'millvib_env.params': raise KeyboardInterrupt\n"
            "sys.meta_path.insert(0, Interrupt())\n"
            "from millvib_cli import main\n"
            "sys.exit(main())\n")
    run = subprocess.run([sys.executable, "-c", hook, "tasks"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 130
    assert run.stderr.strip().splitlines() == ["millvib: interrupted while loading"]


def test_the_launcher_turns_numpys_huge_pages_and_blas_threads_off_before_numpy_loads_unless_the_user_chose():
    """`millvib` sets NUMPY_MADVISE_HUGEPAGE=0 and OPENBLAS_NUM_THREADS=1 before numpy loads
    (`millvib_cli._process_defaults`); a user's own settings are kept."""
    code = ("import os\n"
            "from millvib_cli import _process_defaults\n"
            "_process_defaults()\n"
            "import numpy\n"
            "from threadpoolctl import threadpool_info\n"
            "blas = [lib['num_threads'] for lib in threadpool_info() if lib['internal_api'] == 'openblas']\n"
            "print(os.environ['NUMPY_MADVISE_HUGEPAGE'], numpy._core.multiarray._get_madvise_hugepage(),\n"
            "      os.environ['OPENBLAS_NUM_THREADS'], set(blas) <= {1})\n")
    # numpy's OpenBLAS on one thread; a user's 2 is kept (how many threads it then runs depends on the cores)
    for given, want in (({}, "0 False 1 True"), ({"NUMPY_MADVISE_HUGEPAGE": "1", "OPENBLAS_NUM_THREADS": "2"},
                                                  "1 True 2")):
        env = {k: v for k, v in os.environ.items() if k not in ("NUMPY_MADVISE_HUGEPAGE", "OPENBLAS_NUM_THREADS")}
        env.update(given)
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
        assert run.stdout.split()[:len(want.split())] == want.split(), run.stderr


@pytest.mark.slow  # seconds of work: the full suite runs it, the quick subset does not
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
def test_sigterm_and_a_group_ctrl_c_end_a_command_and_its_workers_in_one_line(tmp_path):
    """SIGTERM to a running command: one line, 143. Ctrl-C to the whole process group (what a terminal
    sends) once the workers of `sweep --jobs 2` are up: one line, 130, no worker's traceback, no worker
    left, and the result folder not written."""
    long_sweep = ["sweep", "--controllers", "pid-nominal", "pid-paper", "--plants", "400", "--quiet"]
    proc = _millvib(*long_sweep, "--jobs", "2", "--out", str(tmp_path / "a"))
    _wait_for(lambda: len(_workers(proc.pid)) >= 2, proc, "two workers")
    workers = _descendants(proc.pid)  # the workers, the resource tracker and the fork server
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=300)[1]
    assert proc.returncode == 143 and _ended_line(err.strip().splitlines()[-1], "millvib sweep: terminated"), err
    assert "Traceback" not in err
    _assert_ended(workers)

    proc = _millvib(*long_sweep, "--jobs", "2", "--out", str(tmp_path / "b"), start_new_session=True)
    _wait_for(lambda: len(_workers(proc.pid)) >= 2 and not _ignores_ctrl_c(proc.pid), proc,
              "two workers and the parent's Ctrl-C handler back")  # it ignores Ctrl-C while it starts them
    workers = _descendants(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)
    err = proc.communicate(timeout=300)[1]
    lines = err.strip().splitlines()
    assert proc.returncode == 130 and len(lines) == 1 and _ended_line(lines[0], "millvib sweep: interrupted"), err
    _assert_ended(workers)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def _ended_line(line: str, ended: str) -> bool:
    """The one line of a command a signal ended: `ended` alone, or with what a long command kept so far (the
    finished jobs of a sweep, entries of a tune) and how to go on from it."""
    return line == ended or (line.startswith(ended + "; ") and "kept in" in line and "--resume" in line)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a child subreaper is Linux's (prctl)")
def test_cpu_time_waits_for_the_orphans_a_command_leaves_and_keeps_its_exit_status(tmp_path):
    """`scripts/cpu_time.py` (how the suite's and a pool's CPU time are measured): a process that outlives the
    command, as a fork server does, is waited for before the line is printed; the command's status is kept."""
    import subprocess

    marker = tmp_path / "orphan-done"
    orphan = ("import os, sys, time\n"
              "if os.fork() == 0:\n"
              "    os.close(1); os.close(2)  # not holding the caller's pipes open\n"
              f"    time.sleep(0.5); open({str(marker)!r}, 'w').close(); os._exit(0)\n"
              "sys.exit(3)\n")
    run = subprocess.run([sys.executable, str(Path(__file__).parents[1] / "scripts" / "cpu_time.py"),
                          sys.executable, "-c", orphan], capture_output=True, text=True, timeout=120)
    assert run.returncode == 3 and marker.exists(), run.stderr
    assert run.stderr.strip().splitlines()[-1].startswith("cpu_time: exit 3, ")


def _cpu_s(pid: int) -> float:
    """The CPU time (user + system, s) process `pid` has used so far (0 where it cannot be read)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@pytest.fixture(scope="module")
def mpc_run_compiled():
    """The run below once to its end, so that its kernels are in numba's cache and the Ctrl-C lands in the MPC's
    solves, what the test is about (in a fresh cache, as `../shared/tools/other-machine` gives, it could land in
    LLVM's compilation, whose callbacks swallow it; the next step raises it again, `millvib_env._interrupt`)."""
    subprocess.run([sys.executable, "-c", "import sys; from millvib_cli import main; sys.exit(main())", "benchmark",
                    *MPC_RUN], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True, timeout=900)


#: the run the test interrupts, and runs once whole before (its batch of 60 plants compiles kernels one plant does
#: not; long enough that 3.5 CPU-s fall within its MPC rows on a fast machine: about 5 CPU-s in all)
MPC_RUN = ("--task", "rolling", "--controllers", "mpc-preview", "--episodes", "60", "--jobs", "1", "--no-scenarios",
           "--quiet")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("after_cpu_s", [1.5, 2.0, 2.5, 3.0, 3.5])
def test_ctrl_c_during_the_mpc_bounds_ends_the_benchmark_in_one_line_and_writes_nothing(tmp_path, after_cpu_s,
                                                                                       mpc_run_compiled):
    """A Ctrl-C while `mpc-preview` runs (its quadratic programme at every loop sample) ends the command: one line,
    130, no result (not a finished run on one interrupted solve's answer, which the OSQP solver the bounds had
    before gave about one time in five here: it caught the signal with its own handler)."""
    out = tmp_path / "b.json"
    proc = _millvib("benchmark", *MPC_RUN, "--json", str(out))
    _wait_for(lambda: _cpu_s(proc.pid) >= after_cpu_s, proc, f"{after_cpu_s} CPU-s of the run")
    proc.send_signal(signal.SIGINT)
    err = proc.communicate(timeout=300)[1]
    assert proc.returncode == 130 and err.strip().splitlines() == ["millvib benchmark: interrupted"], err
    assert not out.exists()


#: the long commands a Ctrl-C is sent into (each writes what `{out}` names; small, so the test stays short)
LONG_COMMANDS = {
    "benchmark": ["benchmark", *MPC_RUN, "--json", "{out}/b.json"],
    "tune": ["tune", "--task", "startup", "--only", "pid-nominal", "--quiet", "--out", "{out}/tuned.yaml"],
    "distill": ["distill", "--task", "startup", "--iterations", "2", "--episodes", "4", "--epochs", "1",
                "--validation-episodes", "2", "--quiet", "--save-dir", "{out}/agent"],
    "train": ["train", "--algo", "ppo", "--task", "startup", "--n-timesteps", "20000", "--quiet",
              "--log-dir", "{out}/runs", "--save-dir", "{out}/agent"],
    "reproduce": ["reproduce", "--t-end", "0.3", "--resolution", "12", "--quiet", "--out", "{out}/paper"],
}
#: moments per command: 3 in the suite; MILLVIB_CTRL_C_MOMENTS=20 for the soak (`pytest -m slow -s -k random_times`,
#: which prints each command's latencies from the signal to the exit)
CTRL_C_MOMENTS = int(os.environ.get("MILLVIB_CTRL_C_MOMENTS", "3"))


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("command", sorted(LONG_COMMANDS))
def test_ctrl_c_at_random_times_ends_every_long_command_in_one_line_and_writes_nothing(tmp_path, command, request):
    """Ctrl-C at random moments of a command's run (by its CPU time, whichever library holds the signal then:
    numba, torch, SB3, DAQP, the tuner, the worker pool): 130, one line, nothing written, no process left."""
    import random

    if command == "benchmark":
        request.getfixturevalue("mpc_run_compiled")  # the Ctrl-C lands in the MPC's solves, not in compilation
    rng = random.Random(f"ctrl-c {command}")  # the same moments on every run of the suite
    interrupted, latencies = 0, []
    for k in range(CTRL_C_MOMENTS):
        out = tmp_path / f"run{k}"
        out.mkdir()
        args = [a.format(out=out) for a in LONG_COMMANDS[command]]
        proc = _millvib(*args)
        after = rng.uniform(1.0, 4.0)
        try:
            _wait_for(lambda: _cpu_s(proc.pid) >= after, proc, f"{after:.2f} CPU-s of the run")
        except AssertionError:  # it ended first: nothing to interrupt this time
            continue
        family = _descendants(proc.pid)
        sent = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        err = proc.communicate(timeout=60)[1]
        if proc.returncode == 0 and not err.strip():  # it had finished its work when the signal came: all written
            result = Path(next(a for a in args if a.startswith(str(out))))
            assert result.is_file() or (result.is_dir() and any(result.iterdir())), result
            continue
        latencies.append(time.perf_counter() - sent)
        lines = err.strip().splitlines()
        assert proc.returncode == 130 and len(lines) == 1, err
        assert _ended_line(lines[0], f"millvib {command}: interrupted"), err
        written = [p for p in out.rglob("*") if p.is_file() and "runs" not in p.relative_to(out).parts
                   and not (any(part.endswith(".partial") for part in p.relative_to(out).parts)
                            and "kept in" in lines[0])]
        assert not written, written  # the log folder of `train` (TensorBoard, checkpoints) is no result, nor the
        # journal of a tune's finished entries or a distillation's iterations that the line names
        _assert_ended(family)
        interrupted += 1
    assert interrupted >= 2 * CTRL_C_MOMENTS // 3
    print(f"\n{command}: {interrupted} of {CTRL_C_MOMENTS} moments interrupted; signal to exit "
          f"{min(latencies):.2f}-{max(latencies):.2f} s")


def _swallowed_ctrl_c():
    """A Ctrl-C that a library's callback catches and drops (llvmlite's while numba compiles does)."""
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(1.0)  # the handler runs here
    except KeyboardInterrupt:
        pass


def _ctrl_c_in_a_callback():
    """A Ctrl-C that arrives in a weakref's callback, which Python cannot raise: it drops it and would print it as an
    "Exception ignored" traceback (as in the garbage collector's callbacks, or llvmlite's)."""
    import weakref

    class Thing:
        pass

    def callback(_):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(1.0)

    thing = Thing()
    ref = weakref.ref(thing, callback)
    del thing
    assert ref() is None


def _ctrl_c_as_a_librarys_error():
    """A Ctrl-C that a library turns into an error of its own (numba, where the signal lands while a compiled
    function unpickles its constants: 'returned a result with an exception set', a SystemError)."""
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(1.0)  # the handler runs here
    except KeyboardInterrupt as err:
        raise SystemError("CPUDispatcher(<function f>) returned a result with an exception set") from err


@pytest.mark.parametrize("where", ["a step", "a callback", "a library's error", "the end"])
def test_a_ctrl_c_a_library_swallowed_still_ends_the_run_and_writes_nothing(tmp_path, monkeypatch, capsys, where):
    """Between the environment's steps (the run ends at the next step), in a callback Python cannot raise from, as
    a library's own error, or after the last step (the result's commit refuses): exit 130 in one line, the previous
    result intact."""
    import millvib_env.evaluation.benchmark as bench
    from millvib_env.envs.batch import EpisodeBatch
    from millvib_env.evaluation.benchmark import comparison, run

    out = tmp_path / "result.json"
    out.write_text("old")
    monkeypatch.setattr(sys, "unraisablehook", sys.__unraisablehook__)  # Python's own, which prints (pytest's does not)
    if where in ("a step", "a callback", "a library's error"):
        reset = EpisodeBatch.reset
        how = {"a step": _swallowed_ctrl_c, "a callback": _ctrl_c_in_a_callback,
               "a library's error": _ctrl_c_as_a_librarys_error}[where]

        def swallowing_reset(self, *a, **k):
            how()
            return reset(self, *a, **k)
        monkeypatch.setattr(EpisodeBatch, "reset", swallowing_reset)
    else:
        summarize = bench.summarize

        def swallowing_summary(*a, **k):
            _swallowed_ctrl_c()
            return summarize(*a, **k)
        for where in (run, comparison):  # where the summaries are made
            monkeypatch.setattr(where, "summarize", swallowing_summary)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # Ctrl-C as a terminal's foreground gets it
    try:
        status = cli_main(["benchmark", "--controllers", "pid-robust", "--episodes", "2", "--json", str(out),
                           "--quiet"])
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the command's handler is gone after it
    finally:
        signal.signal(signal.SIGINT, before)
    err = capsys.readouterr().err
    assert status == 130 and err.strip() == "millvib benchmark: interrupted"
    assert out.read_text() == "old"


@pytest.mark.parametrize("args, name", [
    (["benchmark", "--task", "rolling", "--controllers", "pid-paper", "--episodes", "2", "--quiet", "--json"],
     "b.json"),
    (["simulate", "--t-end", "0.2", "--csv"], "run.csv"),
    (["simulate", "--t-end", "0.2", "--plot"], "run.png"),
    (["benchmark", "--task", "rolling", "--controllers", "pid-paper", "--episodes", "2", "--quiet", "--no-figures",
      "--out"], "results"),
])
def test_a_full_disk_is_a_failure_naming_the_file_and_the_old_result_stays(tmp_path, monkeypatch, capsys, args, name):
    """A file system that takes a write into its cache and finds no room when it writes it back (ENOSPC at
    fsync), on every kind of output (a JSON, a CSV, a figure, a result folder; a config is written the same way,
`_paths.atomic_path`): exit 2 in one line that
    names what the user asked for, and the previous result is as it was, with nothing left beside it."""
    import errno

    old = tmp_path / name
    if "." in name:
        old.write_text("the previous result")
    else:  # a folder: the command's own previous result
        assert cli_main(args + [str(old)]) == 0
        capsys.readouterr()
    before = old.read_bytes() if old.is_file() else (old / "benchmark.json").read_bytes()

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    rc = cli_main(args + [str(old)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "No space left on device" in err[0] and str(old) in err[0], err
    assert (old.read_bytes() if old.is_file() else (old / "benchmark.json").read_bytes()) == before
    assert [p.name for p in tmp_path.iterdir()] == [name]  # no temporary file left beside it


def _readme_blocks(lang: str) -> list[str]:
    text = (Path(__file__).parents[1] / "README.md").read_text()
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_readmes_commands_work_from_an_empty_directory(tmp_path):
    """Every `millvib` line of the README's command blocks, run in turn from an empty directory outside the clone
    (the installed package alone): each ends with 0, or is still at work after 15 CPU-s (its names, files and
    shipped configs all found: a name it cannot find is exit 2 within a second or two), then ends in one line at
    a Ctrl-C. The README's Python blocks run there too."""
    lines = [ln.split("  #")[0].strip() for block in _readme_blocks("bash") for ln in block.splitlines()]
    commands = [shlex.split(ln)[1:] for ln in lines if ln.startswith("millvib ")]
    assert len(commands) >= 10
    for args in commands:
        proc = _millvib(*args, cwd=tmp_path)
        try:
            _wait_for(lambda: _cpu_s(proc.pid) >= 15.0, proc, "15 CPU-s")
        except AssertionError:  # it ended first
            err = proc.communicate(timeout=60)[1]
            assert proc.returncode == 0, f"millvib {' '.join(args)}: {err}"
            continue
        proc.send_signal(signal.SIGINT)
        err = proc.communicate(timeout=60)[1]  # the progress bars (no --quiet), then the one line
        last = err.strip().splitlines()[-1]
        assert proc.returncode == 130 and _ended_line(last, f"millvib {args[0]}: interrupted"), err
        assert "Traceback" not in err
    for code in _readme_blocks("python"):
        run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True,
                             timeout=600)
        assert run.returncode == 0, run.stderr
