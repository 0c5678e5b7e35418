"""An experiment: evolution strategies on a distilled student's output layer, scored by the episode's cost on the
same training plants for every candidate of a generation (common random numbers).

    MILLVIB_NUM_THREADS=1 python scripts/es_output_layer.py agents/dagger-on-pid-pf-preview-rolling/seed-0 \
        --sigma 0.003 --generations 30 --out /tmp/es-rolling-0

PPO's advantages at the loop's 2 kHz carry the noise of every disturbance of an episode (`millvib finetune`
gains 0.1 % on rolling). Here the objective is the benchmark's own cost, and the noise is cancelled instead of
learned: each generation draws `--plants` of the student seed's training plants, and every candidate runs on those
same plants. The search moves only the output layer (the 256 weights and the bias that turn the student's last
hidden layer into its residual command): antithetic pairs theta +- sigma eps, the gradient estimate
sum (cost+ - cost-) eps / (2 sigma pairs) (Salimans et al., 2017) and an Adam step of sigma / 2. Every third
generation the student with the new layer is scored on the 40 validation plants the distillation selected on;
the best of those (never the student itself) is written as an agent folder, `--save-dir` (the student's statistics
and network with the new layer, and a card: the student it started from, every score, the one kept, the command).
`scripts/validation_pairs.py STUDENT SAVE_DIR` checks a result on validation plants no score used.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch

from millvib_env._paths import write_text_atomic
from millvib_env.catalog.agents import AgentPolicy
from millvib_env.evaluation.evaluate import run_episodes


class RowLinear(torch.nn.Module):
    """An output layer per row of the batch: row r of the observations uses candidate r // plants's weights and
    bias (`thetas`: one row of in_features weights and a bias per candidate)."""

    def __init__(self, thetas: np.ndarray, plants: int, in_features: int):
        super().__init__()
        rows = torch.as_tensor(np.repeat(thetas, plants, axis=0), dtype=torch.float32)
        self.weight, self.bias = rows[:, :in_features], rows[:, in_features:]

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        return (latent * self.weight).sum(dim=1, keepdim=True) + self.bias


def model_with(student: Path, net, theta: np.ndarray, use):
    """The student's SB3 model with the output layer `theta`."""
    from stable_baselines3 import PPO

    model = PPO.load(student / "model.zip", device="cpu")
    use(theta)
    model.policy.action_net.load_state_dict(net.state_dict())
    return model


def save_card(student: Path, dest: Path, model, curve: list, gen: int, wall: float, a) -> None:
    """The agent folder: the student's statistics, `model`, and a card that says how it was made."""
    from millvib_env._paths import atomic_folder
    from millvib_env.catalog.agents import read_card
    from millvib_env.training.train import validation_result

    own = read_card(student / "card.json")
    card = {k: v for k, v in own.items() if k not in ("iterations", "selected", "validation", "trained_by", "command",
                                                      "wall_time_s", "n_timesteps")}
    card.update({
        "name": dest.parent.name if dest.name.startswith("seed-") else dest.name,
        "policy": "MlpPolicy (the student's actor, its output layer searched)",
        "trained_by": f"evolution strategies on the output layer of {own['name']} seed {own['seed']}: "
                      f"{a.generations} generations of {a.pairs} antithetic pairs (sigma {a.sigma:g}, Adam step "
                      f"{a.sigma / 2:g}), each pair on the same {a.plants} training plants of seed {own['seed']}, "
                      "the objective the episodes' mean cost",
        "command": "python scripts/es_output_layer.py " + " ".join(sys.argv[1:]),
        "init_from": {"agent": str(student), "name": own["name"], "seed": own["seed"],
                      "command": own.get("command"), "validation": own.get("validation")},
        "n_timesteps": int(gen * a.pairs * 2 * a.plants * 2000),  # loop samples of the candidates' episodes
        "wall_time_s": round(wall, 1),
        "curve": curve,
        "selected": {"generation": gen, "how": "the best validation cost of every third generation's layer (the "
                                               "student itself never among them)"},
    })
    import tempfile

    work = Path(tempfile.mkdtemp(prefix="millvib-es-"))  # scored outside agents/, whose folders the manifest checks
    try:
        shutil.copyfile(student / "vecnormalize.npz", work / "vecnormalize.npz")
        model.save(work / "model.zip")
        card["validation"] = validation_result(work, card)
        write_text_atomic(work / "card.json", json.dumps(card, indent=2))
        with atomic_folder(dest) as tmp:
            for name in ("model.zip", "vecnormalize.npz", "card.json"):
                shutil.copyfile(work / name, tmp / name)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("student")
    p.add_argument("--sigma", type=float, default=0.003, help="the perturbation's size per weight (default 0.003)")
    p.add_argument("--generations", type=int, default=30)
    p.add_argument("--pairs", type=int, default=8, help="antithetic pairs a generation (default 8)")
    p.add_argument("--plants", type=int, default=25, help="training plants a generation (default 25)")
    p.add_argument("--save-dir", required=True, help="the agent folder to write (under agents/: run "
                                                       "scripts/agents_manifest.py after)")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    student = Path(a.student)
    agent = AgentPolicy(student)
    task, net = agent.task, agent.policy.action_net
    theta0 = torch.cat([net.weight.detach().flatten(), net.bias.detach().flatten()]).numpy().astype(np.float64)

    def use(theta: np.ndarray) -> None:
        with torch.no_grad():
            net.weight.copy_(torch.as_tensor(theta[:-1].reshape(net.weight.shape), dtype=torch.float32))
            net.bias.copy_(torch.as_tensor(theta[-1:], dtype=torch.float32))

    def cost(theta: np.ndarray, seeds: list[int]) -> float:
        use(theta)
        return float(np.mean([r["cost"] for r in run_episodes(agent, seeds, task=task)]))

    def costs(thetas: np.ndarray, seeds: list[int]) -> np.ndarray:
        """Each candidate's mean cost on `seeds`: every candidate's episodes in one batch of environments, the
        output layer chosen per row (the hidden layers are the same for all)."""
        agent.policy.action_net = RowLinear(thetas, len(seeds), net.weight.shape[1])
        try:
            records = run_episodes(agent, seeds * len(thetas), task=task)
        finally:
            agent.policy.action_net = net
        return np.array([r["cost"] for r in records]).reshape(len(thetas), len(seeds)).mean(axis=1)

    validation = list(range(task.seeds["validation"].start, task.seeds["validation"].start + 40))
    first = task.train_env_seed(agent.seed)
    rng = np.random.default_rng(agent.seed)
    theta, m, v, lr = theta0.copy(), np.zeros_like(theta0), np.zeros_like(theta0), a.sigma / 2
    start = cost(theta0, validation)
    best_cost, best_gen, best_theta = np.inf, 0, theta0.copy()
    curve = [{"generation": 0, "validation": start}]
    clock = time.time()
    for g in range(1, a.generations + 1):
        seeds = [first + int(s) for s in rng.choice(100, a.plants, replace=False)]
        eps = rng.standard_normal((a.pairs, theta.size))
        both = costs(np.concatenate([theta + a.sigma * eps, theta - a.sigma * eps]), seeds)
        grad = (both[:a.pairs] - both[a.pairs:]) @ eps / (2 * a.sigma * a.pairs)
        m, v = 0.9 * m + 0.1 * grad, 0.999 * v + 0.001 * grad ** 2
        theta = theta - lr * (m / (1 - 0.9 ** g)) / (np.sqrt(v / (1 - 0.999 ** g)) + 1e-12)
        row = {"generation": g, "moved": float(np.linalg.norm(theta - theta0)), "wall_s": round(time.time() - clock)}
        if g % 3 == 0:
            row["validation"] = cost(theta, validation)
            if row["validation"] < best_cost:
                best_cost, best_gen, best_theta = row["validation"], g, theta.copy()
        curve.append(row)
        print(json.dumps(row), flush=True)
    wall = time.time() - clock
    save_card(student, Path(a.save_dir), model_with(student, net, best_theta, use), curve, best_gen, wall, a)
    print(json.dumps({"start": start, "best": best_cost, "generation": best_gen}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
