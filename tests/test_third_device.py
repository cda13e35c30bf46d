"""A throwaway third device, added as docs/architecture.md says, meets every tool.

The fixture builds a linear axis (an encoder of 500 counts per 5 mm lead, metres, newtons)
and puts it beside the two devices for one test: in ``DEVICES``, in the hardware's ``KINDS``
and in the protocol's ``DeviceKind``, and as the env class of its own module.
"""

from __future__ import annotations

import dataclasses
import enum

import gymnasium as gym
import numpy as np
import pytest

import frictiongym  # noqa: F401  (registers the ids)
from frictiongym import devices
from frictiongym.benchmark.figures import figure_names, write_figures
from frictiongym.devices import DEVICES, ROTARY, Device, Figures
from frictiongym.envs.base import FrictionEnv
from frictiongym.hardware import base, emulated, protocol
from frictiongym.hardware.emulated import EmulatedBackend
from frictiongym.hardware.errors import HardwareError
from frictiongym.hardware.firmware import PLACE_RANGE, Firmware
from frictiongym.identification.identify import Plan
from frictiongym.plants import PlantParams
from frictiongym.plants.sensors import SENSOR_IR
from frictiongym.sim2real.run import check_reference

LINEAR = dataclasses.replace(
    ROTARY,
    name="LinearAxis",
    kind="linear",
    env_id="frictiongym/LinearAxis-v0",
    title="a linear axis",
    plant=PlantParams(inertia=2.0, damping=5.0, command_limit=50.0),
    dt=0.001,
    noise_std=1e-5,
    references={**ROTARY.references, "step": {"value": 0.1}},
    limit=0.5,
    observation_names=("position", "velocity", "reference"),
    output="position",
    position_unit="m",
    command_unit="N",
    identification={"env_kwargs": {"safety_limit": 1.0}},  # no plan of its own
    command_scale=100,  # 10 mN: 50 N is 5000 counts
    figures=Figures(
        "linear axis, 0.1 m step", "linear axis: residual", "linear axis", 0.1, 0.01, 0.01
    ),
    counts_per_rev=500,
    position_per_rev=0.005,  # 10 µm per count
    drawing=None,
)


class LinearAxisEnv(FrictionEnv):
    """The third device's single env (its module's, in a real addition)."""

    device = LINEAR


@pytest.fixture
def linear(monkeypatch: pytest.MonkeyPatch) -> Device:
    kinds = (*base.KINDS, LINEAR.kind)
    monkeypatch.setattr(devices, "DEVICES", (*DEVICES, LINEAR))
    for module in (base, emulated):  # the others ask base (kind_code, kind_of_code)
        monkeypatch.setattr(module, "KINDS", kinds)
    members = {kind.upper(): code for code, kind in enumerate(kinds, 1)}
    monkeypatch.setattr(protocol, "DeviceKind", enum.IntEnum("DeviceKind", members))
    return LINEAR


def test_the_benchmark_figures_draw_every_device(linear, tmp_path):
    names = figure_names()
    assert {"linear_response.png", "residual_linear_response.png"} <= set(names)
    written = write_figures([], tmp_path)  # no runs: the friction curves of the three devices
    assert [p.name for p in written] == ["friction_curves.png"]


def test_the_firmware_reads_the_description(linear):
    fw = Firmware("linear")
    hello = fw.hello
    assert (hello.kind, hello.counts_per_rev) == (3, 500)
    assert (hello.command_scale, hello.command_limit) == (100, 5000)
    assert not hello.capabilities & protocol.Capability.DISTANCE_LIMIT
    assert fw.guard is None
    fw.receive(protocol.Place(0.0123), 0.0)
    fw.tick(linear.dt)
    assert fw.position == pytest.approx(0.0123)
    assert fw.sensor == 1230  # counts of 10 µm
    fw.receive(protocol.Command(1, 0, protocol.Flag.ENABLE | protocol.Flag.ZERO_POSITION), 0.0)
    fw.tick(2 * linear.dt)
    assert fw.sensor == 0  # an encoder: it can be zeroed
    fw.receive(protocol.Place(2 * PLACE_RANGE), 0.0)
    fw.tick(3 * linear.dt)
    assert fw.rejected == 1


def test_the_env_and_the_emulated_device_read_the_encoder_of_the_description(linear):
    step = linear.encoder_step
    assert step == 0.005 / 500
    env = LinearAxisEnv()
    obs, _ = env.reset(seed=0, options={"position": 0.01234})
    assert obs[0] == np.float32(1234 * step)  # quantised to its counts, not the QUBE's
    on_device = LinearAxisEnv(backend="emulator://linear?lockstep=1", log=False)
    try:
        first, _ = on_device.reset(seed=0)
        assert on_device.unwrapped.sim.info.counts_per_rev == 500
        moved, *_ = on_device.step(np.array([50.0], dtype=np.float32))
        assert moved[0] > first[0]
        assert moved[0] / step == pytest.approx(round(moved[0] / step))
    finally:
        on_device.close()
    env.close()


def test_a_device_without_a_drawing_says_so(linear):
    env = LinearAxisEnv(render_mode="rgb_array")
    env.reset(seed=0)
    with pytest.raises(NotImplementedError, match="LinearAxis has no drawing"):
        env.render()
    env.close()


def test_identify_refuses_a_device_without_a_plan(linear):
    with pytest.raises(ValueError, match=r"LinearAxis has no identification plan.*levels"):
        Plan.for_device("linear")


def test_messages_take_the_units_of_the_description(linear):
    with pytest.raises(ValueError, match=r"reference 1 m lies beyond the safety limit of 0\.5 m"):
        check_reference("linear", 1.0)
    env = LinearAxisEnv()
    with pytest.raises(ValueError, match=r"within the safety limit ±0\.5 m"):
        env.reset(options={"position": 0.7})
    env.close()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"command_scale": 10_000}, r"plant\.command_limit \* command_scale = 100000 counts"),
        ({"counts_per_rev": 70_000}, "counts_per_rev must be 1..65535"),
        ({"sensor": SENSOR_IR}, "counts_per_rev must be 1..65535 with SENSOR_ENCODER and 0"),
    ],
)
def test_a_description_the_wire_or_the_kernel_cannot_carry_is_refused(changes, message):
    with pytest.raises(ValueError, match=f"RotaryServo: {message}"):
        dataclasses.replace(ROTARY, **changes)


def test_the_emulator_s_own_error_is_reported_when_it_dies_on_open(monkeypatch):
    def broken(self, message, now):
        raise RuntimeError("the firmware broke")

    monkeypatch.setattr(Firmware, "receive", broken)
    backend = EmulatedBackend("rotary", lockstep=True)
    with pytest.raises(HardwareError, match="emulator of 'rotary' stopped: RuntimeError"):
        backend.open()
    assert backend.emulator is None


def test_gym_still_makes_the_two_devices():
    for device in DEVICES:
        gym.make(device.env_id).close()
