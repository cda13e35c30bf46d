"""The trials of a sweep: seeds x the values of each ``--grid KEY=V1,V2,...``.

A trial is one ``frictiongym train`` run: its :class:`TrainSettings` are the sweep's own with
one seed and one value of each grid key, and its output folder is ``OUT/trials/NAME``.
:func:`train_command` writes the ``frictiongym train`` command line that trains the same
policy outside the sweep.
"""

from __future__ import annotations

import dataclasses
import inspect
import itertools
import json
import re
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from frictiongym._validation import MAX_SEED
from frictiongym.controllers.residual import ALGORITHMS
from frictiongym.residual.train import TrainingError, TrainSettings, check_settings

#: Train options a grid may vary (``TrainSettings`` fields) and the JSON types they take.
TRAIN_KEYS: dict[str, tuple[type, ...]] = {
    "algo": (str,),
    "steps": (int,),
    "n_envs": (int,),
    "max_time": (int, float),
    "scale": (int, float),
    "reward": (str,),
    "residual_cost": (int, float),
    "randomize": (str,),
    "checkpoint_every": (int,),
    "validate_every": (int,),
    "validation_plants": (int,),
    "threads": (int,),
    "quick": (bool,),
}
#: Options of ``frictiongym train`` for the fields of :data:`TRAIN_KEYS`, in command order.
_OPTIONS = {key: "--" + key.replace("_", "-") for key in TRAIN_KEYS}
#: Longest part of a trial name taken from one value.
_NAME_PART = 32


class SweepError(Exception):
    """A user error in the sweep's options; the message says what to do."""


def parse_grid(text: str) -> tuple[str, list[Any]]:
    """Parse ``KEY=V1,V2,...`` (values in JSON) into the key and its values.

    The values are read as the JSON array ``[V1,V2,...]``, so a value may be a list or an
    object with commas of its own. Dashes in the key become underscores (``n-envs``).

    Raises
    ------
    ValueError
        For text that is not ``KEY=`` and JSON values, or no values.
    """
    key, sep, values = text.partition("=")
    key = key.strip().replace("-", "_")
    if not sep or not key.isidentifier():
        raise ValueError(f"expected KEY=V1,V2,..., got {text!r}")
    try:
        parsed = json.loads(f"[{values}]")
    except json.JSONDecodeError:
        raise ValueError(
            f"the values of {key} are not JSON separated by commas: {values!r} (strings need "
            f'quotes: {key}="a","b")'
        ) from None
    if not parsed:
        raise ValueError(f"--grid {key}= gives no value; give {key}=V1,V2,...")
    return key, parsed


def _type_name(types: tuple[type, ...]) -> str:
    return " or ".join(
        {"int": "a whole number", "float": "a number"}.get(t.__name__, t.__name__) for t in types
    )


def _sb3_arguments(algo: str) -> set[str]:
    """Return the constructor arguments of SB3's ``algo`` (SweepError without SB3)."""
    try:
        import stable_baselines3  # torch with it: only once a sweep is checked
    except ImportError as exc:
        raise SweepError(
            f'a sweep trains with Stable-Baselines3: pip install "frictiongym[rl]" ({exc})'
        ) from None
    algorithm = getattr(stable_baselines3, ALGORITHMS[algo])
    return set(inspect.signature(algorithm.__init__).parameters) - {"self"}


def check_grid(grid: list[tuple[str, list[Any]]], base: TrainSettings) -> None:
    """Raise :class:`SweepError` for a key given twice, unknown, or a value of the wrong type.

    A key is a train option of :data:`TRAIN_KEYS` or an argument of the SB3 algorithm of
    every trial (``--algo``, or each algorithm of the grid).
    """
    keys = [key for key, _ in grid]
    for key in keys:
        if keys.count(key) > 1:
            raise SweepError(f"--grid {key} is given twice; give all its values in one --grid")
        if key == "seed":
            raise SweepError("--grid seed: give the seeds with --seeds S1 S2 ...")
        if key in base.hyperparameters:
            raise SweepError(f"{key} is given with --sb3 and --grid; give it once")
    algos = dict(grid).get("algo", [base.algo])
    for key, values in grid:
        types = TRAIN_KEYS.get(key)
        if types is None:
            for algo in algos:
                if algo in ALGORITHMS and key not in _sb3_arguments(algo):
                    known = ", ".join(sorted(a for a in _sb3_arguments(algo) if a[0] != "_"))
                    raise SweepError(
                        f"unknown --grid key {key!r}: neither a train option ("
                        f"{', '.join(TRAIN_KEYS)}) nor an argument of SB3's "
                        f"{ALGORITHMS[algo]} ({known})"
                    )
            continue
        for value in values:
            wrong_bool = isinstance(value, bool) and bool not in types
            if wrong_bool or not isinstance(value, types):
                raise SweepError(
                    f"--grid {key}={json.dumps(value)}: {key} takes {_type_name(types)}"
                )


@dataclass(frozen=True)
class Trial:
    """One trial: its name (and folder under ``OUT/trials``), grid values and settings."""

    name: str
    seed: int
    values: dict[str, Any]  #: the grid's value of each key
    settings: TrainSettings
    heldout: dict[str, int]  #: the held-out evaluation: ``plants`` and ``first_seed``

    def config(self) -> dict[str, Any]:
        """Return the trial as JSON-ready data (what Tune hands the trial's worker)."""
        settings = dataclasses.asdict(self.settings)
        settings["out"] = str(self.settings.out)
        return {
            "name": self.name,
            "seed": self.seed,
            "values": self.values,
            "settings": settings,
            "heldout": self.heldout,
        }

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> Trial:
        """Return the trial of :meth:`config`'s data."""
        settings = dict(config["settings"])
        settings["out"] = Path(settings["out"])
        return cls(
            config["name"],
            config["seed"],
            dict(config["values"]),
            TrainSettings(**settings),
            dict(config["heldout"]),
        )


def _slug(value: Any) -> str:
    text = value if isinstance(value, str) else json.dumps(value, separators=(",", ":"))
    return re.sub(r"[^A-Za-z0-9.+-]+", "_", text).strip("_")[:_NAME_PART] or "_"


def trial_name(index: int, seed: int, values: dict[str, Any]) -> str:
    """Return a trial's name: its number, seed and grid values, e.g. ``003-seed1-n_envs=8``."""
    parts = [f"{index:03d}", f"seed{seed}", *(f"{k}={_slug(v)}" for k, v in values.items())]
    return "-".join(parts)


def expand(
    base: TrainSettings,
    seeds: list[int],
    grid: list[tuple[str, list[Any]]],
    out: Path,
    heldout: dict[str, int],
) -> list[Trial]:
    """Return the trials: every combination of the grid's values, each with every seed.

    Raises
    ------
    SweepError
        For bad seeds, or a trial whose settings ``frictiongym train`` would refuse.
    """
    if not seeds:
        raise SweepError("--seeds needs at least one seed")
    for seed in seeds:
        if not 0 <= seed <= MAX_SEED:
            raise SweepError(f"--seeds must be whole numbers from 0 to {MAX_SEED}, got {seed}")
    if len(set(seeds)) != len(seeds):
        raise SweepError(f"--seeds {' '.join(map(str, seeds))} names a seed twice")
    keys = [key for key, _ in grid]
    trials: list[Trial] = []
    for combination in itertools.product(*(values for _, values in grid)):
        values = dict(zip(keys, combination, strict=True))
        for seed in seeds:
            name = trial_name(len(trials), seed, values)
            train_values = {k: v for k, v in values.items() if k in TRAIN_KEYS}
            if "validate_every" in train_values:  # as train's --validate-every: 0 is never
                train_values["validate_every"] = train_values["validate_every"] or None
            sb3 = {k: v for k, v in values.items() if k not in TRAIN_KEYS}
            settings = dataclasses.replace(
                base,
                seed=seed,
                out=out / "trials" / name,
                hyperparameters={**base.hyperparameters, **sb3},
                **train_values,
            )
            settings.command_line = train_command(settings)
            try:
                check_settings(settings)
            except TrainingError as exc:
                raise SweepError(f"trial {name}: {exc}") from None
            trials.append(Trial(name, seed, values, settings, heldout))
    return trials


def train_command(settings: TrainSettings) -> str:
    """Return the ``frictiongym train`` command line that trains with ``settings``."""
    default = TrainSettings(env_id=settings.env_id)
    words = ["frictiongym", "train", "--env", settings.env_id, "--seed", str(settings.seed)]
    for key, option in _OPTIONS.items():
        value = getattr(settings, key)
        if value == getattr(default, key):
            continue
        if isinstance(value, bool):
            words.append(option)
        else:
            words += [option, "0" if value is None else str(value)]
    for key, value in settings.hyperparameters.items():
        words += ["--sb3", f"{key}={json.dumps(value)}"]
    words += ["--out", str(settings.out)]
    return shlex.join(words)
