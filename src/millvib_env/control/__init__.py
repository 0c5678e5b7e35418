"""Controllers: the classical baselines (`policies`), trained agents and their folders (`agents`), and
`load_controller` (`factory`), which builds any of them by name. The public names are imported on
first use, so ``import millvib_env.control.base`` stays light."""

_PUBLIC = {"load_controller": "factory", "load_control_config": "factory", "BASELINES": "registry",
           "REFERENCE": "registry", "baseline_names": "registry", "REGISTRY": "registry", "list_agents": "agents",
           "agent_seeds": "agents", "AgentPolicy": "agents", "Controller": "base"}
__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name in _PUBLIC:
        import importlib

        return getattr(importlib.import_module(f"millvib_env.control.{_PUBLIC[name]}"), name)
    raise AttributeError(f"module 'millvib_env.control' has no attribute {name!r}")
