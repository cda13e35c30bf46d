"""Checks on a real device: deselected by default, run with a device attached.

    FRICTIONGYM_DEVICE=serial:///dev/ttyACM0 FRICTIONGYM_ENV=frictiongym/RotaryServo-v1 \\
        python -m pytest -m hardware tests/test_on_device.py

The servo turns by up to 1 rad; the Altino must stand 25-30 cm from a wall, facing it.
"""

from __future__ import annotations

import os
import time

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401
from frictiongym.controllers import PID, PIDGains
from frictiongym.hardware import DeviceFaultError
from frictiongym.plants.presets import ALTINO_PAPER_GAINS_KI10, ROTARY_PAPER_GAINS

pytestmark = pytest.mark.hardware

DEVICE = os.environ.get("FRICTIONGYM_DEVICE")
ENV_ID = os.environ.get("FRICTIONGYM_ENV", "frictiongym/RotaryServo-v1")
GAINS = {
    "frictiongym/RotaryServo-v1": ROTARY_PAPER_GAINS,
    "frictiongym/AltinoDistance-v1": ALTINO_PAPER_GAINS_KI10,
}


@pytest.fixture
def env(tmp_path):
    if not DEVICE:
        pytest.skip("set FRICTIONGYM_DEVICE to the device's backend URI")
    made = gym.make(ENV_ID, backend=DEVICE, log=tmp_path / "log")
    yield made
    made.close()


def test_a_pid_step_on_the_device_moves_toward_the_target(env):
    pid = PID.for_env(env, PIDGains(**GAINS[ENV_ID]))
    obs, _ = env.reset(seed=0)
    start = obs.copy()
    for _ in range(round(3.0 / env.unwrapped.dt)):
        obs, _, terminated, _, _ = env.step(pid(obs))
        if terminated:
            break
    column = 0 if ENV_ID.endswith(("RotaryServo-v0", "RotaryServo-v1")) else 1
    target = obs[-1]
    assert abs(obs[column] - target) < 0.5 * abs(start[column] - target)
    timing = env.unwrapped.sim.timing()
    assert timing.rate_hz > 0.9 / env.unwrapped.dt


def test_the_device_stops_the_motor_when_the_host_goes_quiet(env):
    env.reset(seed=0)
    env.step(np.array([0.0]))
    watchdog = env.unwrapped.sim.info.watchdog_s
    if watchdog is None:
        pytest.skip("this device has no watchdog (the stock Altino firmware)")
    time.sleep(5 * watchdog)
    with pytest.raises(DeviceFaultError, match="watchdog"):
        env.step(np.array([0.0]))
