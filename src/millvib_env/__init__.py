"""millvib-env: hydraulic screw-down vibration of a rolling mill, as a simulator and RL environments."""
from millvib_env import _numba_cache

_numba_cache.configure()  # before any numba import: cache keyed by this package's source

# isort: split
from millvib_env.params import PAPER_GAINS, MillParams, PIDGains, load_preset

__version__ = "0.1.0"
__all__ = ["MillParams", "PIDGains", "PAPER_GAINS", "load_preset", "__version__"]
