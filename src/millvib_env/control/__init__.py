"""Controllers, the algorithms: the classical baselines (`policies`: fixed-gain PID, + pressure feedback, + force
feedforward, the oracles), the adaptive PID (`adaptive`), LQR (`lqr`), the MPC bounds (`mpc`), the classical
preview controller (`preview`) and what they share (`base`: `Controller`, `ControllerLoop`). Turning a name into
one of them, or an agent folder into a policy, is `millvib_env.catalog`'s (`load_controller`), one floor above."""

from millvib_env.control.base import Controller

#: the names that moved to the catalog (importable from here before it existed): an import of one says where
MOVED = ("load_controller", "load_control_config", "BASELINES", "REFERENCE", "baseline_names", "REGISTRY",
         "list_agents", "agent_seeds", "AgentPolicy")
__all__ = ["Controller"]


def __getattr__(name: str):
    if name in MOVED:  # an ImportError, so that `from millvib_env.control import NAME` shows this line
        raise ImportError(f"millvib_env.control.{name} has moved to the catalog: from millvib_env.catalog import "
                          f"{name}", name=name)
    raise AttributeError(f"module 'millvib_env.control' has no attribute {name!r}")
