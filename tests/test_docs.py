"""The documentation has one home per fact: the environment manuals come from the docstrings, and every
local link resolves."""
import re
import sys
from pathlib import Path

import pytest

from tests._source import parsed

ROOT = Path(__file__).resolve().parents[1]


def test_the_environment_manuals_are_the_docstrings(monkeypatch, capsys):
    # `python scripts/env_docs.py --check`, run in this process (the package is imported here already)
    import runpy

    script = runpy.run_path(str(ROOT / "scripts" / "env_docs.py"))
    monkeypatch.setattr(sys, "argv", ["env_docs.py", "--check"])
    assert script["main"]() == 0, capsys.readouterr().err


def test_every_local_link_in_the_readme_and_docs_resolves():
    missing = []
    for md in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "agents" / "README.md"]:
        text = md.read_text()
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text) + re.findall(r'src="([^"]+)"', text):
            if "://" in target:
                continue
            if not (md.parent / target).exists():
                missing.append(f"{md.relative_to(ROOT)} -> {target}")
    assert not missing, missing


@pytest.mark.slow  # seconds of work: the full suite runs it, the quick subset does not
def test_the_plain_sb3_recipe_runs_as_written_and_gives_the_benchmarks_episode(monkeypatch):
    # agents/README.md: a shipped agent loaded with PPO.load and the statistics file, nothing of ours
    # but the environment, gives the same episode as load_controller in the benchmark's loop
    import numpy as np

    from millvib_env.catalog import load_controller
    from millvib_env.evaluation.evaluate import run_episodes

    text = (ROOT / "agents" / "README.md").read_text()
    code = re.search(r"<!-- recipe: plain-sb3 -->\n```python\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(ROOT)
    scope: dict = {}
    exec(compile(code, "agents/README.md", "exec"), scope)  # noqa: S102 - the documented recipe itself
    rec = run_episodes(load_controller("ppo-gain-pf-rolling"), [120000], task="rolling")[0]
    assert np.isclose(scope["info"]["severity"], rec["severity_mm_s"], rtol=1e-6)
    assert np.isclose(scope["info"]["tracking_rms_um"], rec["tracking_rms_um"], rtol=1e-6)


#: a path named in the docs or configs: under one of the project's folders, placeholders (<task>, *, NAME, T) allowed
_PATH = re.compile(r"(?<![\w/.-])((?:scripts|src|configs|docs|tests|agents)/[A-Za-z0-9_./<>*-]*[A-Za-z0-9_/<>*])")
_MODULE = re.compile(r"\bmillvib_env(?:\.[A-Za-z_][A-Za-z0-9_]*)+")


def _placeholder(path: str) -> bool:
    return any(c in path for c in "<*") or any(re.fullmatch(r"[A-Z]+|seed-[A-Z]|[A-Z]\.ya?ml", part)
                                               for part in path.split("/"))


def _module_exists(dotted: str) -> bool:
    """A module of the package, or a name defined (def, class, assignment, import) in one."""
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        base = ROOT / "src" / Path(*parts[:k])
        source = base.with_suffix(".py") if base.with_suffix(".py").exists() else base / "__init__.py"
        if source.exists():
            if k == len(parts):
                return True
            name = parts[k]
            return k == len(parts) - 1 and re.search(
                rf"^\s*(def|class)\s+{name}\b|^\s*{name}\s*[:=]|\bimport\b.*\b{name}\b", source.read_text(),
                re.M) is not None
    return False


def test_every_path_and_module_named_in_the_docs_and_configs_exists():
    """Docs that cannot drift: each `scripts/...`, `src/...`, `configs/...`, `docs/...`, `tests/...` or `agents/...`
    path and each `millvib_env.<module>[.<name>]` named in the README, docs/, agents/README.md or a config file
    exists (a path from the repository's root or from the file's own folder)."""
    files = [ROOT / "README.md", ROOT / "agents" / "README.md", *sorted((ROOT / "docs").glob("*.md")),
             *sorted((ROOT / "configs").rglob("*.yaml")), *sorted((ROOT / "configs").rglob("*.yml"))]
    missing = []
    for f in files:
        text = f.read_text()
        for path in _PATH.findall(text):
            if not _placeholder(path) and not (ROOT / path).exists() and not (f.parent / path).exists():
                missing.append(f"{f.relative_to(ROOT)}: {path}")
        missing += [f"{f.relative_to(ROOT)}: {m}" for m in _MODULE.findall(text) if not _module_exists(m)]
        for name in re.findall(r"`(?:[A-Za-z0-9_]+/)*([A-Za-z0-9_]+\.py)`", text):  # `core.py`, `envs/core.py`
            if not any(ROOT.glob(f"{top}/**/{name}") for top in ("src", "scripts", "tests")):
                missing.append(f"{f.relative_to(ROOT)}: {name}")
    assert not missing, missing


def test_the_architecture_page_names_every_module_of_the_package():
    """docs/architecture.md's map cannot drift from the code: every module under src/millvib_env (its file's stem)
    is named on the page."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    named = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*", text))
    unnamed = [p.relative_to(ROOT).as_posix() for p in sorted((ROOT / "src" / "millvib_env").rglob("*.py"))
               if p.name != "__init__.py" and p.stem not in named]
    assert not unnamed, f"docs/architecture.md does not name {unnamed}"


def test_outside_envs_no_code_reads_the_engines_arrays():
    """What controllers, evaluation and training read of `MillVibCore` goes through its declared reads
    (`envs.reads.EpisodeReads`): outside envs/ no code names one of the engine's arrays on a core (`core.Y`,
    `self.core.XD`, `venv.core.CS`, ...)."""
    import numpy as np

    from millvib_env.envs.batch import EpisodeBatch

    core = EpisodeBatch("MillVib-Valve-v1", 1, config="rolling").core
    arrays = {name for name, value in vars(core).items() if isinstance(value, np.ndarray)}
    assert {"Y", "XD", "DFL", "CS", "YS", "AUXS", "k", "u_ff"} <= arrays  # the scan below knows what it looks for
    found = []
    for path in sorted((ROOT / "src" / "millvib_env").rglob("*.py")):
        if path.parent.name == "envs":
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            found += [f"{path.relative_to(ROOT)}:{n} core.{name}" for name in re.findall(r"\b_?core\.(\w+)", line)
                      if name in arrays]
    assert not found, found


#: the package's modules that a function may import inside itself: laziness is the point (torch and SB3,
#: scipy.signal, matplotlib) (docs/architecture.md, "Imports at the top")
LAZY_MODULES = {"millvib_env.envs.vec_env", "millvib_env.analysis.dynamics", "millvib_env.analysis.paper",
                "millvib_env.analysis.solver_study", "millvib_env.speed",
                "millvib_env.envs.rendering"}
#: the files whose function-local imports are all deliberate (the CLI, the launcher, the package's __init__)
LAZY_FILES = {"src/millvib_env/cli.py", "src/millvib_cli/__init__.py", "src/millvib_env/__init__.py"}


def test_the_package_imports_its_own_modules_at_the_top_unless_laziness_is_the_point():
    """A function-local import of one of the package's modules names a lazy module (`LAZY_MODULES`), is for type
    checkers only, or stands in a file whose commands import what they run (`LAZY_FILES`)."""
    import ast

    found = []
    for path in sorted((ROOT / "src").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel in LAZY_FILES:
            continue
        tree = parsed(path)
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                mods = [node.module or ""] if isinstance(node, ast.ImportFrom) else \
                    [a.name for a in node.names] if isinstance(node, ast.Import) else []
                found += [f"{rel}:{node.lineno} {m}" for m in mods
                          if m.split(".")[0] in ("millvib_env", "millvib_cli") and m not in LAZY_MODULES
                          and m != "millvib_env"]
    assert not found, found


#: what reads as a timing of a particular day ("3x slower", "about 2 s", "took 12 min", "3.1 CPU-s")
TIMING_CLAIMS = (r"\b\d+(\.\d+)?\s?(x|times)\s(faster|slower)\b",
                 r"\babout \d+(\.\d+)?\s?(s|ms|seconds|minutes|CPU-s)\b",
                 r"\b(took|takes|take) (about )?\d+(\.\d+)?\s?(s|ms|seconds|minutes|min|CPU-s)\b",
                 r"\b\d+(\.\d+)?\s?CPU-s\b")


def test_timings_live_in_the_performance_page_not_in_the_code_or_the_readme():
    """A timing goes stale with the machine and the day: it stands in docs/performance.md beside its command and
    date, and the code's docstrings and comments and the README's prose point there instead."""
    found = []
    for path in [*sorted((ROOT / "src").rglob("*.py")), ROOT / "README.md"]:
        for n, line in enumerate(path.read_text().splitlines(), 1):
            found += [f"{path.relative_to(ROOT)}:{n}: {line.strip()[:100]}" for pattern in TIMING_CLAIMS
                      if re.search(pattern, line)]
    assert not found, found


def test_no_module_of_the_package_passes_600_lines_and_no_function_80():
    """The house's sizes: a module a reader takes in at one sitting, a function on two screens (the plant's
    `plant_rhs`, the kernel's hot path, included: docs/performance.md says why it stays one function)."""
    import ast

    long = []
    for path in sorted((ROOT / "src").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        lines = path.read_text().count("\n")
        if lines > 600:
            long.append(f"{rel}: {lines} lines")
        for fn in ast.walk(parsed(path)):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)) and fn.end_lineno - fn.lineno + 1 > 80:
                long.append(f"{rel}:{fn.lineno} {fn.name}: {fn.end_lineno - fn.lineno + 1} lines")
    assert not long, long


def test_every_floor_imports_downward():
    """docs/architecture.md's floors: evaluation/ imports neither training/ nor tuning/, and those two never
    import each other (each uses evaluation); the catalog (catalog/, names into objects) imports none of the three,
    the algorithms (control/) nothing of the catalog either, envs/ nothing of control/ or the catalog, plant/
    nothing above it. A name that moved from control/ to the catalog, imported from control/ as before,
    is refused with where it went."""
    import ast
    from pathlib import Path

    import millvib_env
    import millvib_env.catalog
    import millvib_env.control

    root = Path(millvib_env.__file__).parent
    upper = ("millvib_env.evaluation", "millvib_env.training", "millvib_env.tuning")
    forbidden = {"evaluation": ("millvib_env.training", "millvib_env.tuning"), "tuning": ("millvib_env.training",),
                 "training": ("millvib_env.tuning",), "catalog": upper, "control": upper + ("millvib_env.catalog",),
                 "envs": upper + ("millvib_env.control", "millvib_env.catalog"),
                 "plant": upper + ("millvib_env.control", "millvib_env.catalog", "millvib_env.envs")}
    for folder, banned in forbidden.items():
        for path in (root / folder).rglob("*.py"):
            for node in ast.walk(parsed(path)):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                    [node.module or ""] if isinstance(node, ast.ImportFrom) else []
                assert not [n for n in names if n.startswith(banned)], (path, names)
    with pytest.raises(ImportError, match="from millvib_env.catalog import load_controller"):
        from millvib_env.control import load_controller  # noqa: F401
    assert callable(millvib_env.catalog.load_controller) and millvib_env.control.Controller


#: where a task's name may become a `Task` (docs/architecture.md, "A task name enters once"): the CLI, the API's
#: entry points (`takes_task`, and the default task), and the two files that name a task (a card, a shared entry)
TASK_LOOKUPS = {("src/millvib_env/cli.py", "_run"), ("src/millvib_env/tasks.py", "default_task"),
                ("src/millvib_env/tasks.py", "entry"), ("src/millvib_env/catalog/agents.py", "card_task"),
                ("src/millvib_env/catalog/tuned.py", "shared_from")}


def test_a_task_name_is_looked_up_only_where_it_enters():
    """`get_task` is called only at the edges (`TASK_LOOKUPS`: file, innermost function); below them a `Task`."""
    import ast

    class Calls(ast.NodeVisitor):
        def __init__(self) -> None:
            self.where: list[str] = ["<module>"]
            self.found: set[str] = set()

        def visit_FunctionDef(self, node) -> None:
            self.where.append(node.name)
            self.generic_visit(node)
            self.where.pop()

        def visit_Call(self, node) -> None:
            if getattr(node.func, "id", getattr(node.func, "attr", None)) == "get_task":
                self.found.add(self.where[-1])
            self.generic_visit(node)

    found = set()
    for path in sorted((ROOT / "src").rglob("*.py")):
        calls = Calls()
        calls.visit(parsed(path))
        found |= {(path.relative_to(ROOT).as_posix(), fn) for fn in calls.found}
    assert found <= TASK_LOOKUPS, sorted(found - TASK_LOOKUPS)


def test_every_shipped_card_names_its_agent_and_the_folder_its_command_saves_to():
    """A card's name is its agent's folder's, and a command that names a save folder (`--save-dir`) names the one
    the card lies in, so that rerunning a card's command writes that seed again (an agent trained elsewhere and
    copied in keeps neither the name nor the folder of the place it was trained)."""
    import json

    for card_path in sorted((ROOT / "agents").glob("*/seed-*/card.json")):
        card = json.loads(card_path.read_text())
        folder = card_path.parent.relative_to(ROOT).as_posix()
        assert card["name"] == card_path.parent.parent.name, (folder, card["name"])
        words = (card.get("command") or "").split()  # a note may hold quotes; a save folder holds no space
        if "--save-dir" in words:
            assert words[words.index("--save-dir") + 1].rstrip("/") == folder, (folder, card["command"])


def test_every_shipped_card_alone_rebuilds_its_agents_environment():
    """The plain SB3 recipe builds the environment from the card alone (``gym.make(card["env_id"],
    **card["env_kwargs"])``): for every shipped agent and seed it is the one `load_controller` runs, task included
    (the same first observation and plant on a held-out seed of the agent's task)."""
    import json

    import gymnasium as gym
    import numpy as np

    import millvib_env  # noqa: F401 - registers the environments
    from millvib_env.catalog import load_controller

    for card_path in sorted((ROOT / "agents").glob("*/seed-*/card.json")):
        card = json.loads(card_path.read_text())
        ctrl = load_controller(str(card_path.parent))
        seed = ctrl.task.seeds["heldout"].start
        plain = gym.make(card["env_id"], **card["env_kwargs"])
        ours = ctrl.make_env()
        (o1, i1), (o2, i2) = plain.reset(seed=seed), ours.reset(seed=seed)
        assert card["env_kwargs"]["config"] == ctrl.task.config, card_path
        assert np.array_equal(o1, o2) and i1["params"] == i2["params"], card_path


def test_the_plain_sb3_recipe_gives_every_shipped_agents_benchmark_episode_from_outside_the_clone(tmp_path,
                                                                                                    monkeypatch):
    """agents/README.md's recipe (SB3's own loader, the card's id and keywords, the statistics file, nothing of ours
    but the environment), run from a directory outside the clone for each shipped agent's lowest seed, gives the
    episode `load_controller` gives in the benchmark's loop on a held-out plant of its task (the benchmark batches
    the network's calls; its float32 sums may round differently, hence 1e-6)."""
    import json

    import gymnasium as gym
    import numpy as np
    from stable_baselines3 import PPO, SAC

    import millvib_env  # noqa: F401 - registers the environments
    from millvib_env.catalog import load_controller
    from millvib_env.evaluation.evaluate import run_episodes

    monkeypatch.chdir(tmp_path)
    folders = [sorted(d.glob("seed-*"))[0] for d in sorted((ROOT / "agents").iterdir()) if d.is_dir()]
    assert len(folders) >= 14
    for folder in folders:
        card = json.loads((folder / "card.json").read_text())
        model = {"ppo": PPO, "sac": SAC}[card["algo"]].load(folder / "model.zip", device="cpu")
        stats = np.load(folder / "vecnormalize.npz")
        env = gym.make(card["env_id"], **card["env_kwargs"])
        ctrl = load_controller(str(folder))
        seed = ctrl.task.seeds["heldout"].start
        obs, info = env.reset(seed=seed)
        done = False
        while not done:
            norm = np.clip((obs - stats["mean"]) / np.sqrt(stats["var"] + stats["epsilon"]),
                           -stats["clip_obs"], stats["clip_obs"]).astype(np.float32)
            action, _ = model.predict(norm, deterministic=True)
            obs, reward, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        rec = run_episodes(ctrl, [seed], task=ctrl.task)[0]
        assert np.isclose(info["severity"], rec["severity_mm_s"], rtol=1e-6), folder
        assert np.isclose(info["tracking_rms_um"], rec["tracking_rms_um"], rtol=1e-6), folder


def test_every_millvib_command_and_flag_named_in_the_docs_exists():
    """Docs that cannot drift: each `millvib COMMAND ...` in the README, docs/ and agents/README.md (in a code span
    or a command block) names a command the CLI has, and each of its `--flags` is one that command takes."""
    import argparse

    from millvib_env.cli import build_parser

    commands: dict[str, set[str]] = {}
    for action in build_parser()._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                commands[name] = {o for a in sub._actions for o in a.option_strings}
    files = [ROOT / "README.md", ROOT / "agents" / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    stale, seen = [], 0
    for f in files:
        text = f.read_text()
        spans = re.findall(r"`(millvib [^`\n]+)`", text)
        spans += [ln.strip() for ln in text.splitlines() if ln.strip().startswith("millvib ")]
        for span in spans:
            words = span.split("#")[0].split()
            if len(words) < 2 or not re.fullmatch(r"[a-z][a-z-]*", words[1]):
                continue  # `millvib` alone, or a placeholder (`millvib <command>`)
            seen += 1
            if words[1] not in commands:
                stale.append(f"{f.relative_to(ROOT)}: {span!r}: no command {words[1]!r}")
                continue
            for flag in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", " ".join(words[2:])):
                if flag not in commands[words[1]]:
                    stale.append(f"{f.relative_to(ROOT)}: {span!r}: {words[1]} has no {flag}")
    assert seen > 20 and not stale, stale
