"""Identification from data a user already has: a measured friction map (``--from-log``).

A friction map is what the paper's Fig. 8(a) plots: pairs of a steady speed and the command
that holds it, measured by hand or by another tool. Read from a CSV file, it is fitted with
the same laws as :func:`~frictiongym.identification.identify.identify`'s own map, and says
plainly what a map cannot give:

* **the break-away levels**: a map holds no start from rest. The paper law's ``u_s`` is then
  the map's extrapolation to zero speed along its low-speed branch (the Stribeck drop), which
  is the law's own ``u_s`` only if the low-speed points lie on it; it carries no standard
  error and the metadata calls it extrapolated;
* **the inertia** ``J``: steady points hold no transient. The file gets ``--inertia`` if
  given, else the device preset's, named as such.

``B`` is the map's linear slope, as ``identify`` takes it when it has no velocity steps.
"""

from __future__ import annotations

import csv
import math
import os
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.optimize import least_squares, minimize

from frictiongym import devices
from frictiongym.friction import StictionCoulomb
from frictiongym.identification.estimates import SteadyPoint
from frictiongym.identification.fit import LAWS, LawFit, fit_law
from frictiongym.identification.identify import Identification

#: Units of one dimension, as factors to the first (SI) one: a log's unit converts to the
#: device's when both are in one row; a device unit in none converts only from itself.
UNIT_FAMILIES: tuple[dict[str, float], ...] = (
    {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "in": 0.0254},
    {"rad": 1.0, "deg": math.pi / 180.0, "rev": 2.0 * math.pi},
    {"V": 1.0, "mV": 1e-3},
    {"A": 1.0, "mA": 1e-3},
    {"N": 1.0, "kN": 1e3},
    {"N·m": 1.0, "mN·m": 1e-3},
)


def units_of(unit: str, per_second: bool = False) -> dict[str, float]:
    """Units that convert to the device's ``unit``, as factors to it, ``unit`` first.

    ``per_second``: the rates of those units (``unit/s``, and ``rpm`` for an angle).
    """
    family = next((f for f in UNIT_FAMILIES if unit in f), {unit: 1.0})
    own = family[unit]
    factors = {name: value / own for name, value in family.items()}
    factors = {unit: 1.0, **{k: v for k, v in factors.items() if k != unit}}
    if not per_second:
        return factors
    rates = {f"{name}/s": value for name, value in factors.items()}
    if "rev" in factors:
        rates["rpm"] = factors["rev"] / 60.0
    return rates


#: Moving points a law needs in each direction (the paper's law: its three parameters).
_MIN_POINTS = 3


class LogFileError(ValueError):
    """A recorded-data file that cannot be read or is not what its options say."""


def read_columns(
    path: str | os.PathLike[str], names: Sequence[str]
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Read the named columns of a CSV file with a header line, as floats.

    Returns the columns and each row's line in the file (blank lines are skipped), for
    messages.

    Raises
    ------
    LogFileError
        Naming the file and, for a bad cell, its line and column: an unreadable file, no
        header, a missing column (with the ones present), a row of another length, a cell that
        is not a finite number, no data rows.
    """
    where = str(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            rows = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError) as exc:
        raise LogFileError(f"{where}: cannot read it: {exc}") from None
    except csv.Error as exc:
        raise LogFileError(f"{where}: not a CSV file: {exc}") from None
    if not rows or not any(cell.strip() for cell in rows[0]):
        raise LogFileError(f"{where}: empty; the first line must name the columns")
    header = [cell.strip() for cell in rows[0]]
    missing = [name for name in names if name not in header]
    if missing:
        raise LogFileError(
            f"{where}: no column {', '.join(map(repr, missing))}; its columns are "
            f"{', '.join(map(repr, header))} (name yours with the column options)"
        )
    index = {name: header.index(name) for name in names}
    values: dict[str, list[float]] = {name: [] for name in names}
    lines: list[int] = []
    for line, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue  # a blank line
        lines.append(line)
        if len(row) != len(header):
            raise LogFileError(
                f"{where}: line {line} has {len(row)} fields, the header {len(header)}"
            )
        for name, i in index.items():
            cell = row[i].strip()
            try:
                value = float(cell)
            except ValueError:
                raise LogFileError(
                    f"{where}: line {line}, column {name!r}: {cell!r} is not a number"
                ) from None
            if not math.isfinite(value):
                raise LogFileError(
                    f"{where}: line {line}, column {name!r}: {cell!r} is not finite; drop the "
                    "row or measure it again"
                )
            values[name].append(value)
    if not values[names[0]]:
        raise LogFileError(f"{where}: the header names the columns but no row follows")
    columns = {name: np.asarray(v, dtype=np.float64) for name, v in values.items()}
    return columns, np.asarray(lines, dtype=np.int64)


def unit_scale(
    where: str, what: str, known: Mapping[str, float], given: str | None, device: str
) -> float:
    """Return the factor from unit ``given`` to the device's (its own when None).

    ``known`` maps the units the device's quantity converts from to their factors, its own
    unit first (:func:`units_of`).

    Raises
    ------
    LogFileError
        If ``given`` is not one of them, naming ``what``, the ``device`` and the units.
    """
    name = next(iter(known)) if given is None else given
    if name not in known:
        raise LogFileError(
            f"{where}: {what} unit {name!r} is not one of {device}'s: use {', '.join(known)}"
        )
    return known[name]


def read_map(
    path: str | os.PathLike[str],
    device: devices.Device,
    *,
    velocity: str = "velocity",
    force: str = "force",
    velocity_unit: str | None = None,
    force_unit: str | None = None,
) -> list[SteadyPoint]:
    """Read a friction map: one steady speed and the command holding it per row.

    Speeds and commands are signed (a negative command holds a negative speed); a speed of 0
    is a command that did not move the body, kept as such (the fits skip it). Units default
    to the device's; others are converted (:func:`units_of`).

    Raises
    ------
    LogFileError
        As :func:`read_columns`; also a unit the device does not know, a moving point whose
        command opposes its speed (naming its line), and too few moving points per direction.
    """
    where = str(path)
    scales = (
        unit_scale(
            where, "velocity", units_of(device.position_unit, True), velocity_unit, device.name
        ),
        unit_scale(where, "force", units_of(device.command_unit), force_unit, device.name),
    )
    columns, lines = read_columns(path, (velocity, force))
    v = columns[velocity] * scales[0]
    u = columns[force] * scales[1]
    opposed = np.flatnonzero((v != 0.0) & (np.sign(u) != np.sign(v)))
    if opposed.size:
        line = int(lines[opposed[0]])
        raise LogFileError(
            f"{where}: line {line}: the force {columns[force][opposed[0]]:g} opposes the "
            f"velocity {columns[velocity][opposed[0]]:g}; a map's force is the command that "
            "holds the speed, of the speed's sign (check the columns' signs)"
        )
    for sign, label in ((1.0, "positive"), (-1.0, "negative")):
        count = int(np.sum(np.sign(v) == sign))
        if count < _MIN_POINTS:
            raise LogFileError(
                f"{where}: {count} moving points of {label} speed; the laws need at least "
                f"{_MIN_POINTS} in each direction"
            )
    return [
        SteadyPoint(
            level=abs(float(ui)),
            velocity=abs(float(vi)),
            velocity_se=math.nan,
            tau=math.nan,
            moved=vi != 0.0,
            sign=float(np.sign(vi) or np.sign(ui) or 1.0),
        )
        for vi, ui in zip(v, u, strict=True)
    ]


def identify_map(
    points: Sequence[SteadyPoint],
    device: str | devices.Device,
    *,
    inertia: float | None = None,
    laws: Sequence[str] = tuple(LAWS),
    source: str = "",
) -> Identification:
    """Fit the laws to a measured map (the module's description says what it cannot give).

    Parameters
    ----------
    points : sequence of SteadyPoint
        The map (:func:`read_map`).
    device : str or Device
        The device whose units the map is in.
    inertia : float, optional
        ``J`` if known from elsewhere; the device preset's otherwise (not identified).
    laws : sequence of str
        Laws to fit (keys of :data:`~frictiongym.identification.fit.LAWS`).
    source : str
        The file, for the metadata.
    """
    started = time.perf_counter()
    described = devices.get(device)
    breakaway = extrapolated_breakaway(points)
    fits = {law: breakaway_free(points, fit_law(points, breakaway, law)) for law in laws}
    if "paper" in fits:  # the standard errors of the extrapolation, from the joint fit
        paper = fits["paper"]
        breakaway = {k: (paper.values[k], paper.stderr[k]) for k in ("us_pos", "us_neg")}
    reference = fits.get("paper") or next(iter(fits.values()))
    damping = (reference.values["viscous"], reference.stderr["viscous"])
    known = inertia is not None
    j = float(inertia) if known else described.plant.inertia  # type: ignore[arg-type]
    return Identification(
        device=described.name,
        env_id=described.env_id,
        breakaways=[],
        points=list(points),
        steps=[],
        fits=fits,
        inertia=(j, math.nan),
        damping=damping,
        breakaway=breakaway,
        traces=[],
        refinement=None,
        env_steps=0,
        seconds=time.perf_counter() - started,
        plan=None,  # no experiments: the device needs no plan
        source={
            "kind": "friction map",
            "file": source,
            "points": len(points),
            "not_identified": {
                "J": "a steady map holds no transient: "
                + ("given with --inertia" if known else "the device preset's value"),
                "us_pos, us_neg": "a map holds no start from rest: the law's extrapolation of "
                "the low-speed branch to zero speed, not a measured break-away",
            },
        },
    )


def extrapolated_breakaway(points: Sequence[SteadyPoint]) -> dict[str, tuple[float, float]]:
    """Return the levels ``u_s`` at which the paper law fits the map best (no standard error).

    The Coulomb levels are bounded by them, so the search starts at the largest level of the
    slowest points and minimises the paper law's residual over both.
    """
    start = []
    for sign in (1.0, -1.0):
        side = sorted((p for p in points if p.moved and p.sign == sign), key=lambda p: p.velocity)
        start.append(max(p.level for p in side[:_MIN_POINTS]))

    def rms(x: np.ndarray) -> float:
        levels = {"us_pos": (float(x[0]), math.nan), "us_neg": (float(x[1]), math.nan)}
        return fit_law(points, levels, "paper").rms

    result = minimize(rms, np.array(start), method="Nelder-Mead", bounds=[(0.0, None)] * 2)
    best = result.x if result.fun <= rms(np.array(start)) else np.array(start)
    return {"us_pos": (float(best[0]), math.nan), "us_neg": (float(best[1]), math.nan)}


def breakaway_free(points: Sequence[SteadyPoint], fit: LawFit) -> LawFit:
    """Refit a law with a Stribeck drop, ``u_s`` free, so its standard errors count it.

    With ``u_s`` held at the extrapolation, the other levels' standard errors leave out its
    uncertainty (a synthetic servo map put ``v0_pos`` 3.6 of them off); fitted together, the
    covariance holds it. A law without a drop (``coulomb``) is returned as it is.
    """
    law = fit.model
    if not isinstance(law, StictionCoulomb):
        return fit
    velocity = np.array([p.sign * p.velocity for p in points if p.moved])
    level = np.array([p.sign * p.level for p in points if p.moved])
    names = ("us_pos", "us_neg", "uc_pos", "uc_neg", "v0_pos", "v0_neg", "viscous")
    x0 = np.array([getattr(law, k) for k in names])
    lower = np.array([0.0, 0.0, 0.0, 0.0, 1e-9, 1e-9, 0.0])

    def build(x: np.ndarray) -> StictionCoulomb:
        # Coulomb at most break-away: the law's own rule, kept by construction.
        return StictionCoulomb(
            float(x[0]),
            float(x[1]),
            float(min(x[2], x[0])),
            float(min(x[3], x[1])),
            float(x[4]),
            float(x[5]),
            float(x[6]),
            law.shape,
        )

    result = least_squares(
        lambda x: np.asarray(build(x).force(velocity), dtype=np.float64) - level,
        np.maximum(x0, lower),
        bounds=(lower, np.inf),
        x_scale="jac",
    )
    model = build(result.x)
    resid = result.fun
    ssr = float(resid @ resid)
    n, k = resid.size, len(names)
    try:
        cov = np.linalg.inv(result.jac.T @ result.jac) * (ssr / max(n - k, 1))
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        se = np.full(k, math.nan)
    values = {key: float(getattr(model, key)) for key in names}
    return replace(
        fit,
        model=model,
        values=values,
        stderr=dict(zip(names, (float(e) for e in se), strict=True)),
        rms=math.sqrt(ssr / n),
        aic=n * math.log(max(ssr, 1e-300) / n) + 2 * k,
    )


def describe_source(source: Mapping[str, Any]) -> list[str]:
    """Lines of the summary that say what the data could not give."""
    lines = [f"From {source['kind']} {source['file']} ({source['points']} points)."]
    if source["kind"] == "log":
        starts = source["starts_from_rest"]
        lines.append(
            f"{source['runs']} run(s), {source['steady_segments']} steady segments, starts "
            f"from rest: {starts['forward']} forward, {starts['backward']} backward; J, B and "
            "the law fitted to every sample (output error)."
        )
    lines += [f"Not identified: {k}: {why}." for k, why in source["not_identified"].items()]
    return lines
