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


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success rename it onto `path`.

    An interrupted or failing writer leaves no half-written file at `path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix or ".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


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
