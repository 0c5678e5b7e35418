"""What the journals of long runs share (`millvib tune`, `sweep` and `distill`): where a run's journal lies, the
one-line refusals of a run that finds one (or none), and the check that a resumed run is the one the journal kept.

A journal lies beside the run's result, its name the result's with `.partial` added (`--out rolling.yaml`:
`rolling.yaml.partial`; `--out results/sweep`: `results/sweep.partial`), and goes once the result is written. A run
that finds one without ``--resume`` stops before doing anything, so finished work is never overwritten by
accident; with ``--resume`` it goes on only from a journal of the same run (the same options).
"""

from __future__ import annotations

from pathlib import Path

from millvib_env._checks import shown, shown_path

__all__ = ["SUFFIX", "journal_path", "found", "check_same_run"]

SUFFIX = ".partial"


def journal_path(target: str | Path) -> Path:
    """The journal of a run whose result goes to `target` (a file or a folder): beside it, `.partial` added."""
    target = Path(target)
    return target.with_name(target.name + SUFFIX)


def found(path: Path, resume: bool, what: str, kept: str) -> bool:
    """Whether the journal `path` is there to go on from. A ValueError of one line where `resume` finds none, or
    where a run without `resume` would start over one. `what`: the run ("tune into rolling.yaml"); `kept`: what
    its journal keeps ("entries")."""
    if not path.exists():
        if resume:
            raise ValueError(f"--resume: there is no journal {shown_path(path)} of an unfinished {what} to go on from")
        return False
    if not resume:
        raise ValueError(f"{shown_path(path)} holds the finished {kept} of an unfinished {what}: add --resume to go "
                         "on from them, or delete it to start again")
    return True


def check_same_run(path: Path, theirs, run: dict, what: str) -> None:
    """A ValueError of one line, naming each option that differs, where the journal `path` kept the run `theirs`
    and this is `run`. `what`: the kind of run ("tune")."""
    if theirs == run:
        return
    theirs = theirs if isinstance(theirs, dict) else {}
    differ = [f"{k} {shown(theirs.get(k))} there, {shown(v)} here" for k, v in run.items() if theirs.get(k) != v]
    raise ValueError(f"--resume: {shown_path(path)} is the journal of another {what} ({'; '.join(differ) or 'run'}): "
                     "give the same options, or delete it to start again")
