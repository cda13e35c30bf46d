"""The tuner's loop built in python-control, to check the tuner and to time it against.

Needs python-control (``pip install frictiongym[test]``); it is imported inside the functions.

* :func:`sampled_data_loop` is the *same* loop the tuner simulates, without saturation and
  friction: the plant ``J x'' + B x' = u`` discretised with ``c2d(..., "zoh")`` (position and
  velocity outputs) and the PID exactly as :class:`~frictiongym.controllers.PID` computes it,
  ``I_k = I_(k-1) + e_k dt``, ``u_k = kp e_k + ki I_k - kd v_k``, with the derivative from the
  plant's velocity state.
* :func:`continuous_loop` is the continuous-time loop with the derivative on the measured
  velocity: ``(kp s + ki) / (J s^3 + (B + kd) s^2 + kp s + ki)``.
* :func:`continuous_error_derivative_loop` is the textbook parallel PID with the derivative on
  the error, ``C(s) = kp + ki/s + kd s`` in unity feedback: what MATLAB's ``pid(Kp, Ki, Kd)``
  and ``feedback(C*P, 1)`` give. Its zero ``kd s^2`` makes the step response faster.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from frictiongym.metrics.step import StepMetricsBatch
from frictiongym.plants.plant import PlantParams
from frictiongym.tuning.specs import StepSpecs


def _control() -> Any:
    try:
        import control
    except ImportError as error:  # pragma: no cover - the test extra installs it
        raise ImportError(
            "the python-control reference needs the 'control' package: pip install control "
            "(or frictiongym[test])"
        ) from error
    return control


def sampled_data_loop(gains: tuple[float, float, float], plant: PlantParams, dt: float) -> Any:
    """Return the tuner's closed loop (no saturation, no friction) as a discrete ``StateSpace``.

    State ``[position, velocity, I_(k-1)]``, input the reference, output the position.
    """
    control = _control()
    kp, ki, kd = (float(g) for g in gains)
    a = np.array([[0.0, 1.0], [0.0, -plant.damping / plant.inertia]])
    b = np.array([[0.0], [1.0 / plant.inertia]])
    discrete = control.c2d(control.ss(a, b, np.eye(2), np.zeros((2, 1))), dt, method="zoh")
    ad, bd = np.asarray(discrete.A), np.asarray(discrete.B)
    # u_k = (kp + ki dt)(r_k - x_k) + ki I_(k-1) - kd v_k ;  I_k = I_(k-1) + dt (r_k - x_k)
    k_state = np.array([[kp + ki * dt, kd]])
    a_cl = np.block([[ad - bd @ k_state, bd * ki], [np.array([[-dt, 0.0, 1.0]])]])
    b_cl = np.vstack([bd * (kp + ki * dt), [[dt]]])
    return control.ss(a_cl, b_cl, np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 1)), dt)


def continuous_loop(gains: tuple[float, float, float], plant: PlantParams) -> Any:
    """Return the continuous loop with the derivative on the velocity.

    ``(kp s + ki) / (J s³ + (B + kd) s² + kp s + ki)``.
    """
    kp, ki, kd = (float(g) for g in gains)
    return _control().tf([kp, ki], [plant.inertia, plant.damping + kd, kp, ki])


def continuous_error_derivative_loop(gains: tuple[float, float, float], plant: PlantParams) -> Any:
    """Return the continuous loop with the derivative on the error (MATLAB's ``pid``).

    ``(kd s² + kp s + ki) / (J s³ + (B + kd) s² + kp s + ki)``.
    """
    kp, ki, kd = (float(g) for g in gains)
    return _control().tf([kd, kp, ki], [plant.inertia, plant.damping + kd, kp, ki])


def step_info_metrics(systems: list[Any], t: npt.ArrayLike, specs: StepSpecs) -> StepMetricsBatch:
    """python-control's ``step_response`` + ``step_info`` of each system on the time grid ``t``.

    The final value is the DC gain (1 for these type-1 loops), the settling band and rise
    limits are those of ``specs``; a response that never reaches the upper rise limit (where
    ``step_info`` raises ``IndexError``) gets ``inf`` times and its final value's overshoot.
    Fields without a ``step_info`` counterpart (steady-state error) are NaN.
    """
    control = _control()
    times = np.asarray(t, dtype=np.float64)
    rows = []
    for system in systems:
        try:
            info = control.step_info(
                system,
                times,
                SettlingTimeThreshold=specs.settling_band,
                RiseTimeLimits=specs.rise_limits,
            )
            rows.append(
                (info["RiseTime"], info["PeakTime"], info["SettlingTime"], info["Overshoot"])
            )
        except IndexError:  # the upper rise limit is never reached
            rows.append((np.inf, np.inf, np.inf, 0.0))
    arr = np.array(rows, dtype=np.float64).reshape(-1, 4)
    settling = np.where(np.isnan(arr[:, 2]), np.inf, arr[:, 2])  # nan: never settles
    nan = np.full(arr.shape[0], np.nan)
    return StepMetricsBatch(
        rise_time=arr[:, 0],
        peak_time=arr[:, 1],
        settling_time=settling,
        overshoot_pct=arr[:, 3],
        steady_state_error=nan,
        steady_state_error_pct=nan.copy(),
    )
