"""The sim-to-real report: ``report.md``, ``sim2real.json`` and figures, from a result.

matplotlib is imported inside :func:`write_figures` with the non-interactive Agg backend.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from frictiongym._io import write_text_atomic
from frictiongym.hardware.runlog import write_json_atomic
from frictiongym.sim2real.run import SIGNALS, Sim2RealResult, differences

#: Step metrics compared, with their units (output units for errors).
METRICS = {
    "rise_time": "s",
    "settling_time": "s",
    "overshoot_pct": "%",
    "steady_state_error": "out",
}
UNITS = {
    "frictiongym/RotaryServo-v0": {"output": "rad", "velocity": "rad/s", "command": "V"},
    "frictiongym/AltinoDistance-v0": {"output": "cm", "velocity": "cm/s", "command": "units"},
}


def _num(value: float, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if math.isinf(value):
        return "never" if value > 0 else "-inf"
    return f"{value:.{digits}g}"


def summary(result: Sim2RealResult) -> dict[str, Any]:
    """Return the report's numbers as plain data (``sim2real.json``)."""
    gaps = {
        name: {s: {"rmse": result.gap(name, s), "fit_pct": result.fit(name, s)} for s in SIGNALS}
        for name in result.models
    }
    nominal = next(iter(result.models))
    closed = {
        name: {
            s: 1.0 - gaps[name][s]["rmse"] / gaps[nominal][s]["rmse"]
            if gaps[nominal][s]["rmse"] > 0
            else math.nan
            for s in SIGNALS
        }
        for name in result.models
        if name != nominal
    }
    timing = result.timing
    return {
        "env_id": result.env_id,
        "backend": result.backend,
        "controller": result.controller,
        "gains": result.gains,
        "repeats": len(result.device),
        "steps": int(min(trace.t.size for trace in result.device)) - 1,
        "models": result.model_descriptions,
        "gap": gaps,
        "gap_closed": closed,
        "device_spread": {s: result.spread(s) for s in SIGNALS},
        "device_metrics": [m.as_dict() for m in result.device_metrics()],
        "model_metrics": {n: t.metrics().as_dict() for n, t in result.models.items()},
        "metric_differences": differences(result, list(METRICS)),
        "timing": None if timing is None else timing.__dict__,
        "device_log": result.log_dir,
    }


def write_report(result: Sim2RealResult, out: Path, command: str, figures: bool = True) -> Path:
    """Write ``report.md``, ``sim2real.json`` and (optionally) the figures; return report.md."""
    out.mkdir(parents=True, exist_ok=True)
    data = summary(result)
    write_json_atomic(out / "sim2real.json", {"command": command, **data})
    if figures:
        write_figures(result, out)
    units = UNITS.get(result.env_id, {s: "" for s in SIGNALS})
    lines = [
        f"# Sim-to-real: {result.env_id}, {result.controller}",
        "",
        f"Reproduce: `{command}`",
        "",
        f"Device: `{result.backend}`, {data['repeats']} runs of {data['steps']} steps "
        f"(log: `{result.log_dir}`). Gains: Kp={result.gains['kp']:g}, Ki={result.gains['ki']:g}, "
        f"Kd={result.gains['kd']:g}.",
        "",
        "Models: " + "; ".join(f"**{n}**: {d}" for n, d in result.model_descriptions.items()),
        "",
        "## Gap to the device (RMSE against the mean of the device runs)",
        "",
        "| signal | "
        + " | ".join(f"{n} RMSE | {n} fit %" for n in result.models)
        + " | device spread |",
        "|---|" + "---:|---:|" * len(result.models) + "---:|",
    ]
    for s in SIGNALS:
        gaps = [data["gap"][n][s] for n in result.models]
        cells = [f"{_num(g['rmse'])} {units[s]} | {_num(g['fit_pct'], 3)}" for g in gaps]
        lines.append(f"| {s} | " + " | ".join(cells) + f" | {_num(data['device_spread'][s])} |")
    lines += ["", "The device spread is each device run's RMSE against the mean of the others:",
              "the noise floor no model can beat.", ""]  # fmt: skip
    for name, closed in data["gap_closed"].items():
        lines.append(
            f"**{name}** closes {_num(100 * closed['output'], 3)} % of the nominal model's output "
            f"gap and {_num(100 * closed['command'], 3)} % of its command gap"
            + (" (negative: farther than the nominal model)." if min(closed.values()) < 0 else ".")
        )
    lines += ["", "## Step metrics (model minus device mean)", "",
              "| metric | device mean | device std | "
              + " | ".join(f"{n} - device" for n in result.models) + " |",
              "|---|---:|---:|" + "---:|" * len(result.models)]  # fmt: skip
    for key, unit in METRICS.items():
        values = np.array([m[key] for m in data["device_metrics"]], dtype=float)
        if np.all(np.isfinite(values)):
            mean, std = float(values.mean()), float(values.std())
        else:  # a run that never settles: no spread to speak of
            mean, std = (math.inf if np.any(values == math.inf) else math.nan), math.nan
        unit = units["output"] if unit == "out" else unit
        diffs = [_num(data["metric_differences"][n][key]) for n in result.models]
        lines.append(f"| {key} ({unit}) | {_num(mean)} | {_num(std)} | " + " | ".join(diffs) + " |")
    timing = data["timing"]
    if timing is not None:
        lines += [
            "", "## Timing of the device loop", "",
            f"{timing['steps']} timed steps at {_num(timing['rate_hz'])} Hz achieved; period "
            f"error |T - dt| p50 {1e3 * timing['period_p50']:.3f} ms, p99 "
            f"{1e3 * timing['period_p99']:.3f} ms, max {1e3 * timing['period_max']:.3f} ms; "
            f"{timing['late']} late commands, {timing['skipped']} skipped ticks.",
        ]  # fmt: skip
        rate = 1.0 / float(result.device[0].t[1])
        if timing["rate_hz"] > 1.5 * rate:
            lines += ["", f"The loop ran faster than the device's {rate:g} Hz: its clock did not "
                      "pace it (a lock-step emulator), so these figures show the host's speed "
                      "only; see docs/benchmarks.md for a real-time run."]  # fmt: skip
    if figures:
        lines += ["", "## Figures", "", "![overlay](overlay.png)", "", "![timing](timing.png)"]
    path = out / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def write_figures(result: Sim2RealResult, out: Path) -> None:
    """``overlay.png`` (signals and errors over time) and ``timing.png`` (host periods)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    units = UNITS.get(result.env_id, {s: "" for s in SIGNALS})
    fig, axes = plt.subplots(4, 1, figsize=(8, 10), sharex=True)
    for k, s in enumerate(SIGNALS):
        ax = axes[k]
        for i, trace in enumerate(result.device):
            ax.plot(trace.t, trace.signal(s), color="0.55", lw=3.0, alpha=0.6,
                    label="device runs" if i == 0 else None)  # fmt: skip
        for name, trace in result.models.items():
            ax.plot(trace.t, trace.signal(s), lw=1.2, label=f"sim: {name}")
        ax.set_ylabel(f"{s} [{units[s]}]")
    axes[0].plot(result.device[0].t, result.device[0].reference, "k--", lw=0.8, label="reference")
    axes[0].legend(loc="best", fontsize="small")
    mean = result.device_mean("output")
    t = result.device[0].t[: mean.size]
    for name, trace in result.models.items():
        n = min(mean.size, trace.output.size)
        axes[3].plot(t[:n], trace.output[:n] - mean[:n], lw=1.0, label=f"{name} - device")
    axes[3].axhline(0.0, color="k", lw=0.6)
    axes[3].set(xlabel="time [s]", ylabel=f"output error [{units['output']}]")
    axes[3].legend(loc="best", fontsize="small")
    fig.suptitle(f"{result.env_id}: {result.controller} on the device and in simulation")
    fig.tight_layout()
    fig.savefig(out / "overlay.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7, 3.5))
    if result.periods.size:
        ax.hist(1e3 * result.periods, bins=60, color="C0")
    dt = result.device[0].t[1] if result.device[0].t.size > 1 else math.nan
    ax.axvline(1e3 * dt, color="k", ls="--", lw=0.8, label="device period")
    ax.set(xlabel="host period between steps [ms]", ylabel="steps", yscale="log")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "timing.png", dpi=110)
    plt.close(fig)


def load_summary(path: Path) -> dict[str, Any]:
    """Read a ``sim2real.json``."""
    data: dict[str, Any] = json.loads(path.read_text())
    return data
