"""How many examples a property-based test draws: its own count in the suite (the derandomized "ci" profile), at
least the "fuzz" profile's under the longer randomized fuzz (`HYPOTHESIS_PROFILE=fuzz`), and exactly
MILLVIB_FUZZ_EXAMPLES where that is set. A test's own `@settings(max_examples=...)` outranks every profile, so
the count goes through here for a profile to lengthen it."""
import os

from hypothesis import settings

FUZZ_ENV = "MILLVIB_FUZZ_EXAMPLES"


def examples(n: int) -> int:
    """The number of examples for a test that draws `n` in the suite."""
    raw = os.environ.get(FUZZ_ENV, "").strip()
    if raw:
        if not raw.isdigit() or int(raw) < 1:
            raise ValueError(f"{FUZZ_ENV} = {raw!r} is invalid: a whole number of examples >= 1")
        return int(raw)
    if os.environ.get("HYPOTHESIS_PROFILE") == "fuzz":
        return max(n, settings.get_profile("fuzz").max_examples)
    return n
