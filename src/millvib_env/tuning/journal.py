"""A tune's journal: the entries an unfinished `millvib tune` has tuned, written after each one, so that a run a
Ctrl-C, a crash or a lost machine ended goes on from them (`--resume`) instead of from the start.

The journal lies beside the result, its name the result's with `.partial` added (`--out rolling.yaml`:
`rolling.yaml.partial`), and holds what identifies the run (task, version, entries asked for, grid, the oracles'
source task, the Optuna study) with the finished entries, as YAML (read back with a safe loader: nothing in it
runs). An entry's numbers go through YAML as the result's do (a float is written with the digits that read back
the same), so a resumed tune writes the file an uninterrupted one would, its `wall_time_s` the sum of its parts.
The journal goes once the result is written. A run that finds one without `--resume` stops before tuning
anything, so an hour of finished entries is never overwritten by accident.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from millvib_env import _interrupt
from millvib_env._checks import shown, shown_path
from millvib_env._journal import check_same_run, found, journal_path
from millvib_env._paths import write_text_atomic
from millvib_env._yaml import load_yaml
from millvib_env.tuning import ENTRIES

__all__ = ["Journal", "journal_path", "open_journal"]

@dataclass
class Journal:
    """An open journal: the run it belongs to (`run`), the entries finished so far and the seconds they took."""

    path: Path
    run: dict
    entries: dict = field(default_factory=dict)
    wall_time_s: float = 0.0

    def record(self, name: str, entry: dict, seconds: float) -> None:
        """Entry `name` finished after `seconds` more: the journal rewritten with it (atomically), and the note an
        interruption says from now on."""
        import yaml

        self.entries[name] = entry
        self.wall_time_s += seconds
        text = yaml.safe_dump({"run": self.run, "wall_time_s": round(self.wall_time_s, 1), "entries": self.entries},
                              sort_keys=False, width=110)
        write_text_atomic(self.path, "# the journal of an unfinished millvib tune (--resume goes on from it)\n" + text)
        _interrupt.leave_note(f"the finished entries ({', '.join(self.entries)}) are kept in "
                              f"{shown_path(self.path)}: the same command with --resume goes on from them")

    def close(self) -> None:
        """The result is written: the journal goes, and so does the note."""
        self.path.unlink(missing_ok=True)
        _interrupt.leave_note("")


def open_journal(target: str | Path, run: dict, resume: bool) -> Journal:
    """The journal of a tune into `target` identified by `run`: a new, empty one, or with `resume` the one an
    unfinished run of the same `run` left. A ValueError of one line where `resume` finds none, finds another run's,
    or finds one the run would overwrite (no `resume`)."""
    path = journal_path(target)
    if not found(path, resume, f"tune into {shown_path(target)}", "entries"):
        return Journal(path, run)
    data = load_yaml(path, "tune journal", mapping=True)
    entries, seconds = data.get("entries"), data.get("wall_time_s")
    if set(data) != {"run", "wall_time_s", "entries"} or not isinstance(entries, dict) \
            or not all(isinstance(e, dict) for e in entries.values()) \
            or isinstance(seconds, bool) or not isinstance(seconds, (int, float)) or not seconds >= 0:
        raise ValueError(f"tune journal {shown_path(path)} is damaged: it must hold run, wall_time_s (seconds >= 0) "
                         "and entries (a mapping of entry names to their configs); delete it to start again")
    unknown = [name for name in entries if name not in ENTRIES]
    if unknown:
        raise ValueError(f"tune journal {shown_path(path)} is damaged: entries {shown(unknown)} are not tuned "
                         f"entries ({', '.join(ENTRIES)}); delete it to start again")
    check_same_run(path, data["run"], run, "tune")
    journal = Journal(path, run, dict(entries), float(seconds))
    if entries:
        _interrupt.leave_note(f"the finished entries ({', '.join(entries)}) are kept in {shown_path(path)}: the same "
                              "command with --resume goes on from them")
    return journal
