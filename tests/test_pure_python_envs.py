"""The envs under ``NUMBA_DISABLE_JIT=1`` (numba's debugging mode) agree with the compiled ones."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from frictiongym.envs import _kernel as env_kernel

NOISY_RUN = """
import sys
import gymnasium as gym
import numpy as np
import frictiongym

values = []
ids = (("frictiongym/RotaryServo-v1", 0.3), ("frictiongym/AltinoDistance-v1", 300.0))
for env_id, scale in ids:
    env = gym.make_vec(env_id, num_envs=257, vectorization_mode="vector_entry_point",
                       sensor_noise=True, max_episode_steps=3)
    obs, _ = env.reset(seed=3)
    values.append(obs)
    rng = np.random.default_rng(0)
    for _ in range(5):  # episode ends and autoresets on the way
        obs, reward, terminated, truncated, _ = env.step(
            rng.uniform(-scale, scale, (257, 1)).astype(np.float32))
        values += [obs, reward, terminated, truncated]
np.save(sys.argv[1], np.concatenate([np.ravel(v).astype(np.float64) for v in values]))
"""


def test_noisy_vector_envs_run_without_numba_as_compiled(tmp_path: Path) -> None:
    # two blocks of envs (257), sensor noise, fresh envs: the noise path of the kernel
    script = tmp_path / "noisy.py"
    script.write_text(NOISY_RUN)
    results = []
    for mode in ("py", "jit"):
        env = {key: val for key, val in os.environ.items() if key != "NUMBA_DISABLE_JIT"}
        if mode == "py":
            env["NUMBA_DISABLE_JIT"] = "1"
        out = tmp_path / f"{mode}.npy"
        command = [sys.executable, "-W", "ignore", str(script), str(out)]
        subprocess.run(command, env=env, check=True, timeout=600)
        results.append(np.load(out))
    np.testing.assert_array_equal(results[0], results[1])


def test_the_noise_of_a_block_is_read_at_an_index_of_any_number_type() -> None:
    # in Python (NUMBA_DISABLE_JIT) with NumPy 1.x an int minus a uint64 is a float
    noise = np.array([0.5, -1.5, 2.5])
    assert env_kernel._noise_at(noise, 2.0) == 2.5
    assert env_kernel._noise_at(noise, np.uint64(1)) == -1.5
    assert env_kernel._noise_at(0.0, 7) == 0.0
