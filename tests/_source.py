"""The repository's Python files, each parsed once per test session: several structure tests (imports declared,
imports at the top, where a task name is looked up, which layer imports which) read the same files."""
import ast
from functools import lru_cache
from pathlib import Path


@lru_cache(maxsize=None)
def parsed(path: Path) -> ast.Module:
    """The syntax tree of the file at `path` (as it was when first read in this session)."""
    return ast.parse(Path(path).read_text())
