"""Skips shared by the test modules."""
import importlib.util

import pytest


def skip_without_sbx() -> None:
    """Skip where sbx is not installed, without importing it: JAX is imported by
    `catalog.agents.algo_class`, which first points its compilation cache at ours (`_jax_cache`)."""
    if importlib.util.find_spec("sbx") is None:
        pytest.skip("sbx is not installed")
