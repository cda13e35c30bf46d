"""The device descriptions: one lookup by any spelling, device_of, and every tool reading them."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import ClipAction

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym import devices
from frictiongym.benchmark.scenarios import all_scenarios, residual_scenarios
from frictiongym.controllers import LoopSpec
from frictiongym.devices import ALTINO, DEVICES, ROTARY, Device, device_of
from frictiongym.envs import ENV_IDS
from frictiongym.hardware import KINDS
from frictiongym.hardware.firmware import Firmware
from frictiongym.identification.identify import Plan, plan_for
from frictiongym.identification.refine import ReciprocalReading
from frictiongym.params import DeviceParams
from frictiongym.residual import ResidualConfig
from frictiongym.residual.train import env_kwargs, hyperparameters

SPELLINGS = [
    (ROTARY, ("rotary", "RotaryServo", "frictiongym/RotaryServo-v1")),
    (ALTINO, ("altino", "AltinoDistance", "frictiongym/AltinoDistance-v1")),
]


@pytest.mark.parametrize(("device", "spellings"), SPELLINGS, ids=["rotary", "altino"])
def test_every_spelling_finds_the_one_description(device, spellings):
    for spelling in spellings:
        assert devices.get(spelling) is device
    assert devices.get(device) is device
    assert (device.kind, device.name, device.env_id) == spellings


@pytest.mark.parametrize("spelling", ["Rotary", "servo", "frictiongym/Nope-v0", ""])
def test_an_unknown_spelling_is_one_line_naming_the_valid_ones(spelling):
    with pytest.raises(ValueError, match="unknown device") as caught:
        devices.get(spelling)
    message = str(caught.value)
    assert "\n" not in message
    for _, spellings in SPELLINGS:
        assert all(name in message for name in spellings)


def test_the_descriptions_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        ROTARY.dt = 0.001  # type: ignore[misc]
    assert ROTARY.dt == 0.002


@pytest.mark.parametrize("device", DEVICES, ids=lambda d: d.kind)
def test_device_of_single_wrapped_and_vector_envs(device):
    env = gym.make(device.env_id)  # a TimeLimit and checker wrappers around it
    assert device_of(env) is device
    assert device_of(env.unwrapped) is device
    assert device_of(ClipAction(env)) is device
    env.close()
    vector = gym.make_vec(device.env_id, 3, vectorization_mode="vector_entry_point")
    assert device_of(vector) is device
    vector.close()


def test_device_of_refuses_other_envs_and_lookalikes():
    env = gym.make("CartPole-v1")
    with pytest.raises(TypeError, match="CartPoleEnv is not a frictiongym env"):
        device_of(env)
    env.close()

    class Torchy:
        device = "cpu"

    with pytest.raises(TypeError, match="not a frictiongym env"):
        device_of(Torchy())


@pytest.mark.parametrize("device", DEVICES, ids=lambda d: d.kind)
def test_the_env_reads_its_task_from_the_description(device):
    env = gym.make(device.env_id, reference="sine")
    assert (
        gym.spec(device.env_id).max_episode_steps
        == device.episode_steps
        == ENV_IDS[device.env_id][3]
    )
    assert env.unwrapped.dt == device.dt
    assert env.observation_space.shape == (len(device.observation_names),)
    assert env.action_space.high[0] == device.plant.command_limit
    sine = env.unwrapped.sim.reference
    assert (sine.amplitude, sine.period) == (
        device.references["sine"]["amplitude"],
        device.references["sine"]["period"],
    )
    spec = LoopSpec.from_env(env)
    assert (spec.direction, spec.rest_speed) == (device.direction, device.rest_speed)
    assert spec.position == device.observation_names.index(device.output)
    env.close()


@pytest.mark.parametrize("device", DEVICES, ids=lambda d: d.kind)
def test_the_tools_read_their_settings_from_the_description(device):
    # Benchmark: run length, the paper's gains, the held-out plants' ranges.
    mine = [s for s in all_scenarios() if s.env_id == device.env_id]
    assert mine
    assert all(s.steps == device.benchmark_steps for s in mine)
    assert all(s.device == device.kind for s in mine)
    compensated = [s for s in mine if s.name == f"noise-{device.kind}-compensated-off"]
    assert dataclasses.asdict(compensated[0].gains) == dict(device.paper_gains["compensated"])
    heldout = residual_scenarios(device.name, "model.zip", plants=2)[-1]
    assert heldout.env_kwargs["randomize"] == dict(device.randomization)
    # Residual policies: the observation scales, the training env and the discount.
    config = ResidualConfig.for_device(device.env_id)
    assert config.device == device.name
    assert config.limit == device.plant.command_limit
    assert {k: getattr(config, k) for k in device.residual} == dict(device.residual)
    kwargs = env_kwargs(device.env_id, "default")
    assert kwargs == {**device.training_env, "randomize": dict(device.randomization)}
    assert hyperparameters("ppo", 1000, 1, False, device)["gamma"] == device.training_gamma
    # Identification: the plan and the env arguments it needs.
    plan = Plan.for_device(device.kind)
    assert plan == plan_for(device.env_id)
    assert dict(plan.env_kwargs) == dict(device.identification.get("env_kwargs", {}))
    # Params files: the units; the firmware: the command scale.
    params = DeviceParams.from_model(
        device.paper_friction, inertia=1.0, damping=0.0, device=device.name
    )
    assert dict(params.units) == device.units
    assert Firmware(device.kind).scale == device.command_scale


def test_the_values_the_tables_held():
    assert ROTARY.units == {
        "force": "V",
        "velocity": "rad/s",
        "viscous": "V·s/rad",
        "J": "V·s²/rad",
        "B": "V·s/rad",
    }
    assert ALTINO.units["J"] == "units·s²/cm"
    assert ROTARY.randomization["sensor_gain"] == (0.99, 1.01)
    assert ALTINO.randomization["sensor_gain"] == (0.9, 1.1)
    assert ROTARY.training_precision == 2.0 * math.pi / 2048
    assert ALTINO.training_precision == 5.0**2 / 966.0
    assert ResidualConfig.for_device("rotary").scale == 1.0
    assert ResidualConfig.for_device("altino").scale == 200.0
    plan = Plan.for_device("altino")
    assert plan.reading == ReciprocalReading(966.0, 45.0, 800)
    assert (plan.span.low, plan.span.high, plan.span.margin) == (3.0, 19.5, 0.5)
    assert plan.relay_levels == tuple(round(float(m), 2) for m in np.geomspace(1.03, 2.5, 20))
    assert (ROTARY.command_scale, ALTINO.command_scale) == (1000, 1)
    assert KINDS == tuple(d.kind for d in DEVICES)  # the protocol's device kinds, in order


def test_every_field_is_set_on_every_device():
    for device in DEVICES:
        for field in dataclasses.fields(Device):
            value = getattr(device, field.name)
            assert value is not None or field.name == "velocity_cutoff", field.name


def test_the_benchmark_no_longer_imports_the_residual_package():
    code = (
        "import sys\n"
        "from frictiongym.benchmark.scenarios import residual_scenarios\n"
        "residual_scenarios('rotary', 'model.zip')\n"
        "assert not [m for m in sys.modules if m.startswith('frictiongym.residual')]\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
