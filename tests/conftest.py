"""Hypothesis profiles.

* ``default``: 60 random examples per property, a fresh draw each run.
* ``ci`` (chosen when ``CI`` is set): the same 60 examples every run, so a landing never
  depends on the luck of the draw.
* ``thorough``: 3000 random examples, for hunting edge cases after touching the kernel:
  ``HYPOTHESIS_PROFILE=thorough python -m pytest -k property``.
"""

import os
import tempfile

from hypothesis import settings

settings.register_profile("default", max_examples=60)
settings.register_profile("ci", max_examples=60, derandomize=True)
settings.register_profile("thorough", max_examples=3000)
settings.load_profile(
    os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "default")
)

# Render tests and gymnasium's check_env (which opens every render mode) never need a screen.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

# Device runs log to $FRICTIONGYM_RUNS by default: keep the tests' logs out of the checkout.
os.environ["FRICTIONGYM_RUNS"] = tempfile.mkdtemp(prefix="frictiongym-runs-")
