"""Load the policy of a Stable-Baselines3 model zip without unpickling anything.

A model zip holds a JSON ``data`` file, some of whose entries (``":serialized:"``) are
base64 cloudpickles, and torch state dicts (``*.pth``). Stable-Baselines3's own ``load``
unpickles every such entry, so a zip from a stranger can run any code on load. Here the
policy is rebuilt from what frictiongym knows: the algorithm's policy class, the residual
observation and action spaces, and ``policy_kwargs`` only when they are plain JSON; its weights
come from ``policy.pth`` through ``torch.load(weights_only=True)``, which refuses anything but
tensors and containers. Pickled entries are never read, only listed.
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import pickletools
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

#: Entries that Stable-Baselines3 itself pickles into ``data``; any other pickled entry is
#: foreign and reported (it is ignored either way).
SB3_PICKLED = frozenset(
    {
        "policy_class",
        "observation_space",
        "action_space",
        "lr_schedule",
        "learning_rate",
        "clip_range",
        "clip_range_vf",
        "exploration_schedule",
        "action_noise",
        "train_freq",
        "_last_obs",
        "_last_episode_starts",
        "_last_original_obs",
        "ep_info_buffer",
        "ep_success_buffer",
        "rollout_buffer_class",
        "replay_buffer_class",
        "rollout_buffer_kwargs",
        "replay_buffer_kwargs",
        "target_policy_noise",
        "target_noise_clip",
        "policy_kwargs",
    }
)


class UnsafeModelError(ValueError):
    """A model file holds something frictiongym will not load without running code."""


#: Names that no pickle Stable-Baselines3 writes for our policies holds: modules and functions
#: that run commands or code, and the pieces of a pickled code object. Found in a pickled
#: entry's strings (read, not run), they are named in the warning.
SUSPECT_NAMES = frozenset(
    {
        "os",
        "posix",
        "nt",
        "subprocess",
        "sys",
        "builtins",
        "__builtin__",
        "importlib",
        "runpy",
        "shutil",
        "socket",
        "pty",
        "ctypes",
        "multiprocessing",
        "marshal",
        "pickle",
        "system",
        "popen",
        "exec",
        "eval",
        "compile",
        "__import__",
        "execfile",
        "spawn",
        "CodeType",
        "_make_function",
        "_builtin_type",
        "_make_skel_func",
    }
)
#: The ``policy_kwargs`` a policy is rebuilt with, and the JSON types each may have.
POLICY_KWARGS: dict[str, tuple[type, ...]] = {
    "net_arch": (list, dict),
    "log_std_init": (int, float),
    "ortho_init": (bool,),
    "use_sde": (bool,),
    "full_std": (bool,),
    "use_expln": (bool,),
    "squash_output": (bool,),
    "share_features_extractor": (bool,),
    "n_critics": (int,),
}
#: Largest layer and deepest network a model file may ask for (the shipped ones are 64 x 2):
#: a file from a stranger must not make the load allocate gigabytes.
MAX_LAYER, MAX_LAYERS = 4096, 16


def pickled_entries(data: dict[str, Any]) -> list[str]:
    """Names of the ``data`` entries stored as pickles (never unpickled here)."""
    return sorted(k for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v)


def suspect_names(data: dict[str, Any]) -> dict[str, list[str]]:
    """Return, per pickled entry, the :data:`SUSPECT_NAMES` among its strings (not unpickled).

    A hint, not a proof: Stable-Baselines3's own load would import and call what a pickle
    names; frictiongym never unpickles these entries either way.
    """
    found = {}
    for key in pickled_entries(data):
        try:
            raw = base64.b64decode(data[key][":serialized:"], validate=True)
            strings = {arg for _, arg, _ in pickletools.genops(raw) if isinstance(arg, str)}
        except (ValueError, TypeError, binascii.Error):  # not a pickle at all: not ours
            strings = {"(not a pickle)"}
        words = {word for text in strings for word in text.replace(".", " ").split()}
        names = sorted(words & SUSPECT_NAMES) or sorted(strings & {"(not a pickle)"})
        if names:
            found[key] = names
    return found


def _check_policy_kwargs(path: Path, kwargs: dict[str, Any]) -> None:
    """Refuse ``policy_kwargs`` that are not plain settings of a sensible size."""
    for key, value in kwargs.items():
        if key not in POLICY_KWARGS or not isinstance(value, POLICY_KWARGS[key]):
            raise ValueError(
                f"{path}: policy_kwargs {key}={value!r} is not a setting frictiongym rebuilds "
                f"a policy with (those are {', '.join(POLICY_KWARGS)}, as plain JSON)"
            )
    arch = kwargs.get("net_arch", [])
    layers = [arch] if isinstance(arch, list) else list(arch.values())
    for sizes in layers:
        if not (
            isinstance(sizes, list)
            and len(sizes) <= MAX_LAYERS
            and all(type(n) is int and 1 <= n <= MAX_LAYER for n in sizes)
        ):
            raise ValueError(
                f"{path}: policy_kwargs net_arch={arch!r} is not a list of at most "
                f"{MAX_LAYERS} layer sizes of 1 to {MAX_LAYER}"
            )


def read_data(path: Path) -> dict[str, Any]:
    """Return the JSON ``data`` file of a model zip (ValueError if it is none)."""
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (zipfile.BadZipFile, KeyError, json.JSONDecodeError, UnicodeDecodeError):
        raise ValueError(f"{path} is not a Stable-Baselines3 model zip") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path} is not a Stable-Baselines3 model zip")
    return data


def _shape(data: dict[str, Any], key: str) -> tuple[int, ...] | None:
    """Return the shape a space entry states in plain JSON (its ``_shape`` text), if any."""
    entry = data.get(key)
    try:
        return tuple(int(n) for n in json.loads(entry["_shape"]))  # type: ignore[index]
    except (TypeError, KeyError, ValueError):
        return None


def load_policy(
    path: str | os.PathLike[str],
    algorithm: Any,
    observation_size: int,
    observation_bound: float,
    device: str = "cpu",
) -> Any:
    """Rebuild the policy of an SB3 model zip from JSON and a weights-only state dict.

    Parameters
    ----------
    path : str or PathLike
        The model zip.
    algorithm : type
        The Stable-Baselines3 algorithm class (``PPO``, ``SAC``, ``TD3``).
    observation_size, observation_bound : int, float
        The residual observation space, ``Box(-bound, bound, (size,))``; the action space is
        ``Box(-1, 1, (1,))``.
    device : str, default "cpu"
        Torch device of the policy.

    Returns
    -------
    stable_baselines3.common.policies.BasePolicy
        The policy in evaluation mode (``predict(obs, deterministic=True)``).

    Raises
    ------
    UnsafeModelError
        If the policy cannot be built without unpickling (pickled ``policy_kwargs``) or its
        weights file holds more than tensors.
    ValueError
        If the zip is not a model of this kind (other spaces, no weights).
    """
    import torch
    from gymnasium import spaces
    from stable_baselines3.common.save_util import load_from_zip_file

    path = Path(path)
    data = read_data(path)
    foreign = [k for k in pickled_entries(data) if k not in SB3_PICKLED]
    if foreign:
        warnings.warn(
            f"{path} carries pickled entries that Stable-Baselines3 does not write "
            f"({', '.join(foreign)}): they may hold code. frictiongym ignored them (nothing in "
            "them ran), but do not open this file with stable_baselines3's own load",
            stacklevel=3,
        )
    suspects = {k: names for k, names in suspect_names(data).items() if k not in foreign}
    if suspects:
        listed = "; ".join(f"{k}: {', '.join(names)}" for k, names in suspects.items())
        warnings.warn(
            f"{path} carries pickles that name what runs commands or code ({listed}): "
            "frictiongym did not unpickle them (nothing ran), but stable_baselines3's own "
            "load would; do not open this file with it",
            stacklevel=3,
        )
    kwargs = data.get("policy_kwargs", {})
    if not isinstance(kwargs, dict) or ":serialized:" in kwargs:
        raise UnsafeModelError(
            f"{path}: its policy_kwargs are a pickle (Python objects such as classes), which "
            "frictiongym will not unpickle; retrain with plain JSON policy kwargs, or, if you "
            "trust the file, load it with stable_baselines3's own load"
        )
    _check_policy_kwargs(path, kwargs)
    for key, size in (("observation_space", observation_size), ("action_space", 1)):
        if _shape(data, key) not in (None, (size,)):
            raise ValueError(
                f"{path}: its {key} has shape {_shape(data, key)}, not ({size},): not a "
                "frictiongym residual policy"
            )
    try:
        _, params, _ = load_from_zip_file(path, load_data=False, device=device)
    except Exception as exc:  # torch's weights-only unpickler refuses anything but tensors
        raise UnsafeModelError(
            f"{path}: its weights are not a plain state dict ({type(exc).__name__}: {exc}); "
            "refusing to load it"
        ) from None
    if "policy" not in params:
        raise ValueError(f"{path} holds no policy weights (policy.pth)")
    if "use_sde" not in kwargs and algorithm.__name__ == "PPO":
        kwargs = {**kwargs, "use_sde": bool(data.get("use_sde", False))}
    policy_class = algorithm.policy_aliases["MlpPolicy"]
    observation_space = spaces.Box(
        -observation_bound, observation_bound, (observation_size,), dtype=np.float32
    )
    action_space = spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
    try:
        policy = policy_class(observation_space, action_space, lambda _: 0.0, **kwargs)
    except (TypeError, ValueError, RuntimeError) as exc:  # settings that contradict each other
        raise ValueError(f"{path}: its policy_kwargs {kwargs} build no policy ({exc})") from None
    try:
        policy.load_state_dict(params["policy"])
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f"{path}: its policy weights do not fit its settings ({exc})") from None
    policy.to(torch.device(device))
    policy.set_training_mode(False)
    return policy
