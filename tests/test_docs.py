"""The documentation has one home per fact: the environment manuals come from the docstrings, and every
local link resolves."""
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_environment_manuals_are_the_docstrings():
    run = subprocess.run([sys.executable, str(ROOT / "scripts" / "env_docs.py"), "--check"], capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr


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


def test_the_plain_sb3_recipe_runs_as_written_and_gives_the_benchmarks_episode(monkeypatch):
    # agents/README.md: a shipped agent loaded with PPO.load and the statistics file, nothing of ours
    # but the environment, gives the same episode as load_controller in the benchmark's loop
    import numpy as np

    from millvib_env.control import load_controller
    from millvib_env.training.evaluate import run_episodes

    text = (ROOT / "agents" / "README.md").read_text()
    code = re.search(r"<!-- recipe: plain-sb3 -->\n```python\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(ROOT)
    scope: dict = {}
    exec(compile(code, "agents/README.md", "exec"), scope)  # noqa: S102 - the documented recipe itself
    rec = run_episodes(load_controller("ppo-gain-pf-rolling"), [120000], task="rolling")[0]
    assert np.isclose(scope["info"]["severity"], rec["severity_mm_s"], rtol=1e-6)
    assert np.isclose(scope["info"]["tracking_rms_um"], rec["tracking_rms_um"], rtol=1e-6)
