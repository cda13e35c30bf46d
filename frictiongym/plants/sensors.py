"""What a controller actually measures: encoder counts, a filtered-derivative velocity, IR readouts.

Each sensor is one compiled scalar function (``encoder_angle``, ``ir_count``, ``ir_estimate``,
``derivative_update``) that the env kernel calls per plant; the public functions here are ufuncs
of the same code, vectorised over any batch shape. Randomness (sensor noise) is never drawn
here: callers pass noise samples drawn from their own generator (an env's ``np_random``, or the
compiled :func:`normal_draw` seeded from it), so every trajectory is reproducible from the seed.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit

from frictiongym._ufunc import float64_ufunc
from frictiongym._validation import real_number

FloatArray = npt.NDArray[np.float64]

SENSOR_ENCODER = 0  #: servo: angle through an encoder, observation [angle, velocity, reference]
SENSOR_IR = 1  #: Altino: IR readout, observation [readout, distance, velocity, reference]

#: QUBE-Servo 2 encoder resolution in quadrature, counts per revolution (Quanser datasheet;
#: the paper's testbed, and gym_brt's ``2*pi/2048``).
QUBE_COUNTS_PER_REV = 2048
#: One encoder count, rad.
QUBE_ENCODER_STEP = 2.0 * math.pi / QUBE_COUNTS_PER_REV

#: Altino IR sensor (paper Eq. (1)): distance d = 966 / (x + 45) cm from the readout x.
IR_NUMERATOR = 966.0
IR_OFFSET = 45.0
IR_MAX_READOUT = 800

#: Relative precision of a float32 observation (its unit roundoff, 2**-24).
FLOAT32_ROUNDOFF = 2.0**-24


@njit(cache=True, inline="always")
def encoder_angle(angle: float, step: float) -> float:
    """Angle read through an encoder of resolution ``step`` rad: ``round(angle / step)`` counts.

    Ties round up (``floor(x + 0.5)``), so the reading errs by at most ``step / 2``.
    """
    return np.floor(angle / step + 0.5) * step


@njit(cache=True, inline="always")
def ir_count(
    distance: float, gain: float, offset: float, noise: float, quantize: bool = True
) -> float:
    """IR readout in 0..800 at ``distance`` > 0 cm (see ir_readout); ``quantize``: rounded."""
    raw = gain * IR_NUMERATOR / distance - IR_OFFSET + offset + noise
    if quantize:
        raw = np.rint(raw)
    if not raw > 0.0:  # also maps rint's -0.0 (a readout just below 0.5) to 0.0
        return 0.0
    return min(raw, float(IR_MAX_READOUT))


@njit(cache=True, inline="always")
def ir_estimate(readout: float) -> float:
    """Distance in cm that a readout stands for, by the paper's calibration, Eq. (1)."""
    return IR_NUMERATOR / (readout + IR_OFFSET)


def noise_std(setting: bool | float, default: float) -> float:
    """Sensor noise of a ``sensor_noise`` setting: none (False), ``default`` (True) or a std."""
    if setting is True or setting is False:
        return default if setting else 0.0
    return real_number("sensor_noise", setting, ">= 0")


def ir_quantum() -> float:
    """Finest step of the IR distance estimate, cm: one readout count at the nearest reading."""
    return float(ir_estimate(IR_MAX_READOUT - 1) - ir_estimate(IR_MAX_READOUT))


def velocity_floor(quantum: float, pole: float, dt: float) -> float:
    """Smallest velocity estimate worth reporting; smaller ones are reported as exactly 0.0.

    One sensor step (``quantum``: an encoder count, or the finest IR distance step) within one
    period moves the estimate by ``(1 - pole) * quantum / dt``, its resolution. After the body
    stops, the estimate only decays geometrically (``pole**k``) and would shrink through the
    float32 subnormals to ``-0.0``. Below ``2**-24`` of the resolution, the relative precision
    of a float32 observation, a remainder is lost beside any new count: it carries no
    information, so it is zeroed (and never signed).

    Parameters
    ----------
    quantum : float
        Position resolution of the sensor, position units.
    pole : float
        Filter pole ``exp(-w dt)`` (0.0: backward difference).
    dt : float
        Sample period, s.

    Returns
    -------
    float
        The floor, velocity units.
    """
    return (1.0 - pole) * quantum / dt * FLOAT32_ROUNDOFF


# Sensor noise: splitmix64 (Steele, Lea & Flood 2014), one uint64 of state per plant, so the
# noise of plant i depends only on its own seed, however the batch is split over threads.
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


@njit(cache=True, inline="always")
def uniform_draw(rng: npt.NDArray[np.uint64], i: int) -> float:
    """Draw the next uniform in (0, 1] from generator ``i``."""
    z = rng[i] + _GOLDEN
    rng[i] = z
    return _mixed(z)


@njit(cache=True, inline="always")
def _mixed(z: np.uint64) -> float:
    """Return the uniform in (0, 1] of splitmix64's state ``z``."""
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    z = z ^ (z >> _S31)
    return (float(z >> _S11) + 1.0) * (1.0 / 9007199254740992.0)


@njit(cache=True, inline="always")
def normal_draw(rng: npt.NDArray[np.uint64], i: int) -> float:
    """Draw a standard normal from generator ``i`` (Box-Muller, one of the pair)."""
    u1 = uniform_draw(rng, i)
    u2 = uniform_draw(rng, i)
    return box_muller(u1, u2)


@njit(cache=True, inline="always")
def last_normal_draw(rng: npt.NDArray[np.uint64], i: int) -> float:
    """Return what the last :func:`normal_draw` of generator ``i`` returned, drawing nothing.

    A splitmix64 draw is a function of the state it leaves, so the last two uniforms are
    those of the state and of the state one step back.
    """
    z = rng[i]
    return box_muller(_mixed(z - _GOLDEN), _mixed(z))


@njit(cache=True, inline="always")
def box_muller(u1: float, u2: float) -> float:
    """Return the standard normal of two uniforms in (0, 1] (Box-Muller, one of the pair)."""
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True, inline="always")
def measure(
    x: float, encoder: bool, gain: float, offset: float, noise: float, quantize: bool, step: float
) -> float:
    """Return the encoder angle (``step``: rad per count) or the IR readout of a plant at ``x``.

    The IR sensor faces a wall at ``x = 0``, which the plant approaches from below.
    """
    if encoder:
        angle = gain * x + noise
        return encoder_angle(angle, step) if quantize else angle
    distance = 0.0 - x
    if distance <= 0.0:  # touching the wall: the nearest reading
        return float(IR_MAX_READOUT)
    return ir_count(distance, gain, offset, noise, quantize)


@njit(cache=True, inline="always")
def derivative_update(
    estimate: float, position: float, previous: float, pole: float, dt: float, floor: float
) -> float:
    """One step of the filtered derivative (see :class:`FilteredDerivative`).

    Estimates smaller than ``floor`` in magnitude are exactly ``0.0`` (:func:`velocity_floor`).
    """
    rate = pole * estimate + (1.0 - pole) * (position - previous) / dt
    if abs(rate) < floor or rate == 0.0:  # rate == 0.0 also turns -0.0 into 0.0
        return 0.0
    return rate


@float64_ufunc(2)
def _encoder_ufunc(angle: float, step: float) -> float:
    return encoder_angle(angle, step)


@float64_ufunc(4)
def _ir_ufunc(distance: float, gain: float, offset: float, noise: float) -> float:
    return ir_count(distance, gain, offset, noise)


@float64_ufunc(1)
def _ir_estimate_ufunc(readout: float) -> float:
    return ir_estimate(readout)


@float64_ufunc(6)
def _derivative_ufunc(
    estimate: float, position: float, previous: float, pole: float, dt: float, floor: float
) -> float:
    return derivative_update(estimate, position, previous, pole, dt, floor)


def quantize_angle(angle: npt.ArrayLike, counts_per_rev: int = QUBE_COUNTS_PER_REV) -> FloatArray:
    """Angle as seen through an incremental encoder zeroed at reset.

    The count is ``round(angle / q)`` with ``q = 2*pi / counts_per_rev``: the reset angle is
    taken mid-count, so the reading errs by at most ``q / 2`` either way.

    Parameters
    ----------
    angle : array_like
        True angle, rad, relative to the angle at reset.
    counts_per_rev : int, default 2048
        Encoder counts per revolution (quadrature).

    Returns
    -------
    ndarray
        The quantised angle, rad.
    """
    return np.asarray(_encoder_ufunc(angle, 2.0 * math.pi / counts_per_rev), dtype=np.float64)


class FilteredDerivative:
    """Velocity estimate ``w s / (s + w)`` of a sampled position, batched.

    The continuous filter is discretised ramp-invariantly (exact when the position moves
    linearly between samples): ``v_k = a v_(k-1) + (1 - a) (y_k - y_(k-1)) / dt`` with
    ``a = exp(-w dt)``. It is stable for every ``dt`` and has unit gain on a ramp. Given the
    sensor's ``resolution``, estimates below :func:`velocity_floor` are exactly 0.0, as the
    envs observe them.

    Parameters
    ----------
    cutoff : float
        Filter bandwidth ``w``, rad/s (50 on the QUBE-Servo 2: the ``50s/(s+50)`` of Quanser's
        QUBE-Servo 2 tachometer).
    dt : float
        Sample period, s.
    shape : tuple of int, default ()
        Batch shape.
    resolution : float, default 0.0
        Position resolution of the sensor (the QUBE's encoder: ``QUBE_ENCODER_STEP``); 0.0
        keeps every estimate, down to the float64 subnormals.
    """

    def __init__(
        self, cutoff: float, dt: float, shape: tuple[int, ...] = (), resolution: float = 0.0
    ) -> None:
        self.cutoff = real_number("cutoff", cutoff, "> 0", unit=" rad/s")
        self.dt = real_number("dt", dt, "> 0", unit=" s")
        resolution = real_number("resolution", resolution, ">= 0")
        self.pole = math.exp(-self.cutoff * self.dt)
        self.floor = velocity_floor(resolution, self.pole, self.dt)
        self._previous: FloatArray = np.zeros(shape)
        self._estimate: FloatArray = np.zeros(shape)

    def reset(self, position: npt.ArrayLike = 0.0, velocity: npt.ArrayLike = 0.0) -> None:
        """Start from a measured ``position`` with the estimate at ``velocity``."""
        self._previous = np.broadcast_to(
            np.asarray(position, np.float64), self._previous.shape
        ).copy()
        self._estimate = np.broadcast_to(
            np.asarray(velocity, np.float64), self._estimate.shape
        ).copy()

    def update(self, position: npt.ArrayLike) -> FloatArray:
        """Feed the newest position sample; return the velocity estimate."""
        y = np.asarray(position, dtype=np.float64)
        self._estimate = np.asarray(
            _derivative_ufunc(self._estimate, y, self._previous, self.pole, self.dt, self.floor)
        )
        self._previous = y.copy()
        return self._estimate


def ir_readout(
    distance: npt.ArrayLike,
    gain: npt.ArrayLike = 1.0,
    offset: npt.ArrayLike = 0.0,
    noise: npt.ArrayLike = 0.0,
) -> npt.NDArray[np.int64]:
    """Integer readout of the Altino's IR distance sensor at a true distance.

    Inverts the paper's Eq. (1): the reflected intensity ``x + 45`` falls as ``966 / d``.
    Reflectivity scales that intensity (``gain``) and ambient light adds to the readout
    (``offset``); the result is rounded and saturates at 0 (far: beyond about 21.5 cm at
    unit gain) and 800 (near: closer than about 1.14 cm).

    Parameters
    ----------
    distance : array_like
        True distance to the wall, cm (> 0).
    gain : array_like, default 1.0
        Reflectivity relative to the paper's calibration.
    offset : array_like, default 0.0
        Ambient-light offset, readout units.
    noise : array_like, default 0.0
        Additive noise samples, readout units (drawn by the caller).

    Returns
    -------
    ndarray of int64
        Readouts in 0..800.
    """
    d = np.asarray(distance, dtype=np.float64)
    if np.any(~(d > 0.0)):
        raise ValueError("IR sensor distance must be > 0 cm (the car is touching the wall)")
    return np.asarray(_ir_ufunc(d, gain, offset, noise)).astype(np.int64)


def ir_distance(readout: npt.ArrayLike) -> FloatArray:
    """Distance estimate from an IR readout with the paper's calibration, Eq. (1), in cm."""
    return np.asarray(_ir_estimate_ufunc(np.asarray(readout, dtype=np.float64)))
