"""What a controller reads: its information set, declared once, so that every controller is judged against the
strongest classical controller that reads the same signals, and bounded by an oracle that knows at least as much.

The atoms (`ATOMS`), in their order:

* ``loop``: the loop's sampled position, pressure and the position's filtered derivative (every controller);
* ``force``: the load cells' rolling-force deviation;
* ``schedule``: the pass schedule's set-point course ahead (a preview of the set-point);
* ``gauge``: the entry gauge's force preview (exact or measured: `envs.gauge`);
* ``pump``: the pump's phase;
* ``params``: the plant's true parameters (c1, Ct, ...): an oracle's;
* ``state``: the plant's true state and its disturbances now: an oracle's.

A set is written as its atoms joined by ``+`` (``loop+force+schedule+gauge``). A controller that holds
``params`` or ``state`` is an oracle, not deployable: it bounds the sets it contains (`bound_candidates`). A
baseline declares its set in its registry entry (`catalog.registry.Baseline.information`); an agent's, an
exported graph's or a user's controller's set is read off the observation its environment gives it
(`from_env_kwargs`), plus ``params`` and ``state`` where it reads the plant itself (`Controller.reads_plant`).
"""

from __future__ import annotations

from typing import Any, Iterable, Mapping

__all__ = ["ATOMS", "ORACLE_ATOMS", "PRESENT_ATOMS", "label", "atoms_of", "from_env_kwargs", "is_oracle",
           "bound_candidates", "classical_candidates"]

#: every atom, with what it is, in the order a set is written
ATOMS: dict[str, str] = {
    "loop": "the loop's sampled position, pressure and derivative",
    "force": "the load cells' rolling force",
    "schedule": "the pass schedule's set-point course ahead",
    "gauge": "the entry gauge's force preview",
    "pump": "the pump's phase",
    "params": "the plant's true parameters (oracle)",
    "state": "the plant's true state and disturbances now (oracle)",
}
#: what only an oracle knows
ORACLE_ATOMS = frozenset({"params", "state"})
#: what a bound of a set may know beyond it without knowing the future: the plant, and the disturbances now
PRESENT_ATOMS = frozenset({"params", "state", "force", "pump"})


def label(atoms: Iterable[str]) -> str:
    """A set's name: its atoms in `ATOMS`' order, joined by ``+``."""
    have = set(atoms)
    unknown = have - set(ATOMS)
    if unknown:
        raise ValueError(f"information {sorted(unknown)} unknown: atoms are {list(ATOMS)}")
    return "+".join(a for a in ATOMS if a in have)


def atoms_of(name: str) -> frozenset[str]:
    """A set's atoms from its name (`label`)."""
    return frozenset(name.split("+"))


def is_oracle(name: str) -> bool:
    """The set holds an oracle's atom: not deployable."""
    return bool(atoms_of(name) & ORACLE_ATOMS)


def from_env_kwargs(env_kwargs: Mapping[str, Any], base_observation: Any = None, reads_plant: bool = False) -> str:
    """The set of a controller that acts through the observation its environment's keyword arguments give it
    (`base_observation`: the task config's `ObservationSettings`, which the keywords override)."""
    seen: dict[str, Any] = {}
    if base_observation is not None:
        seen.update({k: getattr(base_observation, k) for k in ("force", "phase", "params", "preview_samples")})
    cfg = env_kwargs.get("config")
    for source in ((cfg.get("observation") if isinstance(cfg, Mapping) else None), env_kwargs.get("observation")):
        if isinstance(source, Mapping):
            seen.update(source)
    for flag, key in (("observe_phase", "phase"), ("observe_params", "params")):
        if env_kwargs.get(flag) is not None:
            seen[key] = env_kwargs[flag]
    atoms = {"loop"}
    if seen.get("force"):
        atoms.add("force")
    if seen.get("preview_samples"):
        atoms |= {"schedule", "gauge"}
    if seen.get("phase"):
        atoms.add("pump")
    if seen.get("params"):
        atoms.add("params")
    if reads_plant:
        atoms |= {"params", "state"}
    return label(atoms)


def classical_candidates(target: str, sets: Mapping[str, str]) -> list[str]:
    """The deployable controllers among `sets` (name -> set) whose set lies within `target` (they read it, or less):
    every classical design open to a controller that reads `target`, so what such a controller must at least
    beat."""
    want = atoms_of(target)
    return [n for n, s in sets.items() if not is_oracle(s) and atoms_of(s) <= want]


def bound_candidates(target: str, sets: Mapping[str, str]) -> list[str]:
    """The oracles among `sets` that know everything `target` knows and, beyond it, only the plant and the
    disturbances now (`PRESENT_ATOMS`): none previews what `target` does not."""
    want = atoms_of(target)
    return [n for n, s in sets.items() if is_oracle(s) and atoms_of(s) >= want
            and atoms_of(s) <= want | PRESENT_ATOMS]
