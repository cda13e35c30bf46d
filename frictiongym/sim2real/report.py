"""The sim-to-real report: ``report.md``, ``sim2real.json`` and figures, from a result.

matplotlib is imported inside :func:`write_figures` with the non-interactive Agg backend.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from frictiongym import devices
from frictiongym._io import json_value, pyplot, save_figure, write_json_atomic, write_text_atomic
from frictiongym.sim2real.run import (
    COMPLETE,
    DEVICE_LIMIT,
    DISCONNECTED,
    FAULT_TEXT,
    LINK,
    SAFETY_LIMIT,
    SIGNALS,
    WATCHDOG,
    Sim2RealResult,
    signal,
)

#: Step metrics compared, with their units (output units for errors).
METRICS = {
    "rise_time": "s",
    "settling_time": "s",
    "overshoot_pct": "%",
    "steady_state_error": "out",
}


def _units(env_id: str) -> dict[str, str]:
    """Units of the compared signals (:data:`SIGNALS`) on the device of ``env_id``."""
    device = devices.get(env_id)
    position, command = device.position_unit, device.command_unit
    return {"output": position, "velocity": f"{position}/s", "command": command}


def _num(value: float, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if math.isinf(value):
        return "never" if value > 0 else "-inf"
    return f"{value:.{digits}g}"


def summary(result: Sim2RealResult) -> dict[str, Any]:
    """Return the report's numbers as plain data (``sim2real.json``).

    The gap, spread and metric figures come from the complete device runs only; with none
    they are ``null``. ``runs`` says how each device run ended; ``model_stops`` the step at
    which the safety limit ended a simulated model's run (``null``: it ran its full length).
    """
    runs = result.runs
    timing = result.timing
    data: dict[str, Any] = {
        "env_id": result.env_id,
        "backend": result.backend,
        "controller": result.controller,
        "gains": result.gains,
        "repeats": len(runs),
        "complete_runs": len(result.device),
        "runs": [
            {"run": r.run, "steps": r.steps, "ended": r.ended, "detail": r.detail} for r in runs
        ],
        "steps": int(min(t.t.size for t in result.device)) - 1 if result.device else None,
        "models": result.model_descriptions,
        "model_stops": {
            n: t.t.size - 1 if t.terminated else None for n, t in result.models.items()
        },
        "gap": None,
        "gap_closed": None,
        "device_spread": None,
        "device_metrics": [t.metrics(output="measured").as_dict() for t in result.device],
        "model_metrics": {
            n: t.metrics(output="measured").as_dict() for n, t in result.models.items()
        },
        "metric_differences": None,
        "timing": None if timing is None else timing.__dict__,
        "priority": result.priority or None,
        "device_log": result.log_dir,
    }
    if not result.device:
        return data
    gaps = {
        name: {s: {"rmse": result.gap(name, s), "fit_pct": result.fit(name, s)} for s in SIGNALS}
        for name in result.models
    }
    nominal = next(iter(result.models))
    data["gap"] = gaps
    data["gap_closed"] = {
        name: {
            s: 1.0 - gaps[name][s]["rmse"] / gaps[nominal][s]["rmse"]
            if gaps[nominal][s]["rmse"] > 0
            else math.nan
            for s in SIGNALS
        }
        for name in result.models
        if name != nominal
    }
    data["device_spread"] = {s: result.spread(s) for s in SIGNALS}
    data["metric_differences"] = {  # model minus the device runs' mean
        name: {
            k: model[k] - float(np.mean([d[k] for d in data["device_metrics"]])) for k in METRICS
        }
        for name, model in data["model_metrics"].items()
    }
    return data


def runs_text(n: int) -> str:
    """Return "1 run" or "n runs"."""
    return f"{n} run" if n == 1 else f"{n} runs"


def stops(result: Sim2RealResult) -> str:
    """Return how many device runs ended early and by what, e.g. "2 by the device's watchdog"."""
    counts = Counter(run.ended for run in result.stopped)
    names = {SAFETY_LIMIT: "the safety limit", DEVICE_LIMIT: "the device limit", **FAULT_TEXT}
    return ", ".join(f"{n} by {names[ended]}" for ended, n in counts.items()) or "none"


def _run_lines(result: Sim2RealResult, data: dict[str, Any]) -> list[str]:
    """Return the device runs' table and what the stopped ones mean for the figures."""
    lines = ["## Device runs", "", "| run | steps | ended |", "|---:|---:|---|"]
    for run in data["runs"]:
        detail = run["detail"].replace("|", "\\|")  # |angle| must not split the cell
        how = run["ended"] if run["ended"] == COMPLETE else f"**{run['ended']}**: {detail}"
        lines.append(f"| {run['run']} | {run['steps']} | {how} |")
    stopped = result.stopped
    if stopped:
        names = ", ".join(str(run.run) for run in stopped)
        are = "is" if len(stopped) == 1 else "are"
        lines += [
            "",
            f"{len(stopped)} of {runs_text(data['repeats'])} ({names}) ended early "
            f"and {are} left out of the comparison"
            + (
                f": the figures below use the {runs_text(data['complete_runs'])} that completed."
                if result.device
                else "."
            ),
        ]
        if any(run.ended == WATCHDOG for run in stopped):
            lines += [
                "",
                "A watchdog trip means the host loop sent no command for the "
                "device's watchdog time (a stalled host, or lost frames): the device "
                "zeroed its motor, and the next run re-armed it (docs/hardware.md, "
                '"Timing and the watchdog").',
            ]
        if any(run.ended == LINK for run in stopped):
            lines += [
                "",
                "A link fault means no state frame came in time, or one came too old "
                "(a stalled host or emulator, a slow or lossy link): the motor was zeroed "
                "and the next run started afresh.",
            ]
        if any(run.ended == DISCONNECTED for run in stopped):
            lines += [
                "",
                "The device went away (cable, power, emulator stopped): the runs "
                "after it were not tried.",
            ]
        if any(run.ended in (SAFETY_LIMIT, DEVICE_LIMIT) for run in stopped):
            lines += [
                "",
                "A run ended by a limit went where the limit forbids: a reference "
                "near it, or a controller that overshoots.",
            ]
    return lines


def write_report(result: Sim2RealResult, out: Path, command: str, figures: bool = True) -> Path:
    """Write ``report.md``, ``sim2real.json`` and (optionally) the figures; return report.md.

    With no complete device run there is no gap to report: the report says how each run ended,
    and ``overlay.png`` is not drawn.
    """
    out.mkdir(parents=True, exist_ok=True)
    data = summary(result)
    write_json_atomic(out / "sim2real.json", {"command": command, **data}, default=json_value)
    if figures:
        write_figures(result, out)
    units = _units(result.env_id)
    steps = data["steps"] if data["steps"] is not None else max(r["steps"] for r in data["runs"])
    lines = [
        f"# Sim-to-real: {result.env_id}, {result.controller}",
        "",
        f"Reproduce: `{command}`",
        "",
        f"Device: `{result.backend}`, {runs_text(data['repeats'])} of {steps} steps, "
        f"{data['complete_runs']} complete (log: `{result.log_dir}`). Gains: "
        f"Kp={result.gains['kp']:g}, Ki={result.gains['ki']:g}, Kd={result.gains['kd']:g}.",
        "",
        "Models: " + "; ".join(f"**{n}**: {d}" for n, d in result.model_descriptions.items()),
        "",
        *_run_lines(result, data),
        "",
    ]
    if result.device:
        lines += _gap_lines(result, data, units)
    else:
        lines += ["No device run completed, so there is no gap to report."]
    timing = data["timing"]
    if timing is not None and timing["steps"]:
        lines += [
            "",
            "## Timing of the device loop",
            "",
            f"{timing['steps']} timed steps at {_num(timing['rate_hz'])} Hz achieved; period "
            f"error |T - dt| p50 {1e3 * timing['period_p50']:.3f} ms, p99 "
            f"{1e3 * timing['period_p99']:.3f} ms, max {1e3 * timing['period_max']:.3f} ms; "
            f"{timing['late']} late commands, {timing['skipped']} skipped ticks. Host loop "
            f"scheduling: {result.priority or 'not recorded'}.",
        ]
        rate = 1.0 / _period(result)
        if timing["rate_hz"] > 1.5 * rate:
            lines += [
                "",
                f"The loop ran faster than the device's {rate:g} Hz: its clock did not "
                "pace it (a lock-step emulator), so these figures show the host's speed "
                "only; see docs/benchmarks.md for a real-time run.",
            ]
    if figures:
        lines += ["", "## Figures", ""]
        lines += ["![overlay](overlay.png)", ""] if result.device else []
        lines += ["![timing](timing.png)"]
    path = out / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def _period(result: Sim2RealResult) -> float:
    """Return the control period, s (from a simulated model's trace: every run has it)."""
    trace = next(iter(result.models.values()))
    return float(trace.t[1]) if trace.t.size > 1 else math.nan


def _gap_lines(result: Sim2RealResult, data: dict[str, Any], units: dict[str, str]) -> list[str]:
    """Return the gap table, what each model closes and the step metrics (complete runs)."""
    lines = [
        "## Gap to the device (RMSE against the mean of the complete device runs)",
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
    lines += [
        "",
        "The device spread is each device run's RMSE against the mean of the others:",
        "the noise floor no model can beat.",
        "",
    ]
    for name, stop in data["model_stops"].items():
        if stop is not None:
            lines.append(
                f"The safety limit ended the **{name}** model's run after {stop} steps: "
                "its figures cover those steps only."
            )
    if any(stop is not None for stop in data["model_stops"].values()):
        lines.append("")
    for name, closed in data["gap_closed"].items():
        lines.append(
            f"**{name}** closes {_num(100 * closed['output'], 3)} % of the nominal model's output "
            f"gap and {_num(100 * closed['command'], 3)} % of its command gap"
            + (" (negative: farther than the nominal model)." if min(closed.values()) < 0 else ".")
        )
    lines += [
        "",
        "## Step metrics (model minus the complete device runs' mean)",
        "",
        "| metric | device mean | device std | "
        + " | ".join(f"{n} - device" for n in result.models)
        + " |",
        "|---|---:|---:|" + "---:|" * len(result.models),
    ]
    for key, unit in METRICS.items():
        values = np.array([m[key] for m in data["device_metrics"]], dtype=float)
        if np.all(np.isfinite(values)):
            mean, std = float(values.mean()), float(values.std())
        else:  # a run that never settles: no spread to speak of
            mean, std = (math.inf if np.any(values == math.inf) else math.nan), math.nan
        unit = units["output"] if unit == "out" else unit
        diffs = [_num(data["metric_differences"][n][key]) for n in result.models]
        lines.append(f"| {key} ({unit}) | {_num(mean)} | {_num(std)} | " + " | ".join(diffs) + " |")
    return lines


def write_figures(result: Sim2RealResult, out: Path) -> None:
    """Draw ``overlay.png`` (signals and errors over time) and ``timing.png`` (host periods).

    ``overlay.png`` needs a complete device run, and is not drawn without one.
    """
    plt = pyplot()
    if result.device:
        _write_overlay(result, out, plt)
    fig, ax = plt.subplots(figsize=(7, 3.5))
    if result.periods.size:
        ax.hist(1e3 * result.periods, bins=60, color="C0")
    ax.axvline(1e3 * _period(result), color="k", ls="--", lw=0.8, label="device period")
    ax.set(xlabel="host period between steps [ms]", ylabel="steps", yscale="log")
    ax.legend()
    fig.tight_layout()
    save_figure(fig, out / "timing.png", dpi=110)


def _write_overlay(result: Sim2RealResult, out: Path, plt: Any) -> None:
    units = _units(result.env_id)
    fig, axes = plt.subplots(4, 1, figsize=(8, 10), sharex=True)
    for k, s in enumerate(SIGNALS):
        ax = axes[k]
        for i, trace in enumerate(result.device):
            ax.plot(
                trace.t,
                signal(trace, s),
                color="0.55",
                lw=3.0,
                alpha=0.6,
                label="device runs" if i == 0 else None,
            )
        for name, trace in result.models.items():
            ax.plot(trace.t, signal(trace, s), lw=1.2, label=f"sim: {name}")
        ax.set_ylabel(f"{s} [{units[s]}]")
    axes[0].plot(
        result.device[0].t, result.device[0].signal("reference"), "k--", lw=0.8, label="reference"
    )
    axes[0].legend(loc="best", fontsize="small")
    mean = result.device_mean("output")
    t = result.device[0].t[: mean.size]
    for name, trace in result.models.items():
        output = signal(trace, "output")
        n = min(mean.size, output.size)
        axes[3].plot(t[:n], output[:n] - mean[:n], lw=1.0, label=f"{name} - device")
    axes[3].axhline(0.0, color="k", lw=0.6)
    axes[3].set(xlabel="time [s]", ylabel=f"output error [{units['output']}]")
    axes[3].legend(loc="best", fontsize="small")
    fig.suptitle(f"{result.env_id}: {result.controller} on the device and in simulation")
    fig.tight_layout()
    save_figure(fig, out / "overlay.png", dpi=110)
