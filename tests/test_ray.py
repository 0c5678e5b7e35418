"""Scale-out: seeds, benchmark chunks and sweeps as Ray tasks on a local one-CPU cluster equal the local run."""
import pytest

pytestmark = pytest.mark.slow
ray = pytest.importorskip("ray")

from millvib_env.evaluation.benchmark import public_json, run_benchmark  # noqa: E402
from millvib_env.evaluation.sweep import run_sweep  # noqa: E402


@pytest.fixture(scope="module")
def local_cluster():
    # one CPU, so one worker: every job still goes through Ray (serialised, run in a worker, sent back); a second
    # worker would only import the package, torch and SB3 again (about 4 CPU-s of the module's 24)
    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"MILLVIB_NUM_THREADS": "1"}})
    yield ""
    ray.shutdown()


def test_a_sweep_on_ray_equals_the_local_run(local_cluster):
    kw = dict(task="startup", params=["c1", "Ct", "mt"], progress=False)
    local = run_sweep(["pid-robust"], 6, **kw)
    remote = run_sweep(["pid-robust"], 6, ray=local_cluster, **kw)
    assert local["records"] == remote["records"]
    assert min(r["mt"] for r in local["records"]["pid-robust"]) != max(r["mt"] for r in local["records"]["pid-robust"])


def test_a_benchmark_on_ray_equals_the_local_run(local_cluster):
    from millvib_env.catalog.agents import agent_seeds, list_agents

    # a baseline and an agent with every seed it ships, on two plants: the chunks of both kinds of job; the
    # reference is the baseline, so no third controller is added. On startup (1000 steps an episode, half of
    # rolling's); its named scenarios run in the calling process either way, so they are left out
    agents = [n for n in list_agents("startup") if len(agent_seeds(n)) >= 2][:1]
    kw = dict(task="startup", episodes=2, progress=False, all_seeds=True, reference="pid-robust", scenarios=False)
    local = public_json(run_benchmark(["pid-robust", *agents], **kw))
    remote = public_json(run_benchmark(["pid-robust", *agents], ray=local_cluster, **kw))
    assert local == remote
    assert all(local["controllers"][a]["n_seeds"] >= 2 for a in agents)


def test_seeds_train_as_ray_tasks_and_match_local_training(local_cluster, tmp_path):
    from millvib_env.training.train import train_seeds
    from tests.test_training import EXTRA, QUICK_VALIDATION, TINY

    cfg = tmp_path / "ppo.yml"
    cfg.write_text(TINY.format(policy="MlpPolicy", extra=EXTRA["ppo"]))
    kw = dict(algo="ppo", config=str(cfg), eval_freq=128, n_eval_episodes=2, checkpoint_freq=128,
              validation_episodes=QUICK_VALIDATION)
    on_ray = train_seeds([6, 7], ray=local_cluster, log_dir=str(tmp_path / "ray"), **kw)
    local = train_seeds([6, 7], jobs=1, log_dir=str(tmp_path / "local"), **kw)
    for a, b in zip(on_ray, local):
        assert a["seed"] == b["seed"] and a["validation"] == b["validation"]
