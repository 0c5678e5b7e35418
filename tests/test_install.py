"""The install is reproducible: every package the code imports is declared, and every declared one pinned."""
import ast
import re
import sys
import tomllib
from pathlib import Path

from tests._source import parsed

ROOT = Path(__file__).resolve().parents[1]
#: import name -> distribution name, where they differ
DIST = {"yaml": "pyyaml", "sb3_contrib": "sb3-contrib", "stable_baselines3": "stable-baselines3",
        "control": "control", "rl_zoo3": "rl-zoo3", "sbx": "sbx-rl"}


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _imports(folder: Path) -> set[str]:
    found = set()
    for path in folder.rglob("*.py"):
        for node in ast.walk(parsed(path)):
            if isinstance(node, ast.Import):
                found |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module.split(".")[0])
    local = {path.stem for path in folder.rglob("*.py")}  # a script importing its sibling script
    return {m for m in found if m not in sys.stdlib_module_names and m not in {"millvib_env", "tests"} | local}


def _declared() -> tuple[set[str], set[str]]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    req = lambda spec: _norm(re.split(r"[<>=!\[ ;]", spec, maxsplit=1)[0])  # noqa: E731
    core = {req(s) for s in project["dependencies"]}
    extras = {req(s) for specs in project["optional-dependencies"].values() for s in specs}
    return core, extras


def test_every_imported_package_is_declared():
    core, extras = _declared()
    for folder in ("src", "scripts", "tests"):
        missing = {m for m in _imports(ROOT / folder) if _norm(DIST.get(m, m)) not in core | extras}
        assert not missing, f"{folder} imports undeclared packages {sorted(missing)}"


def test_the_dev_extra_holds_every_optional_package():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    req = lambda spec: _norm(re.split(r"[<>=!\[ ;]", spec, maxsplit=1)[0])  # noqa: E731
    extras = project["optional-dependencies"]
    dev = {req(s) for s in extras["dev"]}
    others = {req(s) for name, specs in extras.items() if name != "dev" for s in specs}
    assert others <= dev, sorted(others - dev)


def test_every_declared_package_is_pinned():
    core, extras = _declared()
    pins = {_norm(line.split("==")[0]) for line in (ROOT / "constraints.txt").read_text().splitlines()
            if "==" in line and not line.startswith("#")}
    unpinned = (core | extras) - pins - {"torch"}  # torch: its own CPU line in the README and .ci/run
    assert not unpinned, sorted(unpinned)
