"""Compiled env step: plant, sensor, reference, reward and episode end for N envs at once.

The single env (N = 1) and the vector env run the same code, :func:`_step_block`, through
:func:`step_envs` (serial) or :func:`step_envs_parallel` (numba threads), so their trajectories
agree bit for bit. The plant part is the plant kernel's own
:func:`~frictiongym.plants._batch.step_plants`, the sensors those of
:mod:`frictiongym.plants.sensors`, the reference :func:`~frictiongym.envs.references.reference_at`.

Layouts (all float64 unless noted):

* plant rows (N or 1, ``plant_kernel.ROW_SIZE``): the plant kernel's rows, one shared by all
  envs unless they are randomised (a shared row keeps the working set of 4 096 envs in cache);
* task rows (N, ``TASK_ROW_SIZE``): the sensor gain and offset, then the packed reference of
  the episode;
* state (``ENV_STATE_SIZE``, N): the plant state, then the step count, the estimated
  position, the estimated velocity and the reference of the last observation;
* config (``CONFIG_SIZE``,): settings shared by all envs (``C_*``);
* outputs: ``obs`` (N, obs size) float32, ``out`` (``OUT_SIZE``, N) and ``flags``
  (``FLAG_SIZE``, N) bool, rows named by ``O_*`` and ``F_*``.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import njit, prange

from frictiongym.envs.references import REF_SIZE, reference_at
from frictiongym.plants import _batch as plant_batch
from frictiongym.plants import _kernel as plant_kernel
from frictiongym.plants.sensors import (
    SENSOR_ENCODER,
    derivative_update,
    ir_estimate,
    measure,
    normal_draw,
)
from frictiongym.plants.sensors import SENSOR_IR as SENSOR_IR  # the envs read it here

# Task row.
T_GAIN = 0
T_OFFSET = 1
T_REF = 2
TASK_ROW_SIZE = T_REF + REF_SIZE

# State columns after the plant's.
E_STEPS = plant_kernel.STATE_SIZE
E_ESTIMATE = E_STEPS + 1  #: estimated position: angle (rad) or distance (cm)
E_VELOCITY = E_STEPS + 2  #: filtered derivative of the estimate
E_REFERENCE = E_STEPS + 3
ENV_STATE_SIZE = E_STEPS + 4

# Config.
C_SENSOR = 0
C_QUANTIZE = 1  #: 1.0: encoder counts / integer IR readout; 0.0: ideal sensor
C_NOISE = 2  #: standard deviation of the additive sensor noise (rad or readout units)
C_ENCODER_STEP = 3  #: rad per encoder count
C_POLE = 4  #: velocity filter pole exp(-w dt); 0.0 is a backward difference
C_ERROR_SCALE = 5
C_EFFORT_WEIGHT = 6
C_PENALTY = 7
C_LIMIT = 8  #: servo: |angle| limit, rad; Altino: least distance to the wall, cm
C_MAX_STEPS = 9  #: truncate after this many steps (0: never; the single env's TimeLimit does it)
C_VELOCITY_FLOOR = 10  #: velocity estimates below it are 0.0 (sensors.velocity_floor)
C_ERROR_CAP = 11  #: the tracking term of a step is at most this (0: no cap; the v1 reward)
C_HORIZON = 12  #: episode length: a terminated episode pays as many worst steps (0: none)
CONFIG_SIZE = 13
#: The env's state columns after the plant's.
TASK_COLUMNS = ENV_STATE_SIZE - plant_kernel.STATE_SIZE


def _named(prefix: str) -> dict[str, int]:
    """Return this module's layout constants ``<prefix>NAME`` by lower-case name."""
    return {key[len(prefix) :].lower(): n for key, n in globals().items() if key.startswith(prefix)}


#: Config entries (``C_NOISE``: ``"noise"``) and the env's state columns (``E_STEPS``:
#: ``"steps"``) by name, for :func:`pack_config`, :func:`setting` and :func:`task_state`.
CONFIG, STATE_COLUMNS = _named("C_"), _named("E_")


def pack_config(**settings: float) -> npt.NDArray[np.float64]:
    """Return the config array of these settings (names of :data:`CONFIG`; the rest 0.0)."""
    config = np.zeros(CONFIG_SIZE)
    for name, value in settings.items():
        config[CONFIG[name]] = value
    return config


def setting(config: npt.NDArray[np.float64], name: str) -> float:
    """One setting of a config array, by its name in :data:`CONFIG`."""
    return float(config[CONFIG[name]])


def task_state(state: npt.NDArray[np.float64], name: str) -> npt.NDArray[np.float64]:
    """One of the env's own state columns (a view), by its name in :data:`STATE_COLUMNS`."""
    return state[STATE_COLUMNS[name]]


def set_episode(
    rows: npt.NDArray[np.float64], i: int, gain: float, reference: npt.NDArray[np.float64]
) -> None:
    """Write env ``i``'s drawn sensor gain and packed reference into its task row."""
    rows[i, T_GAIN] = gain
    rows[i, T_REF:] = reference


# Outputs.
O_REWARD = 0
O_POSITION = 1  #: true position: rad, or distance to the wall in cm
O_VELOCITY = 2  #: its true rate
O_COMMAND = 3  #: applied command (after saturation)
O_REFERENCE = 4
O_TIME = 5
OUT_SIZE = 6
F_TERMINATED = 0
F_TRUNCATED = 1
F_STUCK = 2
FLAG_SIZE = 3

#: Envs per block: the plant kernel's blocks.
BLOCK = plant_batch.BLOCK


@njit(cache=True, inline="always")
def _observe_env(
    i: int,
    state: npt.NDArray[np.float64],
    dt: float,
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    rng: npt.NDArray[np.uint64],
    config: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
    one_row: bool,
) -> None:
    """Read env ``i``'s sensor and write its observation, reward and episode end."""
    x, encoder = state[plant_kernel.S_X, i], config[C_SENSOR] == SENSOR_ENCODER
    noise = 0.0
    if config[C_NOISE] > 0.0:
        noise = config[C_NOISE] * normal_draw(rng, i)
    quantize, gain, offset = config[C_QUANTIZE] != 0.0, rows[i, T_GAIN], rows[i, T_OFFSET]
    measured = measure(x, encoder, gain, offset, noise, quantize, config[C_ENCODER_STEP])
    if encoder:
        position, velocity = x, state[plant_kernel.S_V, i]
    else:  # IR: the plant moves toward the wall, so the distance is -x
        position, velocity = 0.0 - x, 0.0 - state[plant_kernel.S_V, i]  # not -0.0 at the wall
    umax = plant_rows[0 if one_row else i, plant_kernel.I_UMAX]
    _observe(
        i,
        measured,
        position,
        velocity,
        state[plant_kernel.S_COMMAND, i],
        umax,
        dt,
        state,
        rows,
        config,
        fresh,
        obs,
        out,
        flags,
        False,
    )
    flags[F_STUCK, i] = state[plant_kernel.S_STUCK, i] != 0.0


#: The smallest normal float32: an observation below it would be subnormal (slow to compute
#: with on x86) or round to -0.0.
FLOAT32_TINY = float(np.finfo(np.float32).tiny)


@njit(cache=True, inline="always")
def _float32_normal(value: float) -> float:
    """Return ``value``, or +0.0 where float32 would hold it as subnormal or -0.0.

    An ideal sensor (``quantize=False``) passes on the true angle, or an IR readout that is
    not rounded, which can come as close to 0 as a start makes them (1e-40 rad: no sensor
    resolves it); the rounded counts never do.
    """
    return value if abs(value) >= FLOAT32_TINY else 0.0


@njit(cache=True, inline="always")
def _observe(
    i: int,
    measured: float,
    position: float,
    velocity: float,
    applied: float,
    umax: float,
    dt: float,
    state: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    config: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
    measured_only: bool,
) -> None:
    """Turn env ``i``'s sensor reading into its observation, reward and episode end.

    The simulator and a device share this: ``measured`` is the encoder angle (rad) or the IR
    readout. A device knows no true ``position`` and ``velocity``; with ``measured_only`` the
    estimates stand for them in the reward, the limit and the outputs.
    """
    t = state[E_STEPS, i] * dt
    if config[C_SENSOR] == SENSOR_ENCODER:
        estimate = measured
    else:
        estimate = ir_estimate(measured)
    if fresh[i]:
        estimated_velocity = 0.0
    else:
        estimated_velocity = derivative_update(
            state[E_VELOCITY, i],
            estimate,
            state[E_ESTIMATE, i],
            config[C_POLE],
            dt,
            config[C_VELOCITY_FLOOR],
        )
    if measured_only:
        position, velocity = estimate, estimated_velocity
    # Written so that a NaN position (a diverged plant) terminates instead of running on.
    if config[C_SENSOR] == SENSOR_ENCODER:
        terminated = not abs(position) <= config[C_LIMIT]
    else:
        terminated = not position > config[C_LIMIT]
    reference = reference_at(t, rows, i, T_REF)
    state[E_ESTIMATE, i] = estimate
    state[E_VELOCITY, i] = estimated_velocity
    state[E_REFERENCE, i] = reference

    if fresh[i]:
        reward, terminated, truncated = 0.0, False, False
    else:
        effort = applied / umax
        tracking = abs(reference - position) / config[C_ERROR_SCALE]
        if config[C_ERROR_CAP] > 0.0 and tracking > config[C_ERROR_CAP]:
            tracking = config[C_ERROR_CAP]
        reward = -(tracking + config[C_EFFORT_WEIGHT] * effort * effort)
        if terminated:
            # v1: and the worst whole episode, so that no ending by the limit scores better
            # than an episode without one (the env classes' "Rewards")
            reward -= config[C_PENALTY] + config[C_HORIZON] * (
                config[C_ERROR_CAP] + config[C_EFFORT_WEIGHT]
            )
        truncated = 0.0 < config[C_MAX_STEPS] <= state[E_STEPS, i]

    if config[C_SENSOR] == SENSOR_ENCODER:
        obs[i, 0], obs[i, 1] = _float32_normal(measured), estimated_velocity
        obs[i, 2] = _float32_normal(reference)
    else:
        obs[i, 0], obs[i, 1] = _float32_normal(measured), estimate
        obs[i, 2], obs[i, 3] = estimated_velocity, _float32_normal(reference)
    out[O_REWARD, i] = reward
    out[O_POSITION, i] = position
    out[O_VELOCITY, i] = velocity
    out[O_COMMAND, i] = applied
    out[O_REFERENCE, i] = reference
    out[O_TIME, i] = t
    flags[F_TERMINATED, i] = terminated
    flags[F_TRUNCATED, i] = truncated


@njit(cache=True)
def observe_device(
    state: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    config: npt.NDArray[np.float64],
    measured: float,
    applied: float,
    umax: float,
    dt: float,
    fresh: npt.NDArray[np.bool_],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> None:
    """Observe a device's sample as env 0 (a step, or the first sample if ``fresh[0]``).

    The same :func:`_observe` as the simulator's: identical readings give identical observations.
    """
    if not fresh[0]:
        state[E_STEPS, 0] += 1.0
    _observe(
        0,
        measured,
        measured,
        0.0,
        applied,
        umax,
        dt,
        state,
        rows,
        config,
        fresh,
        obs,
        out,
        flags,
        True,
    )
    flags[F_STUCK, 0] = False


@njit(cache=True)
def reset_envs(
    mask: npt.NDArray[np.bool_],
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    position: npt.NDArray[np.float64],
    velocity: npt.NDArray[np.float64],
    reference: npt.NDArray[np.float64],
    set_rows: bool,
) -> None:
    """Put the envs of ``mask`` at rest-or-moving starts (k-th masked env: ``position[k]``).

    With ``set_rows`` their task rows also get unit sensor gain and the ``reference`` row;
    otherwise the caller has set the rows. The sensor offset is always zeroed.
    """
    plant_kernel.reset_plants(mask, state, delay_buffer, position, velocity)
    for i in range(mask.shape[0]):
        if mask[i]:
            if set_rows:
                rows[i, T_GAIN] = 1.0
                rows[i, T_REF:] = reference
            rows[i, T_OFFSET] = 0.0


@njit(cache=True)
def observe_envs(
    mask: npt.NDArray[np.bool_],
    state: npt.NDArray[np.float64],
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    rng: npt.NDArray[np.uint64],
    config: npt.NDArray[np.float64],
    dt: float,
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> None:
    """Observe the just-reset envs of ``mask``; step none and leave the others' outputs.

    What a same-step autoreset needs: the ended envs are reset and observed after the step that
    ended them, without stepping the rest a second time.
    """
    one_row = plant_rows.shape[0] == 1
    for i in range(mask.shape[0]):
        if mask[i]:
            _observe_env(
                i, state, dt, plant_rows, rows, rng, config, mask, obs, out, flags, one_row
            )


@njit(cache=True, inline="always")
def _step_block(
    block: int,
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    dt: float,
    n_sub: int,
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    rng: npt.NDArray[np.uint64],
    config: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> None:
    """Step the envs of one block (those not ``fresh``), then observe them all.

    Two loops, not one: fused into one loop body the plant step and the observation compiled
    to code half as fast as the two apart (docs/benchmarks.md, "Kernel near the machine's
    limit"); a block's state stays in cache from the first loop to the second.
    """
    one_row = plant_rows.shape[0] == 1
    start, stop = block * BLOCK, min((block + 1) * BLOCK, state.shape[1])
    plant_batch.step_plants(
        start, stop, state, delay_buffer, head, command, dt, n_sub, plant_rows, fresh
    )
    for i in range(start, stop):
        if not fresh[i]:
            state[E_STEPS, i] += 1.0
    for i in range(start, stop):
        _observe_env(i, state, dt, plant_rows, rows, rng, config, fresh, obs, out, flags, one_row)


@plant_kernel.serial_njit
def step_envs(
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    dt: float,
    n_sub: int,
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    rng: npt.NDArray[np.uint64],
    config: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> int:
    """Step every env not ``fresh`` under ``command`` and observe all of them, in place.

    Returns -1, or the index of the first non-finite command (then nothing changed).
    """
    bad = plant_batch.first_non_finite(command)
    if bad >= 0:
        return bad
    for block in range((state.shape[1] + BLOCK - 1) // BLOCK):
        _step_block(
            block,
            state,
            delay_buffer,
            head,
            command,
            dt,
            n_sub,
            plant_rows,
            rows,
            rng,
            config,
            fresh,
            obs,
            out,
            flags,
        )
    return -1


@njit(cache=True, parallel=True)
def step_envs_parallel(
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    command: npt.NDArray[np.float64],
    dt: float,
    n_sub: int,
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    rng: npt.NDArray[np.uint64],
    config: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> int:
    """:func:`step_envs` with the blocks spread over numba's threads (bit-identical results)."""
    bad = plant_batch.first_non_finite(command)
    if bad >= 0:
        return bad
    for block in prange((state.shape[1] + BLOCK - 1) // BLOCK):
        _step_block(
            np.int64(block),  # prange's index is unsigned; the body indexes with signed integers
            state,
            delay_buffer,
            head,
            command,
            dt,
            n_sub,
            plant_rows,
            rows,
            rng,
            config,
            fresh,
            obs,
            out,
            flags,
        )
    return -1
