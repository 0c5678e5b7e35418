"""Moved to `millvib_env.tuning.baselines`; this name is the same module, kept for one release."""
import sys

from millvib_env.tuning import baselines as _moved

sys.modules[__name__] = _moved
