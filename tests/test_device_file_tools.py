"""The worked example (a ball-screw stage from its description file) through every tool.

What a user of their own rig runs: the env on the emulated device, the emulator's command in
another process, benchmark, train, sim2real. The identification and tuning are in
tests/test_device_file.py.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from _emulator_cli import emulator_port

import frictiongym.envs as envs
from frictiongym import devices
from frictiongym.cli import main
from frictiongym.hardware import protocol
from frictiongym.hardware.base import kind_of_code
from frictiongym.hardware.errors import HardwareError

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = str(REPO / "examples" / "ball_screw" / "ball_screw_stage.toml")


def test_the_emulated_device_reads_as_the_simulator():
    on_device = envs.make(EXAMPLE, backend="emulator://ball-screw?lockstep=1", log=False)
    simulated = envs.make(EXAMPLE)
    try:
        on_device.reset(seed=0)
        assert on_device.unwrapped.sim.info.kind == "ball-screw"
        assert on_device.unwrapped.sim.info.counts_per_rev == 2000
        simulated.reset(seed=0)
        for u in (1.0,) * 50 + (-0.2,) * 50:
            action = np.array([u], np.float32)
            device_obs, *_ = on_device.step(action)
            sim_obs, *_ = simulated.step(action)
            np.testing.assert_array_equal(device_obs, sim_obs)
    finally:
        on_device.close()
        simulated.close()


def test_a_described_device_s_hello_needs_the_host_to_expect_it():
    code = int(protocol.DeviceKind.AXIS)
    assert kind_of_code(code, "ball-screw") == "ball-screw"
    with pytest.raises(HardwareError, match="described by a file"):
        kind_of_code(code, None)
    assert kind_of_code(1, None) == "rotary"


def test_emulate_serves_the_described_device_to_its_env(tmp_path):
    argv = [sys.executable, "-m", "frictiongym.cli", "emulate", "--device", EXAMPLE, "--quiet"]
    with emulator_port(argv) as port:
        env = envs.make(EXAMPLE, backend=f"serial://{port}", log=False)
        try:
            obs, _ = env.reset()
            assert env.unwrapped.sim.info.kind == "ball-screw"
            for _ in range(20):
                obs, *_ = env.step(np.array([2.0], np.float32))
            assert obs[0] > 0.0  # it moved, in encoder counts of the file
            assert obs[0] / 0.0025 == pytest.approx(round(obs[0] / 0.0025))
        finally:
            env.close()


def test_emulate_names_a_bad_description(tmp_path, capsys):
    bad = tmp_path / "stage.toml"
    bad.write_text(Path(EXAMPLE).read_text().replace("dt = 0.001", "dt = -1.0"))
    assert main(["emulate", "--device", str(bad), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ")
    assert "dt: = -1.0" in err


def test_benchmark_runs_the_described_device_s_scenarios(tmp_path):
    out = tmp_path / "bench"
    assert main(["benchmark", "--device", EXAMPLE, "--quick", "--out", str(out), "--quiet"]) == 0
    runs = json.loads((out / "results.json").read_text())
    names = {r["scenario"] for r in runs}
    assert {"paper-ball-screw-pid", "paper-ball-screw-compensated"} <= names
    assert all(r["env_id"] == EXAMPLE for r in runs)
    assert (out / "ball-screw_response.png").exists()
    paper = {r["scenario"]: r for r in runs if r["group"] == "paper"}
    assert paper["paper-ball-screw-pid"]["metrics"]["steady_state_error"] < 0.05  # mm


def test_train_and_sim2real_take_the_description_file(tmp_path):
    pytest.importorskip("stable_baselines3")
    model = tmp_path / "train"
    assert main(["train", "--device", EXAMPLE, "--quick", "--out", str(model), "--quiet"]) == 0
    assert json.loads((model / "train.json").read_text())["env_id"] == EXAMPLE
    report = tmp_path / "s2r"
    backend = "emulator://ball-screw?lockstep=1"
    args = ["sim2real", "--device", EXAMPLE, "--backend", backend, "--repeats", "1"]
    assert main([*args, "--steps", "300", "--out", str(report), "--quiet"]) == 0
    result = json.loads((report / "sim2real.json").read_text())
    assert result["env_id"] == EXAMPLE
    assert devices.get(EXAMPLE).name == "BallScrewStage"


def test_a_described_device_that_is_not_the_env_s_file_is_refused(tmp_path):
    from frictiongym.hardware.errors import ProtocolError

    other = tmp_path / "other.toml"
    text = Path(EXAMPLE).read_text().replace('name = "BallScrewStage"', 'name = "OtherStage"')
    text = text.replace('kind = "ball-screw"', 'kind = "other-stage"')
    other.write_text(text.replace("counts_per_rev = 2000", "counts_per_rev = 4096"))
    devices.load(other)
    backend = "emulator://other-stage?lockstep=1"
    with pytest.raises(ProtocolError, match=r"not the one .*describes: counts_per_rev 4096 \("):
        envs.make(EXAMPLE, backend=backend, log=False)
