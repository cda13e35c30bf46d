"""Plant presets: the paper's QUBE-Servo 2 and our Altino model.

Every number cites its source: the paper (*Performance Enhancement of Motion Control Systems
Through Friction Identification and Compensation*), a datasheet or vendor code, or *assumed, see
docs/altino-model.md*.
"""

from __future__ import annotations

from frictiongym.plants.plant import PlantParams

# --- QUBE-Servo 2 (position in rad, velocity in rad/s, command in V) -------------------------

#: Paper Eq. (2) and §3.1: J_e = 7.143e-3 V·s², B_e = 0.0446 V·s (first-order identification,
#: load disk included; B_e contains the viscous slope 0.0411 V/(rad/s) of Fig. 8(b)).
#: ±10 V: the QUBE-Servo 2 amplifier's command range (Quanser's QUBE-Servo 2 user manual).
#: Backlash (none by default: the disc sits on the motor shaft by a magnet, no gearbox): with
#: ``backlash=`` the load is the disc, 0.80 of J (disc 0.5 m r^2 = 0.5 x 0.053 kg x (0.0248 m)^2
#: = 1.63e-5 kg·m², rotor 4.0e-6 kg·m²: the QUBE-Servo 2 user manual's parameter table), and it
#: carries no friction (the motor's brushes and bearings hold it all; assumed, docs/physics.md).
ROTARY_PLANT = PlantParams(
    inertia=7.143e-3, damping=0.0446, command_limit=10.0, load_inertia=0.8, load_friction=0.0
)

#: 500 Hz, Quanser's usual QUBE-Servo 2 rate (its QUARC models, e.g. ``q_qube2_swingup``, use
#: Ts = 2 ms).
ROTARY_DT = 0.002

#: Velocity estimate 50 s / (s + 50) of the encoder angle, as in Quanser's QUBE models and
#: examples.
ROTARY_VELOCITY_CUTOFF = 50.0

#: The paper's PID for the servo (§3.1), found by random search against its specs.
ROTARY_PAPER_GAINS = {"kp": 7.8, "ki": 1.5, "kd": 0.275}

# --- Altino (position in cm toward the wall, velocity in cm/s, command in motor units) -------

#: The paper gives no nominal model (§3.2); every number here is *assumed, see
#: docs/altino-model.md*:
#:
#: * ``inertia`` 2.2 units·s²/cm: effective mass (car + reflected rotor inertia) in command units,
#:   chosen for a mechanical time constant M/B = 2.2/10.93 = 0.20 s, typical of a small geared DC
#:   motor drive; full command from rest then accelerates at (1000 - 200)/2.2 = 364 cm/s²
#:   (0.37 g), below the tyre-grip limit of a toy car.
#: * ``damping`` 0: the paper's viscous slope 10.93 units/(cm/s) (Fig. 10(b)) is in the friction
#:   law (``ALTINO_PAPER.viscous``) and adds to this.
#: * ``command_limit`` 1000: the Altino's motor command range (``Go(±1000)`` of the
#:   vendor's ``Altino.h``).
#: * ``lag`` 0: a small DC motor's electrical time constant L/R is about 1 ms, far below the control
#:   period; the mechanical lag is the mass itself.
#: * ``dead_time`` 0.05 s = one control period: Bluetooth SPP latency (tens of ms) plus the 10 ms
#:   the on-board library waits per frame (the vendor's ``Altino.h``).
#: * ``load_inertia`` 0.8 and ``load_friction`` 0.5, used only with ``backlash=`` (a gear train's
#:   play, cm of travel): the car's mass against the rotor's reflected inertia, and rolling
#:   resistance against the gearbox's friction. Assumed, see docs/altino-model.md.
ALTINO_PLANT = PlantParams(
    inertia=2.2,
    damping=0.0,
    command_limit=1000.0,
    lag=0.0,
    dead_time=0.05,
    load_inertia=0.8,
    load_friction=0.5,
)

#: 20 Hz: one drive command and one sensor poll per period fit the Altino's serial protocol with
#: its 10 ms per-frame delay, which makes 10–50 Hz the realistic range. Assumed, see
#: docs/altino-model.md.
ALTINO_DT = 0.05

#: Start of the paper's step (not stated in the paper). Assumed, see docs/altino-model.md: the
#: IR sensor's "effective range of up to 30 cm" (paper §2.2), the farthest distance the authors
#: considered measured. Eq. (1) reads 0 beyond 21.47 cm, so the estimate is saturated there
#: for the first ~0.5 s of the approach. Any start from 38.5 cm drives the Ki = 20 run into the
#: wall in this model, which the paper's Ki = 20 run did not do.
ALTINO_START_CM = 30.0

#: The paper's Altino experiments (§3.2, §5.2): target 5 cm from a wall at 0.
ALTINO_TARGET_CM = 5.0
ALTINO_PAPER_GAINS_KI10 = {"kp": 25.0, "ki": 10.0, "kd": 12.0}
ALTINO_PAPER_GAINS_KI20 = {"kp": 25.0, "ki": 20.0, "kd": 12.0}
ALTINO_PAPER_GAINS_COMPENSATED = {"kp": 25.0, "ki": 0.5, "kd": 7.0}
