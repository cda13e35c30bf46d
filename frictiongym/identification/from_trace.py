"""Identification from a recorded log of time, command and position (``--from-log``).

The log is a device run's ``steps.csv`` (frictiongym's run log: ``time``, ``applied``,
``measured``, one run per ``episode``) or any CSV of time, command and position with its
column names and units given. What the data allows is estimated:

1. **The map and the law from steady segments.** Every stretch of constant command long
   enough to reach a steady speed gives a map point (:func:`~frictiongym.identification.
   estimates.steady_velocity`), and the laws are fitted to them with the break-away levels
   extrapolated, as for a measured map (:mod:`~frictiongym.identification.from_log`).
2. **J and B from transients**, with the law and the dead time, by the output-error fit of
   every sample (:func:`~frictiongym.identification.refine.refine`), started from the map's
   law (or the device preset's when the log holds no steady segment).
3. **Break-away levels only where the log holds a start from rest** in that direction: a
   stretch at rest under a command that then moves the body. Without one they are named as
   not identified (the law's extrapolation is written, as for a map).
"""

from __future__ import annotations

import itertools
import math
import os
import time
from collections.abc import Sequence

import numpy as np

from frictiongym import devices
from frictiongym.controllers.rollout import Rollout
from frictiongym.friction import StictionCoulomb
from frictiongym.identification import estimates as est
from frictiongym.identification.fit import LawFit, fit_law, inertia_from_map
from frictiongym.identification.from_log import (
    LogFileError,
    breakaway_free,
    extrapolated_breakaway,
    read_columns,
    unit_scale,
    units_of,
)
from frictiongym.identification.identify import Identification
from frictiongym.identification.refine import Reading, refine, sensor_reading
from frictiongym.plants.sensors import IR_MAX_READOUT, IR_NUMERATOR, IR_OFFSET, SENSOR_IR

TIME_UNITS = {"s": 1.0, "ms": 1e-3}
#: Relative spread of the sampling interval a log may have: the fit holds each command for
#: one interval, so a log sampled unevenly is refused rather than fitted wrongly.
SAMPLING_TOLERANCE = 0.05
#: Shortest constant-command stretch that counts as a steady segment, s.
MIN_SEGMENT = 1.0
#: Samples and seconds at rest before a command that count its start as one from rest.
REST_SAMPLES = 5
REST_WINDOW = 0.05
#: Columns of frictiongym's own run log.
RUN_LOG = {"time": "time", "command": "applied", "position": "measured"}


def read_trace(
    path: str | os.PathLike[str],
    device: devices.Device,
    *,
    time_column: str = "time",
    command: str = "command",
    position: str = "position",
    time_unit: str = "s",
    position_unit: str | None = None,
    command_unit: str | None = None,
) -> tuple[list[Rollout], float]:
    """Read a log into runs (one per ``episode`` if it has that column) and its period.

    A frictiongym run log (its header holds ``applied`` and ``measured``) is read by its own
    column names whatever the options say.

    Raises
    ------
    LogFileError
        As :func:`~frictiongym.identification.from_log.read_columns`; also a unit the device
        does not know, time that does not increase (naming the line), and a sampling interval
        that varies by more than :data:`SAMPLING_TOLERANCE`.
    """
    where = str(path)
    if time_unit not in TIME_UNITS:
        raise LogFileError(f"{where}: time unit {time_unit!r} is not one of s, ms")
    position_scale = unit_scale(
        where, "position", units_of(device.position_unit), position_unit, device.name
    )
    command_scale = unit_scale(
        where, "command", units_of(device.command_unit), command_unit, device.name
    )
    names = {"time": time_column, "command": command, "position": position}
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as handle:
            header = handle.readline()
    except OSError as exc:
        raise LogFileError(f"{where}: cannot read it: {exc}") from None
    fields = [cell.strip() for cell in header.split(",")]
    if RUN_LOG["command"] in fields and RUN_LOG["position"] in fields:
        names = dict(RUN_LOG)
    wanted = list(names.values()) + (["episode"] if "episode" in fields else [])
    columns, lines = read_columns(path, wanted)
    t = columns[names["time"]] * TIME_UNITS[time_unit]
    u = columns[names["command"]] * command_scale
    y = columns[names["position"]] * position_scale
    valid = np.ones(t.size, dtype=bool)
    if device.sensor == SENSOR_IR:  # a saturated readout says only "out of range": masked
        if names["position"] == RUN_LOG["position"]:  # the run log holds the readout itself
            valid = (y > 0.0) & (y < IR_MAX_READOUT)
            y = IR_NUMERATOR / (y + IR_OFFSET)
        else:  # a distance: its two ends are the readout's 0 and 800
            nearest, farthest = (
                IR_NUMERATOR / (IR_MAX_READOUT + IR_OFFSET),
                IR_NUMERATOR / IR_OFFSET,
            )
            valid = (y > nearest * (1 + 1e-6)) & (y < farthest * (1 - 1e-6))
    episode = columns.get("episode", np.zeros(t.size))
    groups = []
    for value in dict.fromkeys(episode.tolist()):  # in file order
        rows = np.flatnonzero(episode == value)
        bad = np.flatnonzero(np.diff(t[rows]) <= 0.0)
        if bad.size:
            row = rows[bad[0] + 1]
            raise LogFileError(
                f"{where}: line {lines[row]}, column {names['time']!r}: time {t[row]:g} does "
                "not increase; sort the log by time (or split its runs with an 'episode' column)"
            )
        if rows.size > 1:  # a run of one sample holds no motion
            groups.append(rows)
    if not groups:
        raise LogFileError(f"{where}: a log needs a run of at least two samples")
    dt = float(np.median(np.concatenate([np.diff(t[rows]) for rows in groups])))
    for rows in groups:
        step = np.diff(t[rows])
        worst = int(np.argmax(np.abs(step - dt)))
        if abs(step[worst] - dt) > SAMPLING_TOLERANCE * dt:
            line = lines[rows[worst + 1]]
            raise LogFileError(
                f"{where}: line {line}: the sampling interval {step[worst]:g} s differs from "
                f"the log's {dt:g} s by more than {SAMPLING_TOLERANCE:.0%}; the fit holds each "
                "command for one interval: resample the log evenly"
            )
    rollouts = [
        Rollout.of_one_run(
            t[rows] - t[rows[0]],
            direction=device.direction,
            settings={"kind": "log"},
            measured=y[rows],
            command=u[rows],
            valid=valid[rows],
        )
        for rows in groups
    ]
    return rollouts, dt


def identify_trace(
    runs: Sequence[Rollout],
    device: str | devices.Device,
    dt: float,
    *,
    source: str = "",
    max_delay_steps: int = 3,
) -> Identification:
    """Identify what the log allows (the module's description).

    Parameters
    ----------
    runs : sequence of Rollout
        The log's runs (:func:`read_trace`), each from rest at its first sample.
    device : str or Device
        The device whose units the log is in.
    dt : float
        The log's sampling interval, s: each command is held for one.
    source : str
        The file, for the metadata.
    max_delay_steps : int, default 3
        Dead times of 0 to this many intervals are tried.

    Raises
    ------
    ValueError
        If there is no run. A log with too little excitation is fitted all the same: its
        standard errors say how poorly (docs/identification.md, "Limits").
    """
    started = time.perf_counter()
    described = devices.get(device)
    reading = sensor_reading(described)
    # The commands that started the body from rest, per direction: each exceeds break-away.
    starts = {s: _starts_from_rest(runs, s, reading) for s in (1.0, -1.0)}
    points = [p for run in runs for p in _steady_points(run)]
    enough = all(sum(p.moved and p.sign == s for p in points) >= 3 for s in (1.0, -1.0))
    not_identified: dict[str, str] = {}
    law = described.paper_friction
    if enough:
        breakaway = extrapolated_breakaway(points)
        law_fit = breakaway_free(points, fit_law(points, breakaway, "paper"))
        assert isinstance(law_fit.model, StictionCoulomb)  # the paper's law
        start_law = _below_starts(law_fit.model, starts)
        inertia_start = est_inertia = inertia_from_map(points, law_fit, min_transient=0.0)[0]
        damping_start = law_fit.values["viscous"]
    else:
        not_identified["map"] = (
            "fewer than three steady segments per direction (constant commands held at least "
            f"{MIN_SEGMENT:g} s): the output-error fit starts from the device preset"
        )
        start_law, est_inertia = law, math.nan
        inertia_start, damping_start = described.plant.inertia, described.plant.damping
    assert isinstance(start_law, StictionCoulomb)
    start = {
        "J": inertia_start if math.isfinite(inertia_start) else described.plant.inertia,
        "B": damping_start + (0.0 if enough else law.viscous),
        **{k: float(getattr(start_law, k)) for k in ("us_pos", "us_neg", "uc_pos", "uc_neg")},
        "v0_pos": float(start_law.v0_pos),
        "v0_neg": float(start_law.v0_neg),
    }
    result = refine(
        list(runs),
        start,
        dt,
        described.plant.command_limit,
        start_law.shape,
        reading=reading,  # the IR's residuals in its counts
        direction=described.direction,
        max_delay_steps=max_delay_steps,
        # From the map's law a few candidates suffice (16: 9 s on a 36 s servo log, 128: 133
        # s, the same result); from the preset, the full multi-start.
        candidates=16 if enough else 128,
        local_fits=1 if enough else 2,
        polish=2 if enough else 3,
    )
    v, se = result.values, result.stderr
    model = result.law(start_law.shape)
    keys = ("us_pos", "us_neg", "uc_pos", "uc_neg", "v0_pos", "v0_neg")
    stderr = {k: se[k] for k in keys} | {"viscous": se["B"]}
    for sign, key in ((1.0, "us_pos"), (-1.0, "us_neg")):
        if not starts[sign]:
            not_identified[key] = (
                f"the log holds no start from rest {'forward' if sign > 0 else 'backward'} "
                f"(a command after {REST_WINDOW:g} s at rest): the output-error fit's value is "
                "not a measured break-away"
            )
            stderr[key] = math.nan
    values = {k: float(getattr(model, k)) for k in (*keys, "viscous")}
    fit = LawFit("paper", model, values, stderr, math.nan, math.nan, len(points))
    return Identification(
        device=described.name,
        env_id=described.env_id,
        breakaways=[],
        points=points,
        steps=[],
        fits={"paper": fit},
        inertia=(v["J"], se["J"]),
        damping=(v["B"], se["B"]),
        breakaway={k: (values[k], stderr[k]) for k in ("us_pos", "us_neg")},
        traces=list(runs),
        refinement=result,
        env_steps=sum(run.t.size for run in runs),
        seconds=time.perf_counter() - started,
        plan=None,  # no experiments: the device needs no plan
        source={
            "kind": "log",
            "file": source,
            "points": sum(run.t.size for run in runs),
            "runs": len(runs),
            "steady_segments": len(points),
            "starts_from_rest": {"forward": len(starts[1.0]), "backward": len(starts[-1.0])},
            "map_inertia": est_inertia,
            "not_identified": not_identified,
        },
    )


def _segments(command: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges ``[a, b)`` over which the command stays exactly constant."""
    edges = np.flatnonzero(np.diff(command) != 0.0) + 1
    bounds = np.concatenate([[0], edges, [command.size]])
    return [(int(a), int(b)) for a, b in itertools.pairwise(bounds)]


def _steady_points(run: Rollout) -> list[est.SteadyPoint]:
    """Return a map point per constant, nonzero command held at least :data:`MIN_SEGMENT`."""
    command = run.signal("command")
    dt = float(run.t[1] - run.t[0]) if run.t.size > 1 else math.inf
    points = []
    valid = run.signal("valid")
    for a, b in _segments(command):
        if command[a] == 0.0 or valid[a:b].sum() * dt < MIN_SEGMENT:  # too short, or unseen
            continue
        piece = Rollout.of_one_run(
            run.t[a:b] - run.t[a],
            direction=run.direction,
            settings={"kind": "constant", "level": command[a], "sign": float(np.sign(command[a]))},
            measured=run.signal("measured")[a:b],
            command=command[a:b],
            valid=valid[a:b],
        )
        points.append(est.steady_velocity(piece))
    return points


def _starts_from_rest(
    runs: Sequence[Rollout], sign: float, reading: Reading | None = None
) -> list[float]:
    """Return the magnitudes of the commands of sign ``sign`` that start the body from rest.

    At rest: the last :data:`REST_WINDOW` s before the command spans at most six noise
    standard deviations, which a body sliding at 0.18 rad/s with the servo's one count of
    noise would exceed. Started: it then moves by over twenty of them in that direction. The
    test is made in the sensor's reading (``reading``: the IR's counts, whose noise is
    uniform), and the noise is estimated from the quieter half of the second differences: a
    relay's log accelerates nearly all the time, and the median would count that as noise.
    """
    commands: list[float] = []
    for run in runs:
        y = run.plant_output()
        z = run.signal("measured") if reading is None else reading.value(run.signal("measured"))
        command = run.signal("command")
        valid = run.signal("valid")
        dt = float(run.t[1] - run.t[0]) if run.t.size > 1 else math.inf
        window = max(REST_SAMPLES, round(REST_WINDOW / dt))
        sigma = _noise_sigma(z, valid)
        for a, b in _segments(command):
            if np.sign(command[a]) != sign or a < window or b - a < REST_SAMPLES:
                continue
            if not (valid[a - window : a + 1].all() and valid[b - 1]):  # seen out of range
                continue
            at_rest = float(np.ptp(z[a - window : a + 1])) <= 6.0 * sigma
            moved = abs(z[b - 1] - z[a]) > 20.0 * sigma + 1e-12
            if at_rest and moved and sign * (y[b - 1] - y[a]) > 0.0:
                commands.append(abs(float(command[a])))
    return commands


def _below_starts(law: StictionCoulomb, starts: dict[float, list[float]]) -> StictionCoulomb:
    """Return the map's law with break-away at most the least command that started a motion.

    Per direction: the map's extrapolation to rest overshoots when few of its points lie in
    the drop below ``v0``, and a command that started the body from rest exceeds the level.
    """
    levels = {}
    for sign, us, uc in ((1.0, law.us_pos, law.uc_pos), (-1.0, law.us_neg, law.uc_neg)):
        bound = min(starts[sign], default=math.inf)
        levels[sign] = max(min(us, bound), uc)
    capped = law.replace(us_pos=levels[1.0], us_neg=levels[-1.0])
    assert isinstance(capped, StictionCoulomb)  # replace keeps the class
    return capped


#: The 25th percentile of ``|N(0, 1)|``: a quantile of the second differences' magnitudes
#: below which motion seldom reaches.
_QUARTILE = 0.31863936396437514


def _noise_sigma(z: np.ndarray, valid: np.ndarray) -> float:
    """Noise std of a reading from the lower quartile of its second differences' magnitudes."""
    second = np.diff(z, 2)[valid[:-2] & valid[1:-1] & valid[2:]]
    if second.size == 0:
        return 0.0
    return float(np.quantile(np.abs(second), 0.25)) / (_QUARTILE * math.sqrt(6.0))
