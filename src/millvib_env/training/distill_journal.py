"""A distillation's journal: what an unfinished `millvib distill` has done, kept after each DAgger iteration, so that
a run a Ctrl-C, a crash or a lost machine ended goes on from its last finished iteration (`--resume`) instead of
from the start.

The journal is a folder beside the agent folder, its name the agent folder's with `.partial` added (`--save-dir
agents/x/seed-0`: `agents/x/seed-0.partial`), and doubles as the run's work folder. It holds:

- each finished iteration's labelled samples, `pool-K.npz` (observations and labels, float32, as pooled);
- the student's weights after the last finished iteration, `weights.npz` (one array per tensor of the policy's
  state dict, float32: read back bit for bit, without pickle);
- the scored students, `itK/` (an agent folder's network and statistics, as the run validated them);
- `journal.json`, written last (atomically) at the end of each iteration: the run's options, the iterations done,
  every iteration's record, the best so far and the seconds spent.

A resumed run rebuilds the pool from the samples in order, the student from the weights and the statistics from
the pool, which are what the uninterrupted run held after that iteration: it goes on to the same agent (every
weight, the card's numbers but `wall_time_s`, which is the sum of the runs' times). The journal goes once the agent
folder is written.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from millvib_env import _interrupt
from millvib_env._checks import shown_path
from millvib_env._journal import check_same_run, found, journal_path
from millvib_env._paths import atomic_path, write_text_atomic

__all__ = ["DistillJournal", "open_distill_journal"]

_KEYS = {"run", "done", "wall_time_s", "history", "best"}


@dataclass
class DistillJournal:
    """An open journal (module docstring): its folder, the run it belongs to and, once resumed or recorded, the
    iterations done, their records and the best iteration so far (None: none scored yet)."""

    path: Path
    run: dict
    iterations: int
    done: int = 0
    wall_time_s: float = 0.0
    history: list | None = None
    best: int | None = None

    def record(self, it: int, X: np.ndarray, Y: np.ndarray, policy, history: list, best: int | None,
               wall_time_s: float) -> None:
        """Iteration `it` (0-based) finished: its samples, the student's weights, then the journal's record."""
        with atomic_path(self.path / f"pool-{it + 1}.npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, X=X, Y=Y)
        with atomic_path(self.path / "weights.npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **{k: v.detach().cpu().numpy() for k, v in policy.state_dict().items()})
        self.done, self.history, self.best, self.wall_time_s = it + 1, history, best, wall_time_s
        write_text_atomic(self.path / "journal.json", json.dumps(
            {"run": self.run, "done": self.done, "wall_time_s": round(wall_time_s, 1), "history": history,
             "best": best}, indent=1))
        _interrupt.leave_note(self._note())

    def samples(self):
        """The finished iterations' samples, in order: (X, Y) for each."""
        for k in range(1, self.done + 1):
            with np.load(self.path / f"pool-{k}.npz", allow_pickle=False) as z:
                yield z["X"], z["Y"]

    def load_weights(self, policy) -> None:
        """The student's weights after the last finished iteration, into `policy` (the run's own network)."""
        import torch

        with np.load(self.path / "weights.npz", allow_pickle=False) as z:
            state = {k: torch.as_tensor(z[k]) for k in z.files}
        policy.load_state_dict(state)

    def close(self) -> None:
        """The agent folder is written: the journal goes, and so does the note."""
        shutil.rmtree(self.path, ignore_errors=True)
        _interrupt.leave_note("")

    def abandon(self) -> None:
        """The run ends without its agent: a journal that keeps no finished iteration goes (what it holds is an
        unfinished iteration's), one that keeps some stays for --resume."""
        if not self.done:
            shutil.rmtree(self.path, ignore_errors=True)

    def _note(self) -> str:
        return (f"{self.done} of {self.iterations} iterations are kept in {shown_path(self.path)}: the same command "
                "with --resume goes on from them")


def open_distill_journal(save_dir: str | Path, run: dict, iterations: int, resume: bool) -> DistillJournal:
    """The journal of a distillation into `save_dir` identified by `run`: a new, empty one (its folder made), or
    with `resume` the one an unfinished run of the same `run` left. A ValueError of one line where `resume` finds
    none, finds another run's or a damaged one, or finds one the run would start over (no `resume`)."""
    path = journal_path(save_dir)
    if path.is_dir() and not (path / "journal.json").exists():
        shutil.rmtree(path)  # a run cut before its first iteration ended (it keeps nothing)
    if not found(path, resume, f"distillation into {shown_path(save_dir)}", "iterations"):
        path.mkdir(parents=True)
        return DistillJournal(path, run, iterations)
    damaged = (f"distillation journal {shown_path(path)} is damaged: it must hold journal.json (run, done, "
               "wall_time_s, history, best), pool-K.npz of each iteration done and weights.npz; delete it to start "
               "again")
    try:
        data = json.loads((path / "journal.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raise ValueError(damaged) from None
    if not isinstance(data, dict) or set(data) != _KEYS:
        raise ValueError(damaged)
    check_same_run(path, data["run"], run, "distillation")
    done, seconds, history, best = data["done"], data["wall_time_s"], data["history"], data["best"]
    if isinstance(done, bool) or not isinstance(done, int) or not 1 <= done < iterations \
            or isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not seconds >= 0 \
            or not isinstance(history, list) or len(history) != done \
            or not (best is None or (isinstance(best, int) and 1 <= best <= done and (path / f"it{best}").is_dir())) \
            or not (path / "weights.npz").is_file() \
            or not all((path / f"pool-{k}.npz").is_file() for k in range(1, done + 1)):
        raise ValueError(damaged)
    journal = DistillJournal(path, run, iterations, done, float(seconds), history, best)
    _interrupt.leave_note(journal._note())
    return journal
