"""Suite-wide settings. Hypothesis draws the same examples on every run (``derandomize``), so the
suite's verdict never depends on a random draw; fresh draws are the job of
``benchmarks/fuzz_probe.py``, whose finds become fixed examples or fixes."""
from hypothesis import settings

settings.register_profile("suite", derandomize=True, database=None)
settings.load_profile("suite")
