"""Where the project's data folders (configs/, agents/) are, and atomic file writes."""

from __future__ import annotations

import contextlib
import glob
import os
import tempfile
import time
from importlib import resources
from pathlib import Path
from typing import Collection, Iterator

from millvib_env import _interrupt
from millvib_env._checks import shown_path

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

    An interrupted or failing writer leaves no half-written file at `path`. The new file reaches the disk
    (fsync) before it takes the old one's place: a file system that accepts a write into its cache and finds no
    room only when it writes it back (a full disk) fails here, naming `path`, and the old file stays as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix or ".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        _interrupt.check()  # a signal a library swallowed while the file was made: it does not take the old's place
        _sync(tmp_path)
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except OSError as err:  # a full disk, a quota: the one line names the file the user asked for
        raise OSError(err.errno, err.strerror or str(err), str(path)) from None
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _sync(path: Path) -> None:
    """`path`'s written data on the disk (where the file system has a disk to sync to)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


#: the file that marks a folder as a command's result: the command and every entry it wrote
RESULT_MARKER = ".millvib-result.json"
#: debris of an interrupted folder write: .<name>.<random>.tmp (the new result) or .old (the previous one)
_OWNER = ".owner"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _owner_pid(folder: Path) -> int | None:
    try:
        return int((folder / _OWNER).read_text().strip())
    except (OSError, ValueError):
        return None


def clean_debris(path: str | os.PathLike) -> None:
    """Remove what an interrupted (even SIGKILLed) write of the folder `path` left beside it: its
    temporary folders whose writing process is gone; where `path` itself is missing because the
    run died between moving the old result aside and putting the new one in place, the old result
    goes back first. A write still running (its process alive) is left alone."""
    import shutil

    path = Path(path)
    if not path.parent.is_dir():
        return
    for kind in (".old", ".tmp"):
        for debris in sorted(path.parent.glob(f".{glob.escape(path.name)}.*{kind}")):
            pid = _owner_pid(debris)
            if not debris.is_dir() or (pid is not None and _alive(pid)):
                continue
            if pid is None and time.time() - debris.stat().st_mtime < 60:
                continue  # just created by a writer that has not yet marked it
            if kind == ".old" and (debris / "x").is_dir() and not path.exists():
                os.replace(debris / "x", path)
            shutil.rmtree(debris, ignore_errors=True)


def _inside(a: Path, b: Path) -> bool:
    """a is b or lies inside b (both resolved)."""
    return a == b or b in a.parents


def check_result_folder(path: str | os.PathLike | None, flag: str, command: str, *,
                        others: tuple = (), own_files: Collection[str] | None = None) -> Path | None:
    """Check, before any work, that the result folder `path` may be (re)written by `command` as a
    whole: it is new, empty, or holds only a previous result of the same command (its
    `RESULT_MARKER` lists every entry in it, or, with `own_files`, every entry is one of those
    names); it is neither the working directory nor one of its ancestors; and no other path the same
    run writes (`others`: (flag, path) pairs) lies inside it or is it. ValueError naming the
    flag otherwise: a user's files are never replaced."""
    p = check_output(path, flag, folder=True)
    if p is None:
        return None
    where = p.resolve()
    cwd = Path.cwd().resolve()
    if _inside(cwd, where):
        raise ValueError(f"{flag} {shown_path(path)} is the working directory or contains it; a result folder is "
                         "replaced as a whole: name a new folder (e.g. results/run1)")
    for other_flag, other in others:
        if other is None:
            continue
        o = Path(other).resolve()
        if _inside(o, where):
            raise ValueError(f"{other_flag} {shown_path(other)} lies inside {flag} {shown_path(path)}, which is "
                             f"replaced as a whole: {other_flag} must lie outside it")
    clean_debris(p)
    if not p.is_dir():
        return p
    entries = sorted(e.name for e in p.iterdir())
    if not entries:
        return p
    if own_files is not None:
        foreign = [e for e in entries if e not in own_files]
    else:
        marker = _read_marker(p)
        if marker is None or marker.get("command") != command:
            what = "no millvib result" if marker is None else f"a `millvib {marker.get('command')}` result"
            raise ValueError(f"{flag} {shown_path(path)} holds {len(entries)} entries and is {what} "
                             f"({', '.join(entries[:4])}{', ...' if len(entries) > 4 else ''}); it would be replaced "
                             "as a whole: name a new or empty folder")
        foreign = [e for e in entries if e != RESULT_MARKER and e not in marker.get("entries", [])]
    if foreign:
        raise ValueError(f"{flag} {shown_path(path)} holds entries this command did not write ({', '.join(foreign[:4])}"
                         f"{', ...' if len(foreign) > 4 else ''}); it would be replaced as a whole: move them or "
                         "name a new folder")
    return p


def _read_marker(folder: Path) -> dict | None:
    import json

    try:
        data = json.loads((folder / RESULT_MARKER).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


@contextlib.contextmanager
def atomic_folder(path: str | os.PathLike, *, keep_existing: bool = False,
                  command: str | None = None) -> Iterator[Path]:
    """Yield a temporary folder beside `path`; on success put it in place of `path` as a whole.

    `keep_existing` starts the temporary folder as a copy of `path` (to update some of its files).
    `command` writes `RESULT_MARKER` (the command and the entries) into the result, so a later run of
    the same command knows the folder for its own (`check_result_folder`). A run interrupted before
    the end leaves `path` as it was, and its temporary folder is removed (on SIGINT and SIGTERM at
    once; after SIGKILL by the next write of `path`, `clean_debris`); two runs at once each replace
    the whole folder, so it holds one run's files, never a mix.
    """
    import json
    import shutil

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    clean_debris(path)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    (tmp / _OWNER).write_text(str(os.getpid()))
    try:
        if keep_existing and path.is_dir():
            shutil.copytree(path, tmp, dirs_exist_ok=True)
            (tmp / _OWNER).write_text(str(os.getpid()))
        try:
            yield tmp
        except OSError as err:  # a full disk inside the folder: the line names the file in the folder asked for
            if err.filename and Path(err.filename).is_relative_to(tmp):
                raise OSError(err.errno, err.strerror or str(err),
                              str(path / Path(err.filename).relative_to(tmp))) from None
            raise
        _interrupt.check()  # a signal a library swallowed while the folder was made: it does not replace `path`
        (tmp / _OWNER).unlink()
        if command is not None:
            entries = sorted(e.name for e in tmp.iterdir() if e.name != RESULT_MARKER)
            (tmp / RESULT_MARKER).write_text(json.dumps({"command": command, "entries": entries}, indent=1))
        os.chmod(tmp, 0o777 & ~_umask())
        olds: list[Path] = []
        try:
            _swap_in(tmp, path, olds)
        finally:
            for old in olds:
                shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


#: how often a finished result tries to take its place while other writers of the same folder finish too
_SWAP_TRIES = 20


def _swap_in(tmp: Path, path: Path, olds: list) -> None:
    """Put folder `tmp` in place of `path`: what is there is moved aside into a fresh folder (appended to
    `olds`, for the caller to remove), then `tmp` renamed to `path`. Another writer that finishes between
    the two renames (its folder now at `path`: ENOTEMPTY) is moved aside in turn, up to `_SWAP_TRIES` times:
    the last writer to finish wins, whole."""
    import errno

    for attempt in range(_SWAP_TRIES):
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            olds.append(old)
            (old / _OWNER).write_text(str(os.getpid()))
            try:
                os.replace(path, old / "x")
            except FileNotFoundError:  # another writer moved it aside first
                pass
        try:
            os.replace(tmp, path)
            return
        except OSError as err:
            if err.errno not in (errno.ENOTEMPTY, errno.EEXIST) or attempt == _SWAP_TRIES - 1:
                raise


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
    long = [part for part in p.parts if len(os.fsencode(part)) > 255]
    if long:
        raise ValueError(f"{flag}: the name {long[0][:40]!r}... is {len(os.fsencode(long[0]))} bytes long; a file or "
                         "folder name may have at most 255")
    if p.exists():
        if folder and not p.is_dir():
            raise ValueError(f"{flag} {shown_path(p)}: a file is in the way; a folder is needed")
        if not folder and p.is_dir():
            raise ValueError(f"{flag} {shown_path(p)} is a folder; a file path is needed")
    parent = p if folder and p.exists() else p.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{flag} {shown_path(p)}: {shown_path(parent)} is a file, so the path cannot be created")
    try:  # really try: as root os.access says yes to /proc and to read-only file systems
        with tempfile.TemporaryFile(dir=parent):
            pass
    except OSError as err:
        raise ValueError(f"{flag} {shown_path(p)}: {shown_path(parent)} is not writable "
                         f"({err.strerror or err})") from None
    return p
