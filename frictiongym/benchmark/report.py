"""Benchmark outputs: ``results.json``, ``results.csv``, ``results.md`` and the paper check.

Files are written to a temporary name and renamed, so an interrupted run never leaves a
half-written file behind.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from frictiongym import devices
from frictiongym._io import csv_text, write_text_atomic
from frictiongym.benchmark.run import METRICS, Result
from frictiongym.tuning.specs import SPEC_FIELDS, StepSpecs

#: Table columns of the metrics: (field, header, format).
COLUMNS = (
    ("rise_time", "rise s", ".3f"),
    ("peak_time", "peak s", ".3f"),
    ("settling_time", "settle s", ".3f"),
    ("overshoot_pct", "OS %", ".2f"),
    ("steady_state_error", "SSE", ".4f"),
    ("steady_state_error_pct", "SSE %", ".2f"),
    ("iae", "IAE", ".4g"),
    ("itae", "ITAE", ".4g"),
    ("control_effort", "effort", ".4g"),
    ("limit_cycle_amplitude", "LC amp", ".3g"),
    ("limit_cycle_period", "LC period s", ".3g"),
    ("time_stuck", "stuck s", ".2f"),
)


def to_json(results: Sequence[Result]) -> str:
    """``results.json``: a list of records (:meth:`Result.record`)."""
    return json.dumps([r.record() for r in results], indent=1, allow_nan=False) + "\n"


def to_csv(results: Sequence[Result]) -> str:
    """``results.csv``: one flat row per run (empty cells: never reached / no cycle)."""
    head = ["scenario", "group", "env_id", "controller", "kp", "ki", "kd", "mode", "scale"]
    rows: list[list[object]] = [[*head, "friction", "sensor_noise", "seed", "terminated", *METRICS]]
    for r in results:
        rec, s = r.record(), r.scenario
        rows.append(
            [
                s.name,
                s.group,
                s.env_id,
                s.controller_name,
                s.gains.kp,
                s.gains.ki,
                s.gains.kd,
                s.mode or "",
                s.scale if s.mode else "",
                s.env_kwargs.get("friction", "paper"),
                s.env_kwargs.get("sensor_noise", False),
                r.seed,
                r.terminated,
                *("" if v is None else repr(v) for v in rec["metrics"].values()),
            ]
        )
    return csv_text(rows)


def format_metric(value: float, fmt: str) -> str:
    """``value`` for a table: ``never`` for inf (not reached), ``-`` for NaN (none)."""
    if math.isnan(value):
        return "-"
    if math.isinf(value):
        return "never"
    return format(value, fmt)


def _ended(result: Result) -> str:
    """How a terminated run ended: at the wall (the IR sensor's), or at the safety limit."""
    return (
        "hit the wall" if devices.get(result.scenario.device).end_stop == 0.0 else "hit the limit"
    )


def _table(results: Sequence[Result]) -> list[str]:
    head = ["scenario", "seed", *(h for _, h, _ in COLUMNS)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in results:
        m = r.metrics.as_dict()
        name = r.scenario.name + (f" ({_ended(r)})" if r.terminated else "")
        cells = [name, str(r.seed), *(format_metric(m[f], fmt) for f, _, fmt in COLUMNS)]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


@dataclass(frozen=True)
class Claim:
    """One of the paper's statements, what our model gives, and whether it agrees."""

    claim: str
    paper: str
    ours: str
    agrees: bool


def paper_claims(results: Sequence[Result]) -> list[Claim]:
    """Check the paper's statements against the runs (those present in ``results``)."""
    by_name = {r.scenario.name: r.metrics for r in results if r.seed == r.scenario.seeds[0]}
    claims: list[Claim] = []
    nominal = by_name.get("paper-rotary-nominal")
    if nominal is not None:
        got, specs = nominal.as_dict(), StepSpecs()  # the paper's specs of the servo (§3.1)
        limits = [(k, getattr(specs, k)) for k, _, _ in SPEC_FIELDS]
        checks = [
            (f"{k} {got[k]:.3g} {'<' if got[k] < v else '≥'} {v:g}", got[k] < v) for k, v in limits
        ]
        claims.append(
            Claim(
                "servo PID meets the four specs on the nominal model",
                "yes (random search)",
                "; ".join(text for text, _ in checks),
                all(ok for _, ok in checks),
            )
        )
    pid, comp = by_name.get("paper-rotary-pid"), by_name.get("paper-rotary-compensated")
    if pid is not None and comp is not None:
        claims.append(
            Claim(
                "servo SSE: PID with friction → compensated",
                "2.78 % → 1.11 % (hardware); 0 % (simulation)",
                f"{pid.steady_state_error_pct:.2f} % → {comp.steady_state_error_pct:.2f} %",
                comp.steady_state_error_pct < pid.steady_state_error_pct,
            )
        )
    ki10, ki20 = by_name.get("paper-altino-pid-ki10"), by_name.get("paper-altino-pid-ki20")
    if ki10 is not None:
        claims.append(
            Claim(
                "Altino Ki 10: overshoots and stays around 3 cm (offset ≈ 2 cm)",
                "offset ≈ 2 cm",
                f"overshoot {ki10.overshoot_pct:.2f} %, SSE {ki10.steady_state_error:.2f} cm",
                ki10.steady_state_error > 1.0,
            )
        )
    if ki20 is not None:
        cycle = ki20.limit_cycle_amplitude > 0.0
        claims.append(
            Claim(
                "Altino Ki 20: limit cycle around 5 cm",
                "sustained oscillation",
                f"amplitude {ki20.limit_cycle_amplitude:.2f} cm, period "
                f"{format_metric(ki20.limit_cycle_period, '.1f')} s; "
                f"SSE {ki20.steady_state_error:.2f} cm",
                cycle,
            )
        )
    m = by_name.get("paper-altino-compensated")
    if m is not None:
        claims.append(
            Claim(
                "Altino compensated (Kp 25, Ki 0.5, Kd 7): rise and settling < 1 s, no SSE, "
                "no oscillation",
                "yes",
                f"rise {format_metric(m.rise_time, '.2f')} s, "
                f"settling {format_metric(m.settling_time, '.2f')} s, "
                f"SSE {m.steady_state_error:.2f} cm, cycle amplitude {m.limit_cycle_amplitude:.2f}",
                m.rise_time < 1.0 and m.settling_time < 1.0 and m.limit_cycle_amplitude == 0.0,
            )
        )
    return claims


@dataclass(frozen=True)
class Comparison:
    """Residual vs compensated PID on one device and plant set (paired runs, same seeds)."""

    device: str
    plants: str
    runs: int
    itae: tuple[float, float]  # means: compensated, residual
    sse: tuple[float, float]
    sse_pct: tuple[float, float]
    itae_wins: int  # plants where the residual's ITAE is lower
    sse_wins: int
    terminated: tuple[int, int]  # runs ended by a safety limit: compensated, residual
    cycles: tuple[int, int]  # runs with a sustained limit cycle: compensated, residual


#: Paired runs of one device and plant set: ``(compensated, residual)`` on the same seed.
Pairs = list[tuple[Result, Result]]


def residual_pairs(results: Sequence[Result]) -> dict[tuple[str, str], Pairs]:
    """Pair the ``residual`` group's runs: ``(device, plants) -> [(compensated, residual)]``.

    ``plants`` is ``nominal`` or ``heldout``; the pairs share a seed (the same plant), in
    seed order. A device and plant set without both controllers is left out.
    """
    runs: dict[tuple[str, str], dict[str, dict[int, Result]]] = {}
    for r in results:
        if r.scenario.group != "residual":
            continue
        plants, kind = r.scenario.name.rsplit("-", 2)[1:]  # residual-<device>-<plants>-<kind>
        device = r.scenario.device
        runs.setdefault((device, plants), {}).setdefault(kind, {})[r.seed] = r
    out: dict[tuple[str, str], Pairs] = {}
    for key, kinds in runs.items():
        comp, res = kinds.get("compensated", {}), kinds.get("residual", {})
        seeds = sorted(set(comp) & set(res))
        if seeds:
            out[key] = [(comp[s], res[s]) for s in seeds]
    return out


def residual_comparisons(results: Sequence[Result]) -> list[Comparison]:
    """Compare the ``residual`` group's paired runs by device and plant set."""
    out = []
    for (device, plants), pairs in residual_pairs(results).items():

        def mean(field: str, i: int, pairs: Pairs = pairs) -> float:
            return sum(getattr(p[i].metrics, field) for p in pairs) / len(pairs)

        def both(field: str) -> tuple[float, float]:
            return mean(field, 0), mean(field, 1)

        out.append(
            Comparison(
                device,
                plants,
                len(pairs),
                both("itae"),
                both("steady_state_error"),
                both("steady_state_error_pct"),
                sum(r.metrics.itae < c.metrics.itae for c, r in pairs),
                sum(r.metrics.steady_state_error < c.metrics.steady_state_error for c, r in pairs),
                (sum(c.terminated for c, _ in pairs), sum(r.terminated for _, r in pairs)),
                (
                    sum(c.metrics.limit_cycle_amplitude > 0 for c, _ in pairs),
                    sum(r.metrics.limit_cycle_amplitude > 0 for _, r in pairs),
                ),
            )
        )
    return out


def residual_markdown(results: Sequence[Result]) -> list[str]:
    """Return the residual-vs-compensated-PID table of ``results.md`` ([] without residuals)."""
    comparisons = residual_comparisons(results)
    if not comparisons:
        return []
    lines = [
        "## Residual policy vs compensated PID",
        "",
        "Paired runs on the paper's step: the same plants (seeds) for both controllers. ITAE "
        "and SSE are means over the plants; `wins`: plants where the residual's is lower; "
        "`terminated`: runs ended by a safety limit (the servo's run-away guard, the Altino "
        "touching the wall) and `cycles`: runs with a sustained limit cycle, compensated / "
        "residual.",
        "",
        "| device | plants | runs | ITAE comp. | ITAE resid. | wins | SSE comp. | SSE resid. "
        "| SSE % comp. | SSE % resid. | wins | terminated | cycles |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in comparisons:
        lines.append(
            f"| {c.device} | {c.plants} | {c.runs} | {c.itae[0]:.4g} | {c.itae[1]:.4g} | "
            f"{c.itae_wins}/{c.runs} | {c.sse[0]:.4g} | {c.sse[1]:.4g} | {c.sse_pct[0]:.2f} | "
            f"{c.sse_pct[1]:.2f} | {c.sse_wins}/{c.runs} | {c.terminated[0]} / {c.terminated[1]} | "
            f"{c.cycles[0]} / {c.cycles[1]} |"
        )
    return [*lines, ""]


def to_markdown(results: Sequence[Result], command: str = "") -> str:
    """``results.md``: the paper check and one table per scenario group."""
    lines = ["# frictiongym benchmark", ""]
    if command:
        lines += [f"Produced by `{command}`.", ""]
    claims = paper_claims(results)
    if claims:
        lines += [
            "## The paper's claims on our model",
            "",
            "| claim | paper | ours | agrees |",
            "|---|---|---|---|",
        ]
        lines += [
            f"| {c.claim} | {c.paper} | {c.ours} | {'yes' if c.agrees else 'no'} |" for c in claims
        ]
        lines.append("")
    lines += residual_markdown(results)
    kinds = dict.fromkeys(r.scenario.device for r in results)
    position = " or ".join(dict.fromkeys(devices.get(k).position_unit for k in kinds)) or "units"
    named = [devices.get(k).command_unit for k in kinds]
    command = " or ".join(dict.fromkeys("motor units" if u == "units" else u for u in named))
    lines += [
        "Metrics of the true output against the reference: 10-90 % rise, 2 % settling, SSE "
        f"= mean |r - y| over the last 10 % of the run ({position}, and % of the step), IAE "
        f"and ITAE in output units x s (x s), effort = RMS command ({command}), LC = a "
        "sustained limit cycle in the second half of the run (half peak-to-peak), stuck = "
        "time held by friction after the first motion. `never`: not reached; `-`: none.",
        "",
    ]
    groups: dict[str, list[Result]] = {}
    for r in results:
        groups.setdefault(r.scenario.group, []).append(r)
    for group, members in groups.items():
        lines += [f"## {group}", "", *_table(members), ""]
    return "\n".join(lines)


def write_reports(
    results: Sequence[Result],
    out: Path,
    command: str = "",
    figures: Callable[[Sequence[Result], Path], list[Path]] | None = None,
) -> list[Path]:
    """Write ``results.json``, ``results.csv``, ``results.md`` (and figures) into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in (
        ("results.json", to_json(results)),
        ("results.csv", to_csv(results)),
        ("results.md", to_markdown(results, command)),
    ):
        write_text_atomic(out / name, text)
        written.append(out / name)
    if figures is not None:
        written += figures(results, out)
    return written
