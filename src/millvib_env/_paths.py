"""Where the project's data folders (configs/, agents/) are, and atomic file writes."""

from __future__ import annotations

import contextlib
import os
import tempfile
from importlib import resources
from pathlib import Path
from typing import Iterator

_REPO_ROOT = Path(__file__).resolve().parents[2]


def _data_dir(name: str) -> Path:
    env = os.environ.get(f"MILLVIB_{name.upper()}")
    if env:
        return Path(env)
    packaged = Path(str(resources.files("millvib_env"))) / "_data" / name
    if packaged.is_dir():  # a wheel install carries configs/ and agents/ inside the package
        return packaged
    return _REPO_ROOT / name  # a source checkout / editable install


def config_dir() -> Path:
    """The configs/ folder (override with MILLVIB_CONFIGS)."""
    return _data_dir("configs")


def agents_dir() -> Path:
    """The agents/ folder of shipped agents (override with MILLVIB_AGENTS)."""
    return _data_dir("agents")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success rename it onto `path` with the mode a plain
    write would give (0666 less the umask; mkstemp's own is 0600).

    An interrupted or failing writer leaves no half-written file at `path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix or ".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike, *, keep_existing: bool = False) -> Iterator[Path]:
    """Yield a temporary folder beside `path`; on success put it in place of `path` as a whole.

    `keep_existing` starts the temporary folder as a copy of `path` (to update some of its files).
    A run interrupted before the end leaves `path` as it was; two runs at once each replace the whole
    folder, so it holds one run's files, never a mix.
    """
    import shutil

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        if keep_existing and path.is_dir():
            shutil.copytree(path, tmp, dirs_exist_ok=True)
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())
        old = None
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            os.replace(path, old / "x")
        os.replace(tmp, path)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def save_figure(fig, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Save a matplotlib figure atomically (format from the suffix, PNG by default) and close it."""
    import matplotlib.pyplot as plt

    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    return path


def check_output(path: str | os.PathLike | None, flag: str, *, folder: bool = False) -> Path | None:
    """Check, before any work, that `path` can be written: a file (or a folder with folder=True)
    whose nearest existing ancestor is a writable folder, and not a folder where a file is needed
    (or the reverse). ValueError naming `flag` otherwise."""
    if path is None:
        return None
    p = Path(path)
    if str(path).strip() == "":
        raise ValueError(f"{flag} = {str(path)!r} is invalid: an empty path")
    if p.exists():
        if folder and not p.is_dir():
            raise ValueError(f"{flag} {p}: a file is in the way; a folder is needed")
        if not folder and p.is_dir():
            raise ValueError(f"{flag} {p} is a folder; a file path is needed")
    parent = p if folder and p.exists() else p.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{flag} {p}: {parent} is a file, so the path cannot be created")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{flag} {p}: {parent} is not writable")
    return p
