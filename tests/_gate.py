"""Imported by a worker pool's fork server in a test (`preload`): the import waits until the file named by
MILLVIB_TEST_GATE exists (a minute at the most), so that no worker starts before the test's parent has run a job
itself. Without the variable (a later server that inherits the module) it passes at once."""
import os
import time
from pathlib import Path

_gate = os.environ.get("MILLVIB_TEST_GATE")
_end = time.monotonic() + 60.0
while _gate and not Path(_gate).exists() and time.monotonic() < _end:
    time.sleep(0.01)
