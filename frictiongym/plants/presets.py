"""Plant presets: the paper's QUBE-Servo 2 and our Altino model.

Every number cites its source: the paper (``shared/reference/friction-paper.txt``), a
datasheet, or *assumed, see docs/altino-model.md*.
"""

from __future__ import annotations

from frictiongym.plants.plant import PlantParams

# --- QUBE-Servo 2 (position in rad, velocity in rad/s, command in V) -------------------------

#: Paper Eq. (2) and §3.1: J_e = 7.143e-3 V·s², B_e = 0.0446 V·s (first-order identification,
#: load disk included; B_e contains the viscous slope 0.0411 V/(rad/s) of Fig. 8(b)).
#: ±10 V: the QUBE-Servo 2 amplifier's command range (Quanser user manual; research/hardware.md).
ROTARY_PLANT = PlantParams(inertia=7.143e-3, damping=0.0446, command_limit=10.0)

#: 500 Hz, Quanser's usual QUBE-Servo 2 rate (QUARC models use Ts = 2 ms; research/hardware.md).
ROTARY_DT = 0.002

#: Velocity estimate 50 s / (s + 50) of the encoder angle, as in Quanser's QUBE models
#: (research/hardware.md).
ROTARY_VELOCITY_CUTOFF = 50.0

#: The paper's PID for the servo (§3.1), found by random search against its specs.
ROTARY_PAPER_GAINS = {"kp": 7.8, "ki": 1.5, "kd": 0.275}

# --- Altino (position in cm toward the wall, velocity in cm/s, command in motor units) -------

#: The paper gives no nominal model (§3.2). Assumed, see docs/altino-model.md: effective mass
#: in command units per cm/s², no extra linear damping beyond the friction law's viscous slope
#: 10.93 units/(cm/s) (paper Fig. 10(b)), ±1000 command saturation (the Altino's motor range),
#: and a dead time of one control period for the Bluetooth serial round trip.
ALTINO_PLANT = PlantParams(
    inertia=2.0, damping=0.0, command_limit=1000.0, lag=0.0, dead_time=0.05
)

#: 20 Hz: the Altino's serial protocol and on-board 10 ms delay allow 10–50 Hz
#: (research/hardware.md). Assumed, see docs/altino-model.md.
ALTINO_DT = 0.05

#: The paper's Altino experiments (§3.2, §5.2): target 5 cm from a wall at 0.
ALTINO_TARGET_CM = 5.0
ALTINO_PAPER_GAINS_KI10 = {"kp": 25.0, "ki": 10.0, "kd": 12.0}
ALTINO_PAPER_GAINS_KI20 = {"kp": 25.0, "ki": 20.0, "kd": 12.0}
ALTINO_PAPER_GAINS_COMPENSATED = {"kp": 25.0, "ki": 0.5, "kd": 7.0}
