"""Agent hyperparameters (configs/agents/<algo>.yml, rl-baselines3-zoo layout), read without eval().

The zoo writes nested arguments as strings such as ``"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"``
and evaluates them. We parse the same strings with Python's `ast` and accept only data: ``dict(...)``
calls with keyword arguments, dict/list/tuple literals, numbers, strings, booleans, None, and
``nn.<activation>`` names from a fixed list of torch activations. Anything else (a function call, an
attribute of something else, an import) is refused with the key named, so a config file cannot run code.
"""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

from millvib_env._checks import shown, shown_path
from millvib_env._paths import config_dir
from millvib_env._yaml import load_yaml

__all__ = ["parse_zoo_value", "load_hyperparams", "ACTIVATIONS", "ZOO_ALGO"]

#: our algorithm name -> the zoo's (and the file under configs/agents/)
ZOO_ALGO = {"ppo": "ppo", "sac": "sac", "recurrentppo": "ppo_lstm"}

#: the torch.nn activations a config may name (as nn.<name>)
ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "GELU", "SiLU", "Sigmoid", "Softplus", "Mish")


def _convert(node: ast.AST, where: str) -> Any:
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float, str, bool, type(None))):
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        value = _convert(node.operand, where)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return -value if isinstance(node.op, ast.USub) else value
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_convert(e, where) for e in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Dict) and all(k is not None for k in node.keys):
        return {_convert(k, where): _convert(v, where) for k, v in zip(node.keys, node.values)
                if k is not None}
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
        return {kw.arg: _convert(kw.value, where) for kw in node.keywords if kw.arg is not None}
    if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "nn"
            and node.attr in ACTIVATIONS):
        import torch.nn as nn

        return getattr(nn, node.attr)
    raise ValueError(f"{where}: {ast.unparse(node)!r} is not allowed: only dict(...), literals and nn.<activation> "
                     f"({', '.join(ACTIVATIONS)}) are read from a config")


def parse_zoo_value(value: Any, where: str = "value") -> Any:
    """A zoo-style ``"dict(...)"`` string as data (other values unchanged); ValueError otherwise."""
    if not isinstance(value, str) or not value.strip().startswith(("dict(", "{", "[")):
        return value
    try:
        tree = ast.parse(value.strip(), mode="eval")
    except SyntaxError:
        raise ValueError(f"{where}: {shown(value)} is not a valid dict(...) expression") from None
    return _convert(tree.body, where)


def load_hyperparams(algo: str, env_id: str, path: str | Path | None = None) -> dict[str, Any]:
    """The hyperparameters of `algo` for `env_id` from configs/agents/<algo>.yml (or `path`)."""

    path = Path(path) if path else config_dir() / "agents" / f"{ZOO_ALGO.get(algo, algo)}.yml"
    if not path.is_file():
        raise ValueError(f"hyperparameter file {shown_path(path)} not found")
    table = load_yaml(path, "hyperparameter file") or {}
    if not isinstance(table, dict) or env_id not in table or not isinstance(table[env_id], dict):
        have = sorted(map(str, table)) if isinstance(table, dict) else []  # keys of any type
        raise ValueError(f"{shown_path(path)} has no entry for {shown(env_id)}; it has {have}")
    hp = {k: parse_zoo_value(v, f"{path} [{env_id}] {k}") for k, v in table[env_id].items()}
    for key in ("n_envs", "n_timesteps", "policy"):
        if key not in hp:
            raise ValueError(f"{shown_path(path)} [{env_id}] is missing {shown(key)}")
    for key in ("n_envs", "n_timesteps"):
        value = hp[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 1 or value != int(value):
            raise ValueError(f"{shown_path(path)} [{env_id}] {key} = {shown(value)} is invalid: a whole number >= 1")
        hp[key] = int(value)
    return hp
