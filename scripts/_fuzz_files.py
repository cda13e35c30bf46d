"""Untrusted files under fuzzing: hostile model zips through ``load_policy`` and mutated
``friction.json`` files through ``load_params``. Part of ``fuzz_hardware.py``.
"""

from __future__ import annotations

import base64
import json
import math
import pickle
import random
import sys
import tempfile
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from _fuzz_common import ROOT, Part, Progress, case_rng, progress

from frictiongym import params as fp

# --- model files --------------------------------------------------------------------------------

SHIPPED_MODEL = ROOT / "models" / "residual" / "rotary.zip"
#: Audit events that mean code ran or a pickle was read while a model loaded.
FORBIDDEN_EVENTS = (
    "pickle.find_class",
    "os.system",
    "subprocess.Popen",
    "os.exec",
    "os.posix_spawn",
    "os.spawn",
    "os.fork",
)


class Touch:
    """A pickle that creates a file when unpickled: the stand-in for any code."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return (Path.touch, (self.marker,))


def _pickled(marker: Path) -> dict[str, str]:
    payload = base64.b64encode(pickle.dumps(Touch(marker))).decode()
    return {":type:": "<class 'object'>", ":serialized:": payload}


class AuditWatch:
    """Records forbidden audit events while :attr:`watching` (a hook cannot be removed)."""

    def __init__(self) -> None:
        self.watching = False
        self.seen: list[str] = []
        sys.addaudithook(self._hook)

    def _hook(self, event: str, args: tuple[Any, ...]) -> None:
        if self.watching and event in FORBIDDEN_EVENTS:
            self.seen.append(f"{event}{args!r:.80}")


def _hostile_zip(rng: random.Random, marker: Path, target: Path) -> str:
    """Write a copy of the shipped model made hostile in one or more ways; say how."""
    ways = rng.sample(
        [
            "added entry",
            "SB3 entries",
            "policy_kwargs",
            "weights",
            "variables",
            "torch pickle",
            "bytes",
            "json",
        ],
        rng.randint(1, 3),
    )
    with zipfile.ZipFile(SHIPPED_MODEL) as source:
        members = {name: source.read(name) for name in source.namelist()}
    data = json.loads(members["data"])
    if "added entry" in ways:
        data[f"evil{rng.randrange(100)}"] = _pickled(marker)
    if "SB3 entries" in ways:
        for key in rng.sample(
            ["policy_class", "observation_space", "action_space", "lr_schedule", "clip_range"], 2
        ):
            data[key] = _pickled(marker)
    if "policy_kwargs" in ways:
        data["policy_kwargs"] = _pickled(marker)
    if "json" in ways:
        key = rng.choice(sorted(data))
        data[key] = rng.choice([None, 1e308, "x" * 1000, [[[]]], {"_shape": "[6]"}, -1])
    members["data"] = json.dumps(data).encode()
    if "weights" in ways:
        members["policy.pth"] = pickle.dumps(Touch(marker))
    if "variables" in ways:
        members["pytorch_variables.pth"] = pickle.dumps(Touch(marker))
    if "torch pickle" in ways:
        import torch

        buffer = target.with_suffix(".pth")
        torch.save({"weight": Touch(marker)}, buffer)
        members[rng.choice(["policy.pth", "pytorch_variables.pth"])] = buffer.read_bytes()
    with zipfile.ZipFile(target, "w") as out:
        for name, content in members.items():
            out.writestr(name, content)
    if "bytes" in ways:
        raw = bytearray(target.read_bytes())
        for _ in range(rng.randint(1, 8)):
            raw[rng.randrange(len(raw))] ^= 1 << rng.randrange(8)
        if rng.random() < 0.3:
            del raw[rng.randrange(len(raw)) :]
        target.write_bytes(bytes(raw))
    return "+".join(ways)


def fuzz_models(cases: range, seed: int, say: Progress) -> Part:
    """Hostile copies of the shipped model through ResidualController's loader."""
    from stable_baselines3 import PPO

    from frictiongym.controllers.policy_file import load_policy

    part = Part.named("model files")
    watch, outcomes = AuditWatch(), {"loaded": 0, "refused": 0}
    with tempfile.TemporaryDirectory(prefix="fuzz-models-") as folder:
        for case in cases:
            rng = case_rng(seed, "models", case)
            marker = Path(folder) / f"ran-{case}"
            target = Path(folder) / f"model-{case}.zip"
            ways = _hostile_zip(rng, marker, target)
            where = f"models case {case} ({ways})"
            watch.watching = True
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    load_policy(target, PPO, 6, 100.0)
                outcomes["loaded"] += 1
            except ValueError:
                outcomes["refused"] += 1
            except Exception as exc:
                part.fail(f"{where}: raised {type(exc).__name__}: {str(exc)[:120]}")
            finally:
                watch.watching = False
            if marker.exists():
                part.fail(f"{where}: the pickle ran")
            if watch.seen:
                part.fail(f"{where}: {watch.seen[0]}")
                watch.seen.clear()
            target.unlink()
            progress(say, part, cases, case, "files")
    part.cases = len(cases)
    part.notes.append(
        f"models: {outcomes['loaded']} loaded (pickles ignored), "
        f"{outcomes['refused']} refused with ValueError"
    )
    return part


# --- params files -------------------------------------------------------------------------------

PARAMS_FILES = [
    ROOT / "docs" / "identification" / d / "friction.json" for d in ("rotary", "altino")
]
ODD_VALUES: list[Callable[[random.Random], str]] = [
    lambda r: "NaN",
    lambda r: "Infinity",
    lambda r: "-Infinity",
    lambda r: "1e308",
    lambda r: "-1",
    lambda r: "0",
    lambda r: '"1.5"',
    lambda r: "null",
    lambda r: "true",
    lambda r: "[]",
    lambda r: "{}",
    lambda r: str(10**400),
    lambda r: "1e-320",
    lambda r: "[" * r.choice([10, 1000, 100_000]) + "]" * r.choice([0, 10]),
    lambda r: str(r.uniform(-1e7, 1e7)),
    lambda r: '"\\ud800"',
]


def _mutated_params(rng: random.Random, text: str) -> tuple[str, bytes]:
    how = rng.choice(
        [
            "value",
            "value",
            "key dropped",
            "bytes",
            "truncated",
            "not utf-8",
            "top level",
            "duplicate key",
        ]
    )
    data = json.loads(text)
    keys = [k for k in data if k not in ("units", "uncertainty", "metadata")]
    key = rng.choice(keys)
    if how == "value":
        new = json.dumps(data).replace(
            f'"{key}": {json.dumps(data[key])}', f'"{key}": {rng.choice(ODD_VALUES)(rng)}', 1
        )
        return f"{key} = odd value", new.encode()
    if how == "key dropped":
        del data[key]
        return f"{key} dropped", json.dumps(data).encode()
    if how == "duplicate key":
        return f"{key} twice", text.replace("{", f'{{"{key}": 1e9, ', 1).encode()
    if how == "top level":
        return how, rng.choice([b"[]", b"1", b'"x"', b"null", b""])
    raw = bytearray(text.encode())
    if how == "bytes":
        for _ in range(rng.randint(1, 6)):
            raw[rng.randrange(len(raw))] = rng.randrange(32, 127)
    elif how == "truncated":
        del raw[rng.randrange(len(raw)) :]
    else:
        raw[rng.randrange(len(raw))] = rng.choice([0x80, 0xC3, 0xFF])
    return how, bytes(raw)


def fuzz_params(cases: range, seed: int, say: Progress) -> Part:
    """Mutated friction.json files through load_params."""
    part = Part.named("params files")
    texts = [path.read_text() for path in PARAMS_FILES]
    loaded = 0
    with tempfile.TemporaryDirectory(prefix="fuzz-params-") as folder:
        target = Path(folder) / "friction.json"
        for case in cases:
            rng = case_rng(seed, "params", case)
            how, content = _mutated_params(rng, rng.choice(texts))
            target.write_bytes(content)
            loaded += _load_params(part, f"params case {case} ({how})", target)
            progress(say, part, cases, case, "files")
    part.cases = len(cases)
    part.notes.append(
        f"params: {loaded} of {len(cases)} mutated files loaded (all in range), the "
        "rest refused with ParamsFileError"
    )
    return part


def _load_params(part: Part, where: str, path: Path) -> bool:
    """Load ``path``; record any error but ParamsFileError; return whether it loaded."""
    try:
        params = fp.load_params(path)
    except fp.ParamsFileError:
        return False
    except Exception as exc:  # RecursionError and OverflowError among the findings
        part.fail(f"{where}: {type(exc).__name__}: {str(exc)[:100]}")
        return False
    _check_loaded(part, where, params)
    return True


def _check_loaded(part: Part, where: str, params: fp.DeviceParams) -> None:
    values = {"J": params.inertia, "B": params.damping}
    values.update({k: v for k, v in vars(params.friction).items() if isinstance(v, float)})
    for key, value in values.items():
        low, high = fp.PARAM_LIMITS.get(key, (-math.inf, math.inf))
        if not (math.isfinite(value) and (low <= value <= high or value == 0.0)):
            part.fail(f"{where}: loaded {key} = {value!r}, outside [{low:g}, {high:g}]")
