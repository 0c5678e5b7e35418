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
from millvib_env.catalog.normalization import normalize_kwargs
from millvib_env.envs.specs import ENV_SPECS

__all__ = ["parse_zoo_value", "load_hyperparams", "shipped_hyperparams", "ACTIVATIONS", "ZOO_ALGO"]

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


def shipped_hyperparams(path: str | Path) -> Path:
    """A hyperparameter file: `path` where it is a file, else the shipped file it names from any working directory
    (``pf/ppo``, ``pf/ppo.yml`` or ``configs/agents/pf/ppo.yml``: configs/agents/pf/ppo.yml of the package);
    ValueError naming it, with the shipped files, otherwise."""
    given = Path(path)
    if given.is_file():
        return given
    shipped = config_dir() / "agents"
    rel = Path(*given.parts[2:]) if given.parts[:2] == ("configs", "agents") else given
    for candidate in (shipped / rel, shipped / rel.with_name(rel.name + ".yml")):
        if not rel.is_absolute() and candidate.is_file():
            return candidate
    names = sorted(str(f.relative_to(shipped).with_suffix("")) for f in shipped.rglob("*.yml"))
    raise ValueError(f"hyperparameter file {shown_path(given)} not found; the shipped ones, by name: {names}")


def load_hyperparams(algo: str, env_id: str, path: str | Path | None = None) -> dict[str, Any]:
    """The hyperparameters of `algo` for `env_id` from configs/agents/<algo>.yml (or `path`): its entry, or for a
    task config's own id (``MillVib-Valve-Rolling-v1``) without one, its generic id's (``MillVib-Valve-v1``).
    ``normalize`` comes back as VecNormalize's keywords or None (`catalog.normalization.normalize_kwargs`)."""

    path = shipped_hyperparams(path) if path else config_dir() / "agents" / f"{ZOO_ALGO.get(algo, algo)}.yml"
    table = load_yaml(path, "hyperparameter file") or {}
    spec = ENV_SPECS.get(env_id)
    if isinstance(table, dict) and env_id not in table and spec is not None and spec.config is not None \
            and spec.generic_id in table:
        env_id = spec.generic_id  # a task config's own id trains with its generic id's entry (the task sets the config)
    if not isinstance(table, dict) or env_id not in table or not isinstance(table[env_id], dict):
        have = sorted(map(str, table)) if isinstance(table, dict) else []  # keys of any type
        raise ValueError(f"{shown_path(path)} has no entry for {shown(env_id)}; it has {have}")
    hp = {k: parse_zoo_value(v, f"{path} [{env_id}] {k}") for k, v in table[env_id].items() if k != "normalize"}
    if "normalize" in table[env_id]:  # every zoo form, as VecNormalize's keywords (None: none), before any step
        hp["normalize"] = normalize_kwargs(table[env_id]["normalize"], f"{path} [{env_id}] normalize")
    for key in ("n_envs", "n_timesteps", "policy"):
        if key not in hp:
            raise ValueError(f"{shown_path(path)} [{env_id}] is missing {shown(key)}")
    for key in ("n_envs", "n_timesteps"):
        value = hp[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 1 or value != int(value):
            raise ValueError(f"{shown_path(path)} [{env_id}] {key} = {shown(value)} is invalid: a whole number >= 1")
        hp[key] = int(value)
    return hp
