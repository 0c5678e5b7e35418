"""Moved to `millvib_env.evaluation.stats`; this name is the same module, kept for one release."""
import sys

from millvib_env.evaluation import stats as _moved

sys.modules[__name__] = _moved
