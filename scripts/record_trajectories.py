"""Hash the envs' trajectories over many configurations, to compare two checkouts byte for byte.

Each configuration (both envs; default, noisy, randomised, dead-zone, sine and random-step
references, Coulomb and LuGre laws; 1, 7 and 300 envs; the vector env's autoreset modes;
serial and threaded at 300) is stepped 150 times with the same random actions from
``reset(seed=3)``; observations, rewards, flags and the numeric ``info`` entries feed one
SHA-256 per configuration. Run it against each checkout and compare the JSON files::

    PYTHONPATH=/path/to/old python scripts/record_trajectories.py old.json
    python scripts/record_trajectories.py new.json
    python scripts/record_trajectories.py --compare old.json new.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode

import frictiongym  # noqa: F401  (registers the envs)

ENVS = ("frictiongym/RotaryServo-v1", "frictiongym/AltinoDistance-v1")
RANDOMIZE = {
    "friction": (0.7, 1.3),
    "inertia": (0.9, 1.1),
    "damping": (0.8, 1.2),
    "sensor_gain": (0.98, 1.02),
}
SETTINGS: dict[str, dict[str, Any]] = {
    "default": {},
    "noise": {"sensor_noise": True},
    "random": {"randomize": RANDOMIZE},
    "deadzone": {"deadzone": None},  # 0.1 V or 50 motor units
    "sine": {"reference": "sine"},
    "random_steps": {"reference": "random_steps"},
    "coulomb": {"friction": "coulomb"},
    "lugre": {"friction": "lugre"},
}
MODES = {"NextStep": AutoresetMode.NEXT_STEP, "SameStep": AutoresetMode.SAME_STEP}


def _make(env_id: str, kwargs: dict[str, Any], n: int, mode: str, parallel: bool | None) -> Any:
    if mode == "single":
        return gym.make(env_id, **kwargs)
    extra = {} if parallel is None else {"parallel": parallel}
    return gym.make_vec(
        env_id,
        num_envs=n,
        vectorization_mode="vector_entry_point",
        autoreset_mode=MODES[mode],
        **kwargs,
        **extra,
    )


def _digest(env: Any, single: bool) -> str:
    h = hashlib.sha256()
    obs, _ = env.reset(seed=3)
    h.update(np.ascontiguousarray(obs).tobytes())
    rng = np.random.default_rng(1)
    space = env.action_space
    for _ in range(150):
        action = rng.uniform(space.low, space.high).astype(np.float32) * 0.3
        obs, reward, terminated, truncated, info = env.step(action)
        for array in (obs, reward, terminated, truncated):
            h.update(np.ascontiguousarray(np.asarray(array)).tobytes())
        for key in sorted(k for k in info if not k.startswith("_")):
            value = info[key]
            if isinstance(value, np.ndarray | float | int | bool | np.floating):
                h.update(np.ascontiguousarray(np.asarray(value)).tobytes())
        if single and (terminated or truncated):
            env.reset()
    return h.hexdigest()


def record() -> dict[str, str]:
    """Return one digest per configuration."""
    out = {}
    for env_id in ENVS:
        for name, settings in SETTINGS.items():
            kwargs = dict(settings)
            if "deadzone" in kwargs:
                kwargs["deadzone"] = 0.1 if "Rotary" in env_id else 50.0
            for n in (1, 7, 300):
                for mode in ("single",) if n == 1 else tuple(MODES):
                    for parallel in (False, True) if n == 300 else (None,):
                        env = _make(env_id, kwargs, n, mode, parallel)
                        key = f"{env_id}|{name}|{n}|{mode}|{parallel}"
                        out[key] = _digest(env, mode == "single")
                        env.close()
    return out


def main(argv: list[str] | None = None) -> int:
    """Record to a JSON file, or compare two."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", help="the JSON file to write, or two to compare")
    parser.add_argument("--compare", action="store_true", help="compare two recorded files")
    args = parser.parse_args(argv)
    if args.compare:
        if len(args.files) != 2:
            parser.error("--compare takes two files")
        old, new = (json.load(open(f)) for f in args.files)
        differ = sorted(k for k in old.keys() | new.keys() if old.get(k) != new.get(k))
        print(f"{len(old)} and {len(new)} configurations; {len(differ)} differ")
        for key in differ:
            print(f"  {key}")
        return 1 if differ else 0
    with open(args.files[0], "w") as f:
        json.dump(record(), f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
