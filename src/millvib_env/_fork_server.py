"""Imported by the worker pools' fork server only (`distributed._pool_context`), once, when it starts.

The first compiled function a process calls sets up numba's compiler context (its typing and target contexts and
the cache's index), which every worker of a pool paid again, while loading each compiled function after that
costs about a hundredth of it (docs/performance.md). One serial plant function (`plant.model.settled_state`, which runs
`plant_rhs`) called here sets the context up in the server, and every worker forked from it starts with it. It is
serial: numba's thread pool is not started, so no worker inherits one (a worker starts its own where it runs a
parallel kernel)."""

from millvib_env.params import MillParams
from millvib_env.plant.model import settled_state

settled_state(MillParams())
