"""Least-squares fits of friction laws to the measured steady-state map.

A point of the map is a level ``u`` held from rest and the steady speed ``v`` it reached:
``u = F(v) + b v`` with ``F`` the law's sliding friction and ``b`` all linear damping (the
plant's and the law's viscous part cannot be told apart in steady state). The break-away
levels ``u_s±`` come from the ramps and are held fixed (docs/identification.md): the low-speed
end of the map constrains ``u_s`` and ``v_0`` together. The curve is
evaluated by the law's own :meth:`~frictiongym.friction.FrictionModel.force`, the code the
simulated plant runs.

Standard errors come from the Jacobian at the optimum, ``(JᵀJ)⁻¹ s²`` with ``s²`` the residual
variance, and are conditional on the break-away levels.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from frictiongym.friction import CoulombViscous, FrictionModel, StictionCoulomb
from frictiongym.identification.estimates import IdentificationError, SteadyPoint

FloatArray = npt.NDArray[np.float64]

#: Laws fitted to the map: name -> decay shape of ``StictionCoulomb`` (None: Coulomb + viscous).
LAWS: dict[str, str | None] = {
    "paper": "linear",
    "stribeck": "exponential",
    "smooth": "smooth",
    "coulomb": None,
}


#: The file's friction keys, in its order.
_KEYS = ("us_pos", "us_neg", "uc_pos", "uc_neg", "v0_pos", "v0_neg", "viscous")


@dataclass(frozen=True)
class LawFit:
    """One law fitted to the map."""

    law: str  #: a key of :data:`LAWS`
    model: FrictionModel  #: the fitted law, its ``viscous`` the map's linear slope
    values: dict[str, float]  #: ``us_pos`` ... ``viscous`` (the file's keys)
    stderr: dict[str, float]  #: standard error of each value (nan: not estimated)
    rms: float  #: residual RMS, command units
    aic: float  #: Akaike information criterion (lower is better)
    points: int

    def predict(self, velocity: npt.ArrayLike) -> FloatArray:
        """Level that holds each (signed) steady speed: ``F(v) + b v``, signed."""
        return np.asarray(self.model.force(velocity), dtype=np.float64)


def _data(points: Sequence[SteadyPoint]) -> tuple[FloatArray, FloatArray]:
    moving = [p for p in points if p.moved and p.velocity > 0.0]
    velocity = np.array([p.sign * p.velocity for p in moving])
    level = np.array([p.sign * p.level for p in moving])
    return velocity, level


def _start(velocity: FloatArray, level: FloatArray, us: float) -> tuple[float, float, float]:
    """Return a start ``(uc, v0, b)`` of one direction (magnitudes) from its fastest half."""
    order = np.argsort(velocity)
    fast = order[len(order) // 2 :]
    b, uc = np.polyfit(velocity[fast], level[fast], 1)
    b = max(float(b), 1e-9)
    uc = float(min(max(uc, 0.0), us))
    excess = (level - uc - b * velocity) / max(us - uc, 1e-12)
    inside = (excess > 0.1) & (excess < 0.9)
    v0 = (
        float(np.median(velocity[inside] / (1.0 - excess[inside])))
        if np.any(inside)
        else float(velocity.max()) / 4.0
    )
    return uc, max(v0, 1e-6 * float(velocity.max())), b


def fit_law(
    points: Sequence[SteadyPoint],
    breakaway: Mapping[str, tuple[float, float]],
    law: str = "paper",
) -> LawFit:
    """Fit one law to the steady-state map.

    Parameters
    ----------
    points : sequence of SteadyPoint
        The map, both directions (points that did not move are ignored).
    breakaway : mapping
        ``{"us_pos": (value, stderr), "us_neg": (value, stderr)}`` from the ramps (not used by
        ``coulomb``, whose break-away is its Coulomb level).
    law : {"paper", "stribeck", "smooth", "coulomb"}

    Returns
    -------
    LawFit
    """
    if law not in LAWS:
        raise ValueError(f"unknown law {law!r}; fit one of {', '.join(LAWS)}")
    velocity, level = _data(points)
    pos, neg = velocity > 0, velocity < 0
    need = 2 if law == "coulomb" else 3
    if pos.sum() < need or neg.sum() < need:
        raise IdentificationError(
            f"the map has {int(pos.sum())} moving points forward and {int(neg.sum())} backward; "
            f"the {law} law needs at least {need} in each direction: hold more levels above "
            "break-away"
        )
    us_pos, us_neg = breakaway["us_pos"][0], breakaway["us_neg"][0]
    uc_p, v0_p, b_p = _start(velocity[pos], level[pos], us_pos)
    uc_n, v0_n, b_n = _start(-velocity[neg], -level[neg], us_neg)
    b0 = 0.5 * (b_p + b_n)
    shape = LAWS[law]

    if shape is None:
        names: tuple[str, ...] = ("uc_pos", "uc_neg", "viscous")
        x0 = np.array([uc_p, uc_n, b0])
        lower, upper = np.zeros(3), np.full(3, np.inf)

        def build(x: FloatArray) -> FrictionModel:
            return CoulombViscous(float(x[0]), float(x[1]), float(x[2]))

    else:
        names = ("uc_pos", "v0_pos", "uc_neg", "v0_neg", "viscous")
        x0 = np.array([min(uc_p, us_pos), v0_p, min(uc_n, us_neg), v0_n, b0])
        tiny = 1e-9 * float(np.abs(velocity).max())
        lower = np.array([0.0, tiny, 0.0, tiny, 0.0])
        upper = np.array([us_pos, np.inf, us_neg, np.inf, np.inf])

        def build(x: FloatArray) -> FrictionModel:
            return StictionCoulomb(
                us_pos,
                us_neg,
                float(x[0]),
                float(x[2]),
                float(x[1]),
                float(x[3]),
                float(x[4]),
                shape,  # type: ignore[arg-type]
            )

    x0 = np.clip(x0, lower, upper)  # least_squares moves it strictly inside

    def residual(x: FloatArray) -> FloatArray:
        return np.asarray(build(x).force(velocity), dtype=np.float64) - level

    result = least_squares(residual, x0, bounds=(lower, upper), x_scale="jac", method="trf")
    model = build(result.x)
    resid = result.fun
    n, k = resid.size, len(names)
    ssr = float(resid @ resid)
    dof = max(n - k, 1)
    try:
        cov = np.linalg.inv(result.jac.T @ result.jac) * (ssr / dof)
        se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        se = np.full(k, math.nan)
    values = {k: float(getattr(model, k, math.nan)) for k in _KEYS}
    values["us_pos"], values["us_neg"] = model.breakaway
    stderr = dict.fromkeys(values, math.nan)
    stderr.update(zip(names, (float(s) for s in se), strict=True))
    if shape is not None:
        stderr["us_pos"], stderr["us_neg"] = breakaway["us_pos"][1], breakaway["us_neg"][1]
    else:
        stderr["us_pos"], stderr["us_neg"] = stderr["uc_pos"], stderr["uc_neg"]
    aic = n * math.log(max(ssr, 1e-300) / n) + 2 * k
    return LawFit(
        law=law,
        model=model,
        values=values,
        stderr=stderr,
        rms=math.sqrt(ssr / n),
        aic=aic,
        points=n,
    )


def rest_slope(points: Sequence[SteadyPoint], sign: float, count: int = 3) -> float:
    """Slope ``du/dv`` of the map at its slowest ``count`` moving points in one direction.

    It is ``b'`` of the motion just after break-away (``J v' + b' v = u - u_s``); 0 when the
    direction has fewer than two moving points.
    """
    chosen = sorted(
        (p for p in points if p.moved and p.sign == sign and p.velocity > 0),
        key=lambda p: p.velocity,
    )[:count]
    if len(chosen) < 2:
        return 0.0
    v = np.array([p.velocity for p in chosen])
    u = np.array([p.level for p in chosen])
    return float(np.polyfit(v, u, 1)[0])


def inertia_from_map(
    points: Sequence[SteadyPoint], fit: LawFit, min_transient: float = 20.0
) -> tuple[float, float]:
    """``J`` from the approach of each constant run: ``tau`` times the map's local slope.

    In one sliding branch ``J v' = u - F(v) - b v`` linearises around the steady speed to a
    first-order lag with ``tau = J / (dF/dv + b)``. Only runs whose fitted transient stands
    ``min_transient`` times above the residual count. Returns the median and a standard error
    from the spread (``1.25 MAD / sqrt(n)``); ``(nan, nan)`` without usable runs.
    """
    estimates = []
    for p in points:
        if not (p.moved and p.transient >= min_transient and math.isfinite(p.tau)):
            continue
        v = p.sign * p.velocity
        h = 1e-4 * max(abs(v), 1e-9)
        slope = float((fit.predict(v + h) - fit.predict(v - h)) / (2 * h))  # du/dv
        if slope > 0.0:
            estimates.append(p.tau * slope)
    if not estimates:
        return math.nan, math.nan
    arr = np.asarray(estimates)
    median = float(np.median(arr))
    spread = 1.4826 * float(np.median(np.abs(arr - median)))
    return median, 1.25 * spread / math.sqrt(arr.size) if arr.size > 1 else math.nan
