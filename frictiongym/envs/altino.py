"""``frictiongym/AltinoDistance-v1``: hold the Altino car at a distance from a wall, by IR."""

from __future__ import annotations

from frictiongym.devices import ALTINO
from frictiongym.envs.base import FrictionEnv
from frictiongym.envs.vector import FrictionVectorEnv


class AltinoDistanceEnv(FrictionEnv):
    r"""Drive the Altino robot car to a distance from a wall, measured by its front IR sensor.

    ## Description

    The car moves toward the wall under ``M x'' + B x' = u(t - T_d) - F(x', u)`` with the
    paper's asymmetric friction in motor units (Fig. 10(b): ``u_s± = 200``,
    ``u_c+ = 150.4``, ``u_c- = 119.6``, viscous 10.93 per cm/s) and an assumed mass, dead time
    and period (docs/altino-model.md: ``M = 2.2``, one period of dead time, 20 Hz). Its distance
    ``d`` to the wall is read through the IR sensor's integer readout, ``d = 966/(x + 45)``
    cm (paper Eq. (1)), which saturates at 0 (beyond 21.47 cm) and 800 (1.14 cm). The task
    of the paper: hold the car 5 cm from the wall.

    ## Action Space

    ``Box(-1000, 1000, (1,), float32)``: the motor command (the Altino's ``Go(±1000)`` units);
    **positive drives the car forward, toward the wall**. Larger values are saturated at ±1000
    and ``info["command"]`` reports the applied value; NaN or infinite actions raise
    ``ValueError``.

    ## Observation Space

    ``Box((0, 1.143, -inf, -inf), (800, 21.47, inf, inf), (4,), float32)``:

    | Num | Observation | Unit    | Source                                               |
    |-----|-------------|---------|------------------------------------------------------|
    | 0   | readout     | counts  | IR readout 0..800 (integer when ``quantize``), + noise |
    | 1   | distance    | cm      | ``966 / (readout + 45)``, the paper's Eq. (1)        |
    | 2   | velocity    | cm/s    | backward difference of the distance estimate         |
    | 3   | reference   | cm      | target distance at this sample                       |

    The velocity is the rate of the distance: negative while the car approaches the wall.
    Observations hold no float32 subnormals and no ``-0.0`` (see the servo's velocity).

    ## Rewards

    ``-min(|r - d| / 5 cm, 8) - effort_weight * (u / 1000)²`` per step (v1), with the true
    distance ``d`` and the applied command ``u`` (``effort_weight`` 0.01): a step costs
    between 0 and ``c = 8.01`` (the error is charged up to 40 cm, beyond the start and the
    IR's range), so an episode of ``H`` steps scores at least ``-c H``. The step that touches
    the wall costs ``limit_penalty`` (100) more, and ``c H`` more again: an episode ended at
    the wall scores below ``-c H``, less than any episode of up to ``H`` steps that does not
    touch it. ``H`` is ``horizon``: by default the vector env's ``max_episode_steps``, else
    the registered 400 steps (a single env cannot see its ``TimeLimit``: give ``horizon``
    with another ``max_episode_steps``). With v0 a crash paid: the contact cost 100 where
    standing still at the start cost 2000 per episode, so full throttle from the start (the
    wall in 13 steps, -135) beat holding still; v1 scores that crash -3339.
    ``terminal_cost=False`` gives v0's reward (no cap, only the penalty at the wall).

    ## Starting State

    At rest (stuck) 30 cm from the wall (the IR's stated range, docs/altino-model.md).
    ``reset(options=...)`` takes ``position`` (distance, cm > 0), ``velocity`` (rate of the
    distance, cm/s) and ``reference`` for one episode.

    ## Episode End

    Terminated when the car touches the wall (distance <= ``safety_limit``, 0 cm); truncated
    after 400 steps (20 s at 50 ms) by the registered time limit. The wall is a rigid stop:
    the contact is located inside the step and stops the car dead at 0 cm, so the terminal
    step's ``info`` (distance 0, velocity 0), observation (the nearest readout, 800) and
    reward describe the contact.

    ## Arguments

    As :class:`~frictiongym.envs.RotaryServoEnv`, in the car's units: ``friction``, ``dt``
    (default 0.05 s), ``reference`` (``"step"``: 5 cm, default; ``"step_sequence"``,
    ``"ramp"``, ``"sine"``, ``"random_steps"``: a new level in 3–18 cm every 5 s; a number; or a
    generator), ``sensor_noise`` (True: 2 readout units, std), ``quantize`` (integer readout),
    ``delay`` (default one period, 0.05 s), ``deadzone`` (motor units, default 0: none),
    ``backlash`` (the gear train's play as car travel, cm, default 0: none; the car is then
    0.8 of the mass and carries half the friction, assumed), ``jitter`` (the Bluetooth loop's
    varying latency, s, below ``dt``; default 0: none), ``randomize`` (``"inertia"`` is
    the car's mass,
    ``"sensor_gain"`` the wall's IR reflectivity), ``plant``, ``params`` (an identified
    ``friction.json`` of this car: its ``J`` is the mass, its ``B`` the total damping, viscous
    slope included; the preset is the file ``J = 2.2``, ``B = viscous = 10.93``),
    ``effort_weight``, ``safety_limit`` (cm), ``limit_penalty``, ``terminal_cost``,
    ``horizon``, ``backend`` (a device:
    ``"altino-stock:///dev/rfcomm0"``, ``"serial://..."``, ``"emulator://altino"``; see
    docs/hardware.md), ``log``, ``run_metadata``, ``render_mode``.

    ``info`` of every step: ``position`` (true distance to the wall, cm), ``velocity`` (its
    true rate, cm/s), ``command`` (applied), ``reference``, ``time`` (s), ``stuck``.

    ## Version History

    * v1: the tracking term capped (40 cm) and the terminal cost of a worst whole episode
      (``terminal_cost=True``, the default), so an episode ended at the wall never pays off.
    * v0: first release; still registered (with ``terminal_cost=False``), for the results
      made with it.
    """

    device = ALTINO


class AltinoDistanceVectorEnv(FrictionVectorEnv):
    """``num_envs`` Altino envs stepped by one compiled call (see :class:`AltinoDistanceEnv`).

    Takes the single env's arguments plus ``num_envs``, ``max_episode_steps`` (default 400
    through ``gym.make_vec``), ``parallel`` and ``autoreset_mode`` (``NEXT_STEP`` by default,
    ``SAME_STEP`` or ``DISABLED``: :mod:`frictiongym.envs.vector`). Env ``i`` of
    ``reset(seed=s)`` follows the single env reset with ``seed=s + i`` exactly.
    """

    device = ALTINO
