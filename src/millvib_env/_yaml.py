"""YAML loading that reads 1e4 and 2.5e9 as numbers (PyYAML's YAML 1.1 rules read them as strings) and refuses
what a config file never needs: aliases, deep nesting and repeated keys."""

from __future__ import annotations

import copy
import re
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

from millvib_env._checks import shown_path


#: the deepest nesting a config file may have (the project's own are at most 5 deep)
MAX_DEPTH = 32


class _NoRepeatedKeys:
    """A SafeLoader's constructor that refuses a key given twice in one mapping (PyYAML keeps the last one
    silently). An alias and deep nesting are refused by `_check_graph`, between composing and building."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:  # an unhashable key: PyYAML's own error follows
                continue
            if duplicate:
                raise yaml.constructor.ConstructorError(None, None, f"the key {key!r} is given twice",
                                                        key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


class _PyLoader(_NoRepeatedKeys, yaml.SafeLoader):
    """PyYAML's own parser (Python)."""


class _CLoader(_NoRepeatedKeys, getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """libyaml's parser (C): the same documents, the same resolver and constructor (PyYAML's, in Python), so the
    same data, read faster (docs/performance.md). They differ on damaged text only: libyaml takes a tab
    inside a plain scalar, which the schema then refuses as a value of the wrong type."""


#: the loader: libyaml's where PyYAML was built with it, else PyYAML's own
_Loader = _CLoader if getattr(yaml, "__with_libyaml__", False) else _PyLoader


def _check_graph(root: yaml.Node) -> None:
    """Refuse, in the composed node graph (before anything is built or expanded): an alias (``*name``, which
    lets a small file expand without bound; composed, it is a node met a second time) and nesting deeper
    than `MAX_DEPTH` (the root is level 1). Iterative: no recursion on a deep graph."""
    seen: set[int] = set()
    stack = [(root, 1)]
    while stack:
        node, depth = stack.pop()
        if id(node) in seen:
            raise yaml.composer.ComposerError(None, None, "an alias (*name) is not allowed in a config file",
                                              node.start_mark)
        seen.add(id(node))
        if depth > MAX_DEPTH:
            raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_DEPTH} levels", node.start_mark)
        if isinstance(node, yaml.SequenceNode):
            stack.extend((child, depth + 1) for child in reversed(node.value))
        elif isinstance(node, yaml.MappingNode):
            stack.extend((child, depth + 1) for pair in reversed(node.value) for child in reversed(pair))


for _cls in (_PyLoader, _CLoader):
    _cls.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                   |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                   |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                   |[-+]?\.(?:inf|Inf|INF)
                   |\.(?:nan|NaN|NAN))$""", re.X),
        list("-+0123456789."),
    )



#: the largest config file read (a YAML config is a few kB; /dev/zero or a huge file is refused, not read)
MAX_BYTES = 16 * 2**20


#: the largest text whose parse is kept for the process (the project's configs are a few kB)
MAX_CACHED = 2**16


@lru_cache(maxsize=256)
def _parse(text: str) -> Any:
    """A YAML text's data, parsed once per process per text (a benchmark reads the same few config files dozens
    of times); callers get a deep copy. A text that fails to parse raises each time: errors are not cached."""
    return parse_text(text)


def parse_text(text: str, loader_class: type = _Loader) -> Any:
    """A YAML text's data: composed by `loader_class`'s parser, checked (`_check_graph`), then built by its safe
    constructor (no tag builds a Python object). Raises yaml.YAMLError on a text it refuses."""
    loader = loader_class(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_graph(node)
        try:
            return loader.construct_document(node)
        except (IndexError, KeyError, TypeError, AttributeError) as err:
            # PyYAML's constructors fail so on a tag with a value it cannot hold (`!!float` with none, `!!bool x`)
            raise yaml.constructor.ConstructorError(None, None, f"a tagged value that its tag cannot hold "
                                                    f"({type(err).__name__})", None) from None
    finally:
        loader.dispose()


def load_yaml(path: str | Path, what: str = "config file", mapping: bool = False) -> Any:
    """The data of a YAML file, read with a safe loader (no tags that build Python objects); a file
    that is missing, not a regular file, too large, not UTF-8 or not valid YAML is a ValueError of
    one line naming it (and `what` it is); `mapping` also refuses anything but a mapping."""
    path = Path(path)
    try:
        if not path.is_file():
            raise ValueError("no such file" if not path.exists() else "not a regular file")
        if path.stat().st_size > MAX_BYTES:
            raise ValueError(f"larger than {MAX_BYTES // 2**20} MiB")
        text = path.read_bytes().decode("utf-8")
        data = copy.deepcopy(_parse(text)) if len(text) <= MAX_CACHED else _parse.__wrapped__(text)
    except ValueError as err:  # includes UnicodeDecodeError
        raise ValueError(f"{what} {shown_path(path)} cannot be read: {str(err).splitlines()[0]}") from None
    except OSError as err:
        raise ValueError(f"{what} {shown_path(path)} cannot be read: {err.strerror or type(err).__name__}") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        problem = getattr(err, "problem", None) or str(err).splitlines()[0]
        raise ValueError(f"{what} {shown_path(path)} is not valid YAML{where}: {problem}") from None
    except RecursionError:
        raise ValueError(f"{what} {shown_path(path)} is nested too deeply") from None
    if mapping and not isinstance(data, dict):
        raise ValueError(f"{what} {shown_path(path)} must be a mapping (key: value lines), not {type(data).__name__}")
    return data
