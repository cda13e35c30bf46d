"""``frictiongym/RotaryServo-v1``: position control of a Quanser QUBE-Servo 2 with friction."""

from __future__ import annotations

from frictiongym.devices import ROTARY
from frictiongym.envs.base import FrictionEnv
from frictiongym.envs.vector import FrictionVectorEnv


class RotaryServoEnv(FrictionEnv):
    r"""Position control of a Quanser QUBE-Servo 2 inertia disk with stiction and Coulomb friction.

    ## Description

    A DC motor turns an inertia disk: ``J θ'' + B θ' = u - F(θ', u)`` with the paper's
    identified ``J = 7.143e-3 V·s²``, ``B = 0.0446 V·s`` (Eq. (2)) and its asymmetric
    stiction/Coulomb friction ``F`` (Fig. 8(b); ``u_s+ = 0.210 V``, ``u_s- = 0.190 V``,
    ``u_c+ = 0.124 V``, ``u_c- = 0.104 V``). The disk sticks while the voltage lies in the
    break-away band and the plant is stepped with true stick/slip, so a PID without friction
    compensation stalls short of its target (docs/physics.md). The goal is to make the disk's
    angle follow a reference.

    ## Action Space

    ``Box(-10, 10, (1,), float32)``: the motor voltage, V. A larger value is saturated at
    ±10 V as the amplifier does, and ``info["command"]`` reports the applied voltage. NaN or
    infinite actions raise ``ValueError``. RL code may rescale with
    ``gymnasium.wrappers.RescaleAction``.

    ## Observation Space

    ``Box(-inf, inf, (3,), float32)``, what a QUBE controller measures:

    | Num | Observation | Unit  | Source                                              |
    |-----|-------------|-------|-----------------------------------------------------|
    | 0   | angle       | rad   | encoder, 2048 counts/rev (``quantize``), + noise    |
    | 1   | velocity    | rad/s | filtered derivative ``50 s/(s + 50)`` of the angle   |
    | 2   | reference   | rad   | the reference at this sample                        |

    After the disk stops, the filtered estimate decays geometrically; once it is below
    ``2**-24`` of its resolution (one count in one period through the filter, 0.146 rad/s)
    it is exactly 0.0, so observations hold no float32 subnormals and no ``-0.0``
    (:func:`~frictiongym.plants.sensors.velocity_floor`).

    ## Rewards

    ``-min(|r - θ| / 1 rad, 2π) - effort_weight * (u / 10 V)²`` per step (v1), with the true
    angle θ and the applied voltage ``u`` (``effort_weight`` 0.01): a step costs between 0 and
    ``c = 2π + 0.01``, so an episode of ``H`` steps scores at least ``-c H``. The step that
    crosses the safety limit costs ``limit_penalty`` (100) more, and ``c H`` more again: an
    episode ended at the limit scores below ``-c H``, less than any episode of up to ``H``
    steps that does not end there, so an agent never gains by running into the limit. ``H``
    is ``horizon``: by default the vector env's ``max_episode_steps``, else the registered
    2500 steps (a single env cannot see its ``TimeLimit``: give ``horizon`` with another
    ``max_episode_steps``). With v0 it did pay: 10 V from rest reached the limit in 79 steps
    for -415, where holding still scored -2500 (v1: -16 088). ``terminal_cost=False`` gives
    v0's reward: the tracking term uncapped and only the penalty at the limit.

    ## Starting State

    At rest at 0 rad, stuck. ``reset(options=...)`` takes ``position`` (rad), ``velocity``
    (rad/s) and ``reference`` (as the ``reference`` argument) for one episode.

    ## Episode End

    Terminated when ``|θ|`` exceeds ``safety_limit`` (4π rad, a run-away guard: the disk has
    no end stops); truncated after 2500 steps (5 s at 2 ms) by the registered time limit.

    ## Arguments

    ``gym.make("frictiongym/RotaryServo-v1", **kwargs)`` with

    * ``friction``: ``"paper"`` (default), ``"none"``, ``"coulomb"``, ``"stribeck"``,
      ``"lugre"`` or a :class:`~frictiongym.friction.FrictionModel`;
    * ``dt``: control period, s (default 0.002);
    * ``reference``: ``"step"`` (1 rad, default), ``"step_sequence"``, ``"ramp"``, ``"sine"``,
      ``"random_steps"`` (a new level in ±π every second), a number (a constant set-point) or a
      :mod:`~frictiongym.envs.references` generator;
    * ``sensor_noise``: False (default), True (one encoder count, std) or a std in rad;
    * ``quantize``: encoder quantisation (default True);
    * ``delay``: actuator dead time, s, whole periods (default 0);
    * ``deadzone``: half-width of the amplifier's dead zone, V: a command up to it in
      magnitude drives nothing, a larger one drives ``u - deadzone sign(u)`` (default 0: none);
    * ``backlash``: free play between the motor and the disc, rad (default 0: none, as on the
      QUBE, whose disc sits on the shaft): the motor turns this far between the faces without
      moving the disc, which then carries 0.8 of ``J`` and no friction (``plant=`` sets other
      shares); the position and velocity are the disc's (docs/physics.md, "Backlash");
    * ``jitter``: varying latency of the drive, s, below ``dt``: each new command takes
      effect at a uniformly random instant up to ``jitter`` after the step starts (on top of
      ``delay``), drawn from the env's seed (default 0: none);
    * ``randomize``: factor ranges drawn at each reset, e.g. ``{"friction": (0.5, 1.5),
      "inertia": (0.9, 1.1), "damping": (0.8, 1.2), "sensor_gain": (0.99, 1.01)}``
      (``"deadzone"`` and ``"backlash"`` scale the ``deadzone`` and ``backlash`` given);
    * ``plant``: a :class:`~frictiongym.plants.PlantParams` replacing the nominal plant;
    * ``params``: identified parameters, the path of a ``friction.json`` (or its directory) or
      a :class:`~frictiongym.params.DeviceParams`: the plant gets the file's ``J`` and total
      damping ``B``, the friction its law with the viscous slope left out (``B`` includes it),
      and compensators built with ``for_env`` model its friction. Not with ``plant`` or another
      ``friction``; a file identified on another device is refused;
    * ``effort_weight``, ``safety_limit`` (rad), ``limit_penalty``, ``terminal_cost``,
      ``horizon``: reward and safety (see Rewards);
    * ``backend``: ``"sim"`` (default), a device URI (``"serial:///dev/ttyACM0"``,
      ``"quanser-hil://qube_servo2_usb/0"``, ``"emulator://rotary"``...) or a
      :class:`~frictiongym.hardware.Backend` (docs/hardware.md); on a device ``log`` (True, a
      directory or False) and ``run_metadata`` set the run log, simulator-only settings are
      refused and ``info`` holds the measured estimates;
    * ``render_mode``: ``"rgb_array"`` or ``"human"`` (needs pygame).

    ``info`` of every step: ``position`` (true angle, rad), ``velocity`` (true, rad/s),
    ``command`` (applied voltage), ``reference``, ``time`` (s since reset), ``stuck``.

    An unknown argument raises ``TypeError`` naming the valid ones; ``step`` before the first
    ``reset`` raises ``gymnasium.error.ResetNeeded``; an action must be one number of shape
    ``(1,)`` (a list, tuple or array).

    ## Version History

    * v1: the tracking term capped at 2π and the terminal cost of a worst whole episode
      (``terminal_cost=True``, the default), so an episode ended by the safety limit never
      pays off.
    * v0: first release; still registered (with ``terminal_cost=False``), for the results
      made with it.
    """

    device = ROTARY


class RotaryServoVectorEnv(FrictionVectorEnv):
    """``num_envs`` QUBE-Servo 2 envs stepped by one compiled call (see :class:`RotaryServoEnv`).

    Takes the single env's arguments plus ``num_envs``, ``max_episode_steps`` (default 2500
    through ``gym.make_vec``) and ``parallel`` (``True``: numba's threads, ``False``: one;
    default: from 512 envs, whichever is faster at the moment) and ``autoreset_mode``
    (``NEXT_STEP`` by default, ``SAME_STEP`` or ``DISABLED``: :mod:`frictiongym.envs.vector`).
    Env ``i`` of ``reset(seed=s)`` follows the single env reset with ``seed=s + i`` exactly.
    """

    device = ROTARY
