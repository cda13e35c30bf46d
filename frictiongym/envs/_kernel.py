"""Compiled env step: plant, sensor, reference, reward and episode end for N envs at once.

The single env (N = 1) and the vector env run the same code, :func:`_step_block`, through
:func:`step_envs` (serial) or :func:`step_envs_parallel` (numba threads), so their trajectories
agree bit for bit. The plant part is the plant kernel's own
:func:`~frictiongym.plants._batch.step_plants`, the sensors those of
:mod:`frictiongym.plants.sensors`, the reference :func:`~frictiongym.envs.references.reference_at`.

Layouts (all float64 unless noted):

* plant rows (N or 1, ``plant_kernel.ROW_SIZE``): the plant kernel's rows, one shared by all
  envs unless they are randomised (a shared row keeps the working set of 4 096 envs in cache);
* task rows (``TASK_ROW_SIZE``, N): the sensor gain and offset, then the packed reference of
  the episode, each entry a row of the envs (a loop over envs reads each contiguously);
* state (``ENV_STATE_SIZE``, N): the plant state, then the step count, and of the last
  observation the estimated position, the estimated velocity, the reference, the reading, the
  episode-end flags and the reward;
* config (``CONFIG_SIZE``,): settings shared by all envs (``C_*``);
* outputs: ``obs`` (N, obs size) float32, ``out`` (``OUT_SIZE``, N) and ``flags``
  (``FLAG_SIZE``, N) bool, rows named by ``O_*`` and ``F_*``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from numba import njit, prange, types
from numba.extending import overload

from frictiongym.envs.references import REF_SIZE, reference_at
from frictiongym.plants import _batch as plant_batch
from frictiongym.plants import _kernel as plant_kernel
from frictiongym.plants._kernel import I_UMAX
from frictiongym.plants.sensors import (
    SENSOR_ENCODER,
    box_muller,
    derivative_update,
    ir_estimate,
    last_normal_draw,
    measure,
    normal_draw,
    uniform_draw,
)
from frictiongym.plants.sensors import SENSOR_IR as SENSOR_IR  # the envs read it here

# Task rows.
T_GAIN = 0
T_OFFSET = 1
#: the command limit of the env's plant row, copied at reset: a loop over envs reads it
#: contiguously (an indirect read of the plant rows kept the observation loop out of SIMD code)
T_UMAX = 2
T_REF = 3
TASK_ROW_SIZE = T_REF + REF_SIZE

# State columns after the plant's.
E_STEPS = plant_kernel.STATE_SIZE
E_ESTIMATE = E_STEPS + 1  #: estimated position: angle (rad) or distance (cm)
E_VELOCITY = E_STEPS + 2  #: filtered derivative of the estimate
E_REFERENCE = E_STEPS + 3
E_MEASURED = E_STEPS + 4  #: the sensor reading: encoder angle (rad) or IR readout
E_TERMINATED = E_STEPS + 5  #: 1.0 if the last observation ended the episode at a limit
E_TRUNCATED = E_STEPS + 6  #: 1.0 if it truncated the episode
E_REWARD = E_STEPS + 7  #: its reward
ENV_STATE_SIZE = E_STEPS + 8

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
    """Write env ``i``'s drawn sensor gain and packed reference into its task column."""
    rows[T_GAIN, i] = gain
    rows[T_REF:, i] = reference


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
F_DONE = 3  #: terminated or truncated
FLAG_SIZE = 4

#: Envs per block: the plant kernel's blocks.
BLOCK = plant_batch.BLOCK


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
def _settings(config: npt.NDArray[np.float64]) -> tuple[float, ...]:
    """Return the config as a tuple (read once per call, not per env)."""
    return (
        config[0],
        config[1],
        config[2],
        config[3],
        config[4],
        config[5],
        config[6],
        config[7],
        config[8],
        config[9],
        config[10],
        config[11],
        config[12],
    )


if CONFIG_SIZE != 13:  # _settings unpacks the config by hand
    raise ImportError("frictiongym.envs._kernel._settings must unpack every config entry")


@njit(cache=True, inline="always")
def _reading(
    x: float, v: float, gain: float, offset: float, noise: float, cfg: tuple[float, ...]
) -> tuple[float, float, float]:
    """Return the sensor reading of a plant at ``x`` moving at ``v``, its position and rate."""
    encoder = cfg[C_SENSOR] == SENSOR_ENCODER
    measured = measure(x, encoder, gain, offset, noise, cfg[C_QUANTIZE] != 0.0, cfg[C_ENCODER_STEP])
    return measured, _toward(x, encoder), _toward(v, encoder)


@njit(cache=True, inline="always")
def _toward(value: float, encoder: bool) -> float:
    """Return the plant's position or rate as the env reports it (the IR's: distance, rate)."""
    # IR: the plant moves toward the wall, so the distance is -x (written 0.0 - x: not -0.0)
    return value if encoder else 0.0 - value


@njit(cache=True, inline="always")
def _scored(
    measured: float,
    position: float,
    velocity: float,
    applied: float,
    umax: float,
    steps: float,
    previous_velocity: float,
    previous_estimate: float,
    fresh: bool,
    reference: float,
    dt: float,
    cfg: tuple[float, ...],
    measured_only: bool,
) -> tuple[float, float, float, float, float, bool, bool]:
    """Turn a sensor reading into the estimates, the reward and the episode end.

    The simulator and a device share this: ``measured`` is the encoder angle (rad) or the IR
    readout. A device knows no true ``position`` and ``velocity``; with ``measured_only`` the
    estimates stand for them in the reward, the limit and the outputs. Conditional expressions
    only, so that a loop over envs compiles to SIMD code.

    Returns
    -------
    estimate, estimated_velocity, position, velocity, reward : float
    terminated, truncated : bool
    """
    encoder = cfg[C_SENSOR] == SENSOR_ENCODER
    estimate = measured if encoder else ir_estimate(measured)
    rate = derivative_update(
        previous_velocity, estimate, previous_estimate, cfg[C_POLE], dt, cfg[C_VELOCITY_FLOOR]
    )
    estimated_velocity = 0.0 if fresh else rate
    position = estimate if measured_only else position
    velocity = estimated_velocity if measured_only else velocity
    # Written so that a NaN position (a diverged plant) terminates instead of running on.
    beyond = not abs(position) <= cfg[C_LIMIT] if encoder else not position > cfg[C_LIMIT]
    effort = applied / umax
    tracking = abs(reference - position) / cfg[C_ERROR_SCALE]
    capped = cfg[C_ERROR_CAP] > 0.0 and tracking > cfg[C_ERROR_CAP]
    tracking = cfg[C_ERROR_CAP] if capped else tracking
    reward = -(tracking + cfg[C_EFFORT_WEIGHT] * effort * effort)
    # v1: and the worst whole episode, so that no ending by the limit scores better than an
    # episode without one (the env classes' "Rewards")
    ending = cfg[C_PENALTY] + cfg[C_HORIZON] * (cfg[C_ERROR_CAP] + cfg[C_EFFORT_WEIGHT])
    reward = reward - ending if beyond else reward
    truncated = 0.0 < cfg[C_MAX_STEPS] <= steps
    return (
        estimate,
        estimated_velocity,
        position,
        velocity,
        0.0 if fresh else reward,
        False if fresh else beyond,
        False if fresh else truncated,
    )


@njit(cache=True, inline="always")
def _write(
    i: int,
    measured: float,
    scored: tuple[float, float, float, float, float, bool, bool],
    applied: float,
    reference: float,
    t: float,
    encoder: bool,
    state: npt.NDArray[np.float64],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> None:
    """Store env ``i``'s estimates, observation and outputs."""
    _store(i, measured, scored, applied, reference, t, state, out)
    _publish(i, encoder, state, obs)
    for flag, row in _FLAG_ROWS:
        _flag(i, flag, row, state, flags)
    _done(i, flags)


@njit(cache=True, inline="always")
def _store(
    i: int,
    measured: float,
    scored: tuple[float, float, float, float, float, bool, bool],
    applied: float,
    reference: float,
    t: float,
    state: npt.NDArray[np.float64],
    out: npt.NDArray[np.float64],
) -> None:
    """Store env ``i``'s estimates, flags and outputs in the state and ``out``."""
    _keep(i, measured, scored, state)
    state[E_REFERENCE, i] = reference
    out[O_REWARD, i] = scored[4]
    out[O_POSITION, i] = scored[2]
    out[O_VELOCITY, i] = scored[3]
    out[O_COMMAND, i] = applied
    out[O_REFERENCE, i] = reference
    out[O_TIME, i] = t


@njit(cache=True, inline="always")
def _keep(
    i: int,
    measured: float,
    scored: tuple[float, float, float, float, float, bool, bool],
    state: npt.NDArray[np.float64],
) -> None:
    """Store env ``i``'s estimates, reading, reward and flags in its state."""
    estimate, estimated_velocity, _, _, reward, terminated, truncated = scored
    state[E_ESTIMATE, i] = estimate
    state[E_VELOCITY, i] = estimated_velocity
    state[E_MEASURED, i] = measured
    state[E_TERMINATED, i] = 1.0 if terminated else 0.0
    state[E_TRUNCATED, i] = 1.0 if truncated else 0.0
    state[E_REWARD, i] = reward


@njit(cache=True, inline="always")
def _publish(
    i: int,
    encoder: bool,
    state: npt.NDArray[np.float64],
    obs: npt.NDArray[np.float32],
) -> None:
    """Write env ``i``'s observation from what :func:`_store` stored."""
    obs[i, 0] = _float32_normal(state[E_MEASURED, i])
    if encoder:
        obs[i, 1] = state[E_VELOCITY, i]
        obs[i, 2] = _float32_normal(state[E_REFERENCE, i])
    else:
        obs[i, 1] = state[E_ESTIMATE, i]
        obs[i, 2] = state[E_VELOCITY, i]
        obs[i, 3] = _float32_normal(state[E_REFERENCE, i])


#: The flags and the state rows they are read from, in :func:`_flag` and its loops.
_FLAG_ROWS = (
    (F_TERMINATED, E_TERMINATED),
    (F_TRUNCATED, E_TRUNCATED),
    (F_STUCK, plant_kernel.S_STUCK),
)


@njit(cache=True, inline="always")
def _flag(
    i: int, flag: int, row: int, state: npt.NDArray[np.float64], flags: npt.NDArray[np.bool_]
) -> None:
    """Set flag ``flag`` of env ``i`` from state row ``row`` (1.0: set)."""
    flags[flag, i] = state[row, i] != 0.0


@njit(cache=True, inline="always")
def _done(i: int, flags: npt.NDArray[np.bool_]) -> None:
    """Set env ``i``'s done flag from its other flags: terminated or truncated."""
    flags[F_DONE, i] = flags[F_TERMINATED, i] | flags[F_TRUNCATED, i]


@njit(cache=True, inline="always")
def _observe_env(
    i: int,
    state: npt.NDArray[np.float64],
    dt: float,
    rows: npt.NDArray[np.float64],
    noise: float,
    config: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> None:
    """Read env ``i``'s sensor plus ``noise``; write its observation, reward, episode end."""
    cfg = _settings(config)
    x, v = state[plant_kernel.S_X, i], state[plant_kernel.S_V, i]
    measured, position, velocity = _reading(x, v, rows[T_GAIN, i], rows[T_OFFSET, i], noise, cfg)
    applied, umax = state[plant_kernel.S_COMMAND, i], rows[T_UMAX, i]
    steps = state[E_STEPS, i]
    t = steps * dt
    reference = reference_at(t, rows, i, T_REF)
    previous_velocity, previous_estimate = state[E_VELOCITY, i], state[E_ESTIMATE, i]
    scored = _scored(
        measured,
        position,
        velocity,
        applied,
        umax,
        steps,
        previous_velocity,
        previous_estimate,
        fresh[i],
        reference,
        dt,
        cfg,
        False,
    )
    encoder = cfg[C_SENSOR] == SENSOR_ENCODER
    _write(i, measured, scored, applied, reference, t, encoder, state, obs, out, flags)


@njit(cache=True, inline="always")
def _score_lanes(
    lo: int,
    hi: int,
    state: npt.NDArray[np.float64],
    dt: float,
    rows: npt.NDArray[np.float64],
    config: npt.NDArray[np.float64],
    noise: Any,
) -> None:
    """:func:`_observe_env`'s reading and scoring of envs not fresh, into their state.

    The references are in ``state[E_REFERENCE]``; ``noise`` is the envs' sensor noise (entry
    ``i - lo``, :func:`_block_noise`) or ``0.0`` for all. A loop free of branches over two
    arrays, three with noise (the compiler must prove the arrays of a loop apart before it runs
    the loop in SIMD lanes, and gives up beyond a few).
    """
    cfg = _settings(config)
    base = np.uint64(lo)
    # an unsigned index: numba then adds no wrap-around of negative indices, which would hide
    # from the compiler that the loop walks each array with unit stride
    for i in range(np.uint64(lo), np.uint64(hi)):
        x, v = state[plant_kernel.S_X, i], state[plant_kernel.S_V, i]
        gain, offset, added = rows[T_GAIN, i], rows[T_OFFSET, i], _noise_at(noise, i - base)
        measured, position, velocity = _reading(x, v, gain, offset, added, cfg)
        applied = state[plant_kernel.S_COMMAND, i]
        umax = rows[T_UMAX, i]
        steps = state[E_STEPS, i]
        reference = state[E_REFERENCE, i]
        previous_velocity, previous_estimate = state[E_VELOCITY, i], state[E_ESTIMATE, i]
        scored = _scored(
            measured,
            position,
            velocity,
            applied,
            umax,
            steps,
            previous_velocity,
            previous_estimate,
            False,
            reference,
            dt,
            cfg,
            False,
        )
        _keep(i, measured, scored, state)


@njit(cache=True, inline="always")
def _output_lanes(
    lo: int,
    hi: int,
    state: npt.NDArray[np.float64],
    dt: float,
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
    encoder: bool,
) -> None:
    """Write the outputs of envs ``lo`` to ``hi - 1`` from their state (``encoder``: a constant).

    A loop each: a loop over two arrays is one the compiler proves safe to run in SIMD lanes,
    one over many is not.
    """
    for i in range(np.uint64(lo), np.uint64(hi)):
        out[O_REWARD, i] = state[E_REWARD, i]
    for i in range(np.uint64(lo), np.uint64(hi)):
        out[O_POSITION, i] = _toward(state[plant_kernel.S_X, i], encoder)
    for i in range(np.uint64(lo), np.uint64(hi)):
        out[O_VELOCITY, i] = _toward(state[plant_kernel.S_V, i], encoder)
    for i in range(np.uint64(lo), np.uint64(hi)):
        out[O_COMMAND, i] = state[plant_kernel.S_COMMAND, i]
    for i in range(np.uint64(lo), np.uint64(hi)):
        out[O_REFERENCE, i] = state[E_REFERENCE, i]
    for i in range(np.uint64(lo), np.uint64(hi)):
        out[O_TIME, i] = state[E_STEPS, i] * dt
    for i in range(np.uint64(lo), np.uint64(hi)):
        _publish(i, encoder, state, obs)
    for flag, row in _FLAG_ROWS:
        for i in range(np.uint64(lo), np.uint64(hi)):
            _flag(i, flag, row, state, flags)
    for i in range(np.uint64(lo), np.uint64(hi)):
        _done(i, flags)


@njit(cache=True, inline="always")
def _block_noise(
    lo: int, hi: int, rng: npt.NDArray[np.uint64], std: float
) -> npt.NDArray[np.float64]:
    """Return the sensor noise of envs ``lo`` to ``hi - 1`` (entry ``i - lo``), std ``std``.

    Each env's draw is :func:`~frictiongym.plants.sensors.normal_draw` of its own generator,
    split in two loops: the generators' uniforms (integer arithmetic, SIMD code), then the
    Box-Muller transform (calls of ``log`` and ``cos``, scalar).
    """
    envs = rng[lo:hi]
    first, second = np.empty(hi - lo), np.empty(hi - lo)
    for k in range(np.uint64(hi - lo)):
        first[k] = uniform_draw(envs, k)
        second[k] = uniform_draw(envs, k)
    for k in range(np.uint64(hi - lo)):
        first[k] = std * box_muller(first[k], second[k])
    return first


def _noise_at(noise: Any, k: int) -> float:
    """Return entry ``k`` of an array of noise, or the float ``noise`` itself.

    Compiled per type (:func:`_noise_at_overload`): a noiseless block reads no array.
    """
    # int(k): under NUMBA_DISABLE_JIT with NumPy 1.x, int - uint64 is a float
    return float(noise[int(k)]) if isinstance(noise, np.ndarray) else float(noise)


@overload(_noise_at, inline="always")
def _noise_at_overload(noise, k):  # type: ignore[no-untyped-def]  # numba matches its signature
    if isinstance(noise, types.Array):
        return lambda noise, k: noise[k]
    return lambda noise, k: noise


@njit(cache=True, inline="always")
def _fresh_count(lo: int, hi: int, fresh: npt.NDArray[np.bool_]) -> int:
    """How many of envs ``lo`` to ``hi - 1`` are fresh: a loop without branches (SIMD code)."""
    count = 0
    for i in range(np.uint64(lo), np.uint64(hi)):
        count += np.uint64(fresh[i])
    return count


@njit(cache=True, parallel=True, error_model="numpy")
def observe_block(
    lo: int,
    hi: int,
    state: npt.NDArray[np.float64],
    dt: float,
    rows: npt.NDArray[np.float64],
    rng: npt.NDArray[np.uint64],
    config: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> int:
    """Observe envs ``lo`` to ``hi - 1`` in SIMD code.

    The references are evaluated first, in a loop of their own (a sine needs a call, a step
    sequence an indirect read), and the sensor noise, if any, in loops of its own
    (:func:`_block_noise`); then the rest in SIMD code, as if every env had been stepped; then
    the fresh envs (just reset, rare) once more on their own. Compiled on its own (the parallel
    pipeline starts no threads here; it drops reference counting) with NumPy's error model, so
    that no exception branch stays in the loops. Both ways compute the same values with the
    same operations. Returns how many of these envs ended their episode (terminated or
    truncated).
    """
    for i in range(lo, hi):
        state[E_REFERENCE, i] = reference_at(state[E_STEPS, i] * dt, rows, i, T_REF)
    if config[C_NOISE] > 0.0:
        noise = _block_noise(lo, hi, rng, config[C_NOISE])
        _score_lanes(lo, hi, state, dt, rows, config, noise)
    else:
        _score_lanes(lo, hi, state, dt, rows, config, 0.0)
    if config[C_SENSOR] == SENSOR_ENCODER:
        _output_lanes(lo, hi, state, dt, obs, out, flags, True)
    else:
        _output_lanes(lo, hi, state, dt, obs, out, flags, False)
    # the fresh envs once more (the loops took every env as stepped); most blocks have none,
    # found by a count without branches
    if _fresh_count(lo, hi, fresh) > 0:
        for i in range(lo, hi):
            if fresh[i]:
                # the noise drawn for them above, drawn again from their generators' state
                std = config[C_NOISE]
                added = std * last_normal_draw(rng, i) if std > 0.0 else 0.0
                _observe_env(i, state, dt, rows, added, config, fresh, obs, out, flags)
    ended = 0
    for i in range(np.uint64(lo), np.uint64(hi)):
        ended += flags[F_DONE, i]
    return ended


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

    The same :func:`_scored` as the simulator's: identical readings give identical observations.
    """
    if not fresh[0]:
        state[E_STEPS, 0] += 1.0
    cfg = _settings(config)
    steps = state[E_STEPS, 0]
    t = steps * dt
    reference = reference_at(t, rows, 0, T_REF)
    previous_velocity, previous_estimate = state[E_VELOCITY, 0], state[E_ESTIMATE, 0]
    scored = _scored(
        measured,
        measured,
        0.0,
        applied,
        umax,
        steps,
        previous_velocity,
        previous_estimate,
        fresh[0],
        reference,
        dt,
        cfg,
        True,
    )
    encoder = cfg[C_SENSOR] == SENSOR_ENCODER
    _write(0, measured, scored, applied, reference, t, encoder, state, obs, out, flags)
    flags[F_STUCK, 0] = False


@njit(cache=True)
def reset_envs(
    mask: npt.NDArray[np.bool_],
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    position: npt.NDArray[np.float64],
    velocity: npt.NDArray[np.float64],
    reference: npt.NDArray[np.float64],
    set_rows: bool,
) -> None:
    """Put the envs of ``mask`` at rest-or-moving starts (k-th masked env: ``position[k]``).

    ``position`` and ``velocity`` hold an entry per masked env, or one for all.

    With ``set_rows`` their task columns also get unit sensor gain and the ``reference`` row;
    otherwise the caller has set the rows. The sensor offset is always zeroed, and the command
    limit copied from the env's plant row (set before this call).
    """
    index = plant_kernel.selected(mask)
    for k in range(index.shape[0]):
        i, at = index[k], k if position.shape[0] > 1 else 0
        _reset_env(i, position[at], velocity[at], state, delay_buffer, plant_rows, rows)
        if set_rows:
            rows[T_GAIN, i] = 1.0
            for entry in range(REF_SIZE):
                rows[T_REF + entry, i] = reference[entry]


@njit(cache=True, inline="always")
def _reset_env(
    i: int,
    position: float,
    velocity: float,
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
) -> None:
    """Put env ``i``'s plant at ``position`` moving at ``velocity``, and set its task rows.

    The rows every reset sets: the sensor offset zeroed, the command limit copied from the
    env's plant row.
    """
    plant_kernel.reset_plant(i, position, velocity, state, delay_buffer)
    rows[T_OFFSET, i] = 0.0
    rows[T_UMAX, i] = plant_rows[0 if plant_rows.shape[0] == 1 else i, I_UMAX]


@njit(cache=True, inline="always")
def _reset_fresh(
    lo: int,
    hi: int,
    fresh: npt.NDArray[np.bool_],
    start: npt.NDArray[np.float64],
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
) -> None:
    """Reset the fresh envs among ``lo`` to ``hi - 1`` to ``start`` (position, velocity).

    :func:`reset_envs` without ``set_rows``, in the kernel: an autoreset that draws nothing.
    """
    if _fresh_count(lo, hi, fresh) > 0:  # most blocks have none
        for i in range(lo, hi):
            if fresh[i]:
                _reset_env(i, start[0], start[1], state, delay_buffer, plant_rows, rows)


@njit(cache=True)
def observe_envs(
    mask: npt.NDArray[np.bool_],
    state: npt.NDArray[np.float64],
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
    std = config[C_NOISE]
    for i in range(mask.shape[0]):
        if mask[i]:
            noise = std * normal_draw(rng, i) if std > 0.0 else 0.0
            _observe_env(i, state, dt, rows, noise, config, mask, obs, out, flags)


@njit(cache=True)
def publish_envs(
    state: npt.NDArray[np.float64], config: npt.NDArray[np.float64], obs: npt.NDArray[np.float32]
) -> None:
    """Write every env's observation again from its state: the one it last returned.

    Every observation is written by :func:`_publish` from the state rows it reads, and nothing
    else changes them between steps.
    """
    encoder = config[C_SENSOR] == SENSOR_ENCODER
    for i in range(state.shape[1]):
        _publish(i, encoder, state, obs)


def float64_commands(command: npt.NDArray[np.floating[Any]]) -> npt.NDArray[np.float64]:
    """Return ``command`` itself if it is a contiguous float64 array, else a float64 buffer.

    A buffer of one command per env is left empty: each block converts its own envs'
    commands into it (:func:`convert_commands`), on the thread that steps them, so that no
    thread reads commands another has just written. Compiled per type
    (:func:`_float64_commands`): the plant kernel then sees one command type and compiles once,
    not once per type (30 s each).
    """
    return np.ascontiguousarray(command, dtype=np.float64)


@overload(float64_commands)
def _float64_commands(command):  # type: ignore[no-untyped-def]  # numba matches its signature
    if command.dtype == types.float64 and command.layout == "C":
        return lambda command: command

    def buffer(command):  # type: ignore[no-untyped-def]
        if command.shape[0] == 1:  # one command for all: every block reads it
            return np.ascontiguousarray(command).astype(np.float64)
        return np.empty(command.shape[0])

    return buffer


def convert_commands(
    lo: int,
    hi: int,
    command: npt.NDArray[np.floating[Any]],
    buffer: npt.NDArray[np.float64],
) -> None:
    """Fill ``buffer`` (:func:`float64_commands`) with the commands of envs ``lo`` to ``hi - 1``."""
    buffer[lo:hi] = command[lo:hi]


@overload(convert_commands)
def _convert_commands(lo, hi, command, buffer):  # type: ignore[no-untyped-def]
    if command.dtype == types.float64 and command.layout == "C":
        return lambda lo, hi, command, buffer: None  # the buffer is the command array itself

    def convert(lo, hi, command, buffer):  # type: ignore[no-untyped-def]
        if command.shape[0] > 1:  # else converted whole
            for i in range(lo, hi):
                buffer[i] = command[i]

    return convert


@njit(cache=True, inline="always")
def _step_block(
    block: int,
    state: npt.NDArray[np.float64],
    delay_buffer: npt.NDArray[np.float64],
    head: int,
    given: npt.NDArray[np.floating[Any]],
    command: npt.NDArray[np.float64],
    dt: float,
    n_sub: int,
    plant_rows: npt.NDArray[np.float64],
    rows: npt.NDArray[np.float64],
    rng: npt.NDArray[np.uint64],
    config: npt.NDArray[np.float64],
    fresh: npt.NDArray[np.bool_],
    reset: bool,
    start: npt.NDArray[np.float64],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> int:
    """Step the envs of one block (those not ``fresh``), observe them all; return how many ended.

    ``given`` holds the caller's commands, ``command`` them as float64 (:func:`float64_commands`;
    this block converts its own). With ``reset`` the fresh envs are first reset to ``start``
    (:func:`_reset_fresh`), by the thread that steps the block: the main thread then touches no
    line of their state. Two loops, not one: fused into one loop body the plant step and the
    observation compiled to code half as fast as the two apart (docs/benchmarks.md, "A kernel
    near the machine's limit"); a block's state stays in cache from the first loop to the
    second.
    """
    start_env, stop_env = block * BLOCK, min((block + 1) * BLOCK, state.shape[1])
    if reset:
        _reset_fresh(start_env, stop_env, fresh, start, state, delay_buffer, plant_rows, rows)
    convert_commands(start_env, stop_env, given, command)
    plant_batch.step_plants(
        start_env, stop_env, state, delay_buffer, head, command, dt, n_sub, plant_rows, fresh
    )
    for i in range(start_env, stop_env):
        state[E_STEPS, i] += 0.0 if fresh[i] else 1.0  # steps count from +0.0: no sign to keep
    return observe_block(start_env, stop_env, state, dt, rows, rng, config, fresh, obs, out, flags)


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
    reset: bool,
    start: npt.NDArray[np.float64],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> int:
    """Step every env not ``fresh`` under ``command`` and observe all of them, in place.

    With ``reset`` the fresh envs are reset first to ``start`` (their position and velocity)
    as :func:`reset_envs` does without ``set_rows``, once the commands are found finite: the
    autoreset of envs whose reset draws nothing and whose task rows hold the defaults.

    Returns the index of the first non-finite command (then nothing changed), or else -1 minus
    the number of envs whose episode ended on this step (their ``F_DONE`` flags).
    """
    bad = plant_batch.first_non_finite(command)
    if bad >= 0:
        return bad
    command64 = float64_commands(command)  # one type for the plant kernel
    ended = 0
    for block in range((state.shape[1] + BLOCK - 1) // BLOCK):
        ended += _step_block(
            block,
            state,
            delay_buffer,
            head,
            command,
            command64,
            dt,
            n_sub,
            plant_rows,
            rows,
            rng,
            config,
            fresh,
            reset,
            start,
            obs,
            out,
            flags,
        )
    return -1 - ended


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
    reset: bool,
    start: npt.NDArray[np.float64],
    obs: npt.NDArray[np.float32],
    out: npt.NDArray[np.float64],
    flags: npt.NDArray[np.bool_],
) -> int:
    """:func:`step_envs` with the blocks spread over numba's threads (bit-identical results)."""
    bad = plant_batch.first_non_finite(command)
    if bad >= 0:
        return bad
    command64 = float64_commands(command)  # one type for the plant kernel
    ended = 0
    for block in prange((state.shape[1] + BLOCK - 1) // BLOCK):
        ended += _step_block(
            np.int64(block),  # prange's index is unsigned; the body indexes with signed integers
            state,
            delay_buffer,
            head,
            command,
            command64,
            dt,
            n_sub,
            plant_rows,
            rows,
            rng,
            config,
            fresh,
            reset,
            start,
            obs,
            out,
            flags,
        )
    return -1 - ended
