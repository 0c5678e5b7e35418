"""Moved to `millvib_env.tuning.search`; this name is the same module, kept for one release."""
import sys

from millvib_env.tuning import search as _moved

sys.modules[__name__] = _moved
