"""Write the environment manuals of docs/environments.md from the environments' docstrings (their one home).

    python scripts/env_docs.py           # rewrite the generated blocks
    python scripts/env_docs.py --check   # exit 1 if the file is out of date (tests/test_docs.py does this)

The blocks lie between ``<!-- generated: ENV_ID -->`` and ``<!-- end generated -->``; the rest of the
file is written by hand.
"""
from __future__ import annotations

import argparse
import inspect
import re
import sys
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "environments.md"
BLOCK = re.compile(r"(<!-- generated: (?P<id>[\w-]+) -->\n)(?P<body>.*?)(<!-- end generated -->)", re.S)


def render(env_id: str) -> str:
    """The manual of `env_id` as markdown: the class docstring, its sections one level down."""
    import gymnasium as gym

    import millvib_env  # noqa: F401 (registers the ids)

    cls = gym.spec(env_id).entry_point
    if isinstance(cls, str):
        module, name = cls.split(":")
        cls = getattr(__import__(module, fromlist=[name]), name)
    text = inspect.cleandoc(cls.__doc__)
    text = re.sub(r"^## ", "### ", text, flags=re.M)
    text = re.sub(r"``([^`]+)``", r"`\1`", text)
    return text.strip() + "\n"


def rewrite(text: str) -> str:
    return BLOCK.sub(lambda m: m.group(1) + render(m.group("id")) + m.group(4), text)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only check that the file is up to date")
    args = ap.parse_args()
    old = DOC.read_text()
    new = rewrite(old)
    if args.check:
        if new != old:
            print(f"{DOC} is out of date: run python scripts/env_docs.py", file=sys.stderr)
            return 1
        return 0
    DOC.write_text(new)
    print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
