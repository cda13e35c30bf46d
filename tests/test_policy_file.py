"""Model files from strangers: loading a residual policy never unpickles anything.

Stable-Baselines3's own ``load`` unpickles the ``:serialized:`` entries of a model's ``data``;
one added entry in a copy of a shipped model runs code on load. These tests build such hostile
zips and show that ``ResidualController.load`` runs none of it.
"""

from __future__ import annotations

import base64
import json
import pickle
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from frictiongym.controllers import ResidualController
from frictiongym.controllers.policy_file import UnsafeModelError

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "models" / "residual" / "rotary.zip"
SERVO = "frictiongym/RotaryServo-v1"


class Touch:
    """A pickle that creates a file when unpickled: the stand-in for any code."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple:
        return (Path.touch, (self.marker,))


def pickled(marker: Path) -> dict[str, str]:
    payload = base64.b64encode(pickle.dumps(Touch(marker))).decode()
    return {":type:": "<class 'object'>", ":serialized:": payload}


def rewrite(source: Path, target: Path, data_edit=None, files: dict | None = None) -> Path:
    """Copy a model zip, editing its ``data`` JSON and replacing or adding members."""
    with zipfile.ZipFile(source) as src, zipfile.ZipFile(target, "w") as dst:
        for name in src.namelist():
            content = src.read(name)
            if name == "data" and data_edit is not None:
                data = json.loads(content)
                data_edit(data)
                content = json.dumps(data).encode()
            if files and name in files:
                content = files[name]
            dst.writestr(name, content)
    return target


def test_sb3_load_runs_an_added_pickle(tmp_path: Path) -> None:
    """The danger the loader avoids: Stable-Baselines3's own load runs the entry."""
    from stable_baselines3 import PPO

    marker = tmp_path / "ran"
    hostile = rewrite(SHIPPED, tmp_path / "m.zip", lambda d: d.update(evil=pickled(marker)))
    PPO.load(hostile, device="cpu")
    assert marker.exists()


def test_residual_load_runs_nothing_and_warns(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    hostile = rewrite(SHIPPED, tmp_path / "m.zip", lambda d: d.update(evil=pickled(marker)))
    with pytest.warns(UserWarning, match=r"pickled entries .*\(evil\)"):
        controller = ResidualController.load(hostile, gym.make(SERVO))
    assert not marker.exists()
    # The policy still works, and acts exactly as the untouched shipped one.
    shipped = ResidualController.load(SHIPPED, gym.make(SERVO))
    obs = np.random.default_rng(0).uniform(-2.0, 2.0, (20, 6)).astype(np.float32)
    a = controller.model.predict(obs, deterministic=True)[0]
    np.testing.assert_array_equal(a, shipped.model.predict(obs, deterministic=True)[0])


def test_standard_sb3_pickles_are_replaced_not_run(tmp_path: Path) -> None:
    """Entries SB3 pickles itself (the policy class, the spaces) are never read either."""
    marker = tmp_path / "ran"

    def poison(data: dict) -> None:
        for key in ("policy_class", "observation_space", "action_space", "lr_schedule"):
            data[key] = pickled(marker)

    hostile = rewrite(SHIPPED, tmp_path / "m.zip", poison)
    ResidualController.load(hostile, gym.make(SERVO))
    assert not marker.exists()


def test_pickled_policy_kwargs_are_refused(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    hostile = rewrite(
        SHIPPED, tmp_path / "m.zip", lambda d: d.update(policy_kwargs=pickled(marker))
    )
    with pytest.raises(UnsafeModelError, match="policy_kwargs are a pickle"):
        ResidualController.load(hostile, gym.make(SERVO))
    assert not marker.exists()


def test_weights_that_are_not_tensors_are_refused(tmp_path: Path) -> None:
    marker = tmp_path / "ran"
    hostile = rewrite(
        SHIPPED, tmp_path / "m.zip", files={"policy.pth": pickle.dumps(Touch(marker))}
    )
    with pytest.raises(UnsafeModelError, match="not a plain state dict"):
        ResidualController.load(hostile, gym.make(SERVO))
    assert not marker.exists()


def test_a_model_of_other_spaces_is_refused(tmp_path: Path) -> None:
    def widen(data: dict) -> None:
        data["observation_space"]["_shape"] = "[7]"

    other = rewrite(SHIPPED, tmp_path / "m.zip", widen)
    with pytest.raises(ValueError, match=r"shape \(7,\)"):
        ResidualController.load(other, gym.make(SERVO))


class System:
    """A pickle that would call ``os.system`` when unpickled (never unpickled here)."""

    def __reduce__(self) -> tuple:
        import os

        return (os.system, ("true",))


def test_a_poisoned_sb3_entry_is_named_though_nothing_runs(tmp_path: Path) -> None:
    """``policy_class`` is an entry SB3 itself writes; one replaced by a call of
    ``os.system`` loaded with no word (SB3's own load would run it)."""
    payload = {
        ":type:": "<class 'abc.ABCMeta'>",
        ":serialized:": base64.b64encode(pickle.dumps(System())).decode(),
    }
    hostile = rewrite(SHIPPED, tmp_path / "m.zip", lambda d: d.update(policy_class=payload))
    with pytest.warns(UserWarning, match=r"name what runs commands or code \(policy_class: .*sy"):
        ResidualController.load(hostile, gym.make(SERVO))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"activation_fn": {"x": 1}}, "activation_fn=.* is not a setting frictiongym rebuilds"),
        ({"optimizer_class": "os.system"}, "optimizer_class='os.system' is not a setting"),
        ({"net_arch": [200_000, 200_000]}, "net_arch=.* is not a list of at most 16 layer"),
        ({"net_arch": {"pi": [64], "vf": "x"}}, "is not a list of at most 16 layer"),
        ({"log_std_init": "big"}, "log_std_init='big' is not a setting"),
    ],
)
def test_policy_kwargs_are_plain_settings_of_a_sensible_size(tmp_path, kwargs, match) -> None:
    """Non-JSON values raised TypeError, and a 200 000-wide net_arch allocated 160 GB."""
    hostile = rewrite(SHIPPED, tmp_path / "m.zip", lambda d: d.update(policy_kwargs=kwargs))
    with pytest.raises(ValueError, match=match):
        ResidualController.load(hostile, gym.make(SERVO))
