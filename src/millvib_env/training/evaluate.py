"""Moved to `millvib_env.evaluation.evaluate`; this name is the same module, kept for one release."""
import sys

from millvib_env.evaluation import evaluate as _moved

sys.modules[__name__] = _moved
