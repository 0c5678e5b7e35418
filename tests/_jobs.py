"""Jobs for the worker-pool tests: importable by a spawned worker without the test modules' imports."""
import time
from pathlib import Path


def fail_or_finish_late(i: int, folder: str) -> int:
    """Job 0 fails at once; the others would write a file after 30 s."""
    if i == 0:
        raise ValueError("job 0 failed")
    time.sleep(30)
    Path(folder, f"finished-{i}").write_text("late")
    return i
