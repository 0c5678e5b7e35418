"""The shipped agents' checksum manifest (agents/MANIFEST.sha256, `sha256sum` format).

A shipped agent's files are verified against it before loading: `model.zip` is deserialised by
SB3 (which unpickles parts of it), so a changed file must not be loaded silently. Agent folders
given by path are not covered: they are trusted code (README, `millvib benchmark --help`).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from millvib_env._checks import shown_path
from millvib_env._paths import agents_dir, write_text_atomic

__all__ = ["MANIFEST", "AGENT_FILES", "EVAL_CURVE", "write_manifest", "verify_agent"]

MANIFEST = "MANIFEST.sha256"
#: EvalCallback's curve (SB3's file name), shipped beside the model for the training-curve plots
EVAL_CURVE = "evaluations.npz"
AGENT_FILES = ("model.zip", "vecnormalize.npz", "card.json", EVAL_CURVE)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_manifest(root: Path | None = None) -> Path:
    """(Re)write the manifest over every agent folder under `root` (default: agents/)."""
    root = Path(root or agents_dir())
    lines = []
    for card in sorted(root.glob("*/card.json")) + sorted(root.glob("*/seed-*/card.json")):
        folder = card.parent
        for name in AGENT_FILES:
            if (folder / name).exists():
                lines.append(f"{_sha256(folder / name)}  {folder.relative_to(root).as_posix()}/{name}")
    return write_text_atomic(root / MANIFEST, "\n".join(lines) + "\n")


def verify_agent(folder: Path) -> bool:
    """Check a folder under the shipped agents' root against the manifest; True if it is shipped
    (and intact), False if it lies elsewhere; ValueError if a shipped file is missing or changed."""
    root = Path(agents_dir()).resolve()
    folder = Path(folder).resolve()
    if root not in folder.parents or len(folder.relative_to(root).parts) > 2:
        return False  # not under agents/ (an agent, or a seed-<s> folder of one)
    rel = folder.relative_to(root).as_posix()
    manifest = root / MANIFEST
    if not manifest.is_file():
        raise ValueError(f"{manifest} is missing: the shipped agents cannot be verified")
    entries = {}
    for line in manifest.read_text().splitlines():
        digest, _, name = line.partition("  ")
        entries[name] = digest
    listed = [name for name in entries if name.rsplit("/", 1)[0] == rel]
    if not listed:
        raise ValueError(f"{shown_path(folder)} is not in {manifest}: regenerate it with `python "
                         "scripts/agents_manifest.py` after adding an agent")
    for name in listed:
        path = root / name
        if not path.is_file() or _sha256(path) != entries[name]:
            raise ValueError(f"{shown_path(path)} does not match its checksum in {manifest}: the shipped file is "
                             "missing or changed; restore it (git checkout) or regenerate the manifest for a new agent")
    return True
