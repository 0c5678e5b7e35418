"""The catalog: everything that turns a name into an object, above the algorithms of `millvib_env.control`.

`registry` (every baseline by name: description, builder, information set, role in the benchmark), `tuned` (the
tuned baselines' config files), `named` (named gain sets in an env's keywords), `agents` (agent folders, cards and
`AgentPolicy`), `manifest` (their checksums), `normalization` (their observation statistics), `onnx_policy` and
`export` (exported graphs), `sbx_to_sb3` (the sbx conversion), `information` (what each controller reads) and
`factory` (`resolve_controller` -> a frozen `ControllerSpec`, `build_controller`, `load_controller`). The public
names are imported on first use, so ``import millvib_env.catalog.information`` stays light."""

_PUBLIC = {"load_controller": "factory", "resolve_controller": "factory", "build_controller": "factory",
           "ControllerSpec": "factory", "load_control_config": "factory", "BASELINES": "registry",
           "REFERENCE": "registry", "baseline_names": "registry", "REGISTRY": "registry", "list_agents": "agents",
           "agent_seeds": "agents", "AgentPolicy": "agents"}
__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name in _PUBLIC:
        import importlib

        return getattr(importlib.import_module(f"millvib_env.catalog.{_PUBLIC[name]}"), name)
    raise AttributeError(f"module 'millvib_env.catalog' has no attribute {name!r}")
