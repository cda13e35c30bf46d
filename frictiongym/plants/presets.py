"""Plant presets: the paper's QUBE-Servo 2 and our Altino model.

The numbers are read from the built-in devices' description files
(``frictiongym/data/devices/*.toml``), where each cites its source: the paper (*Performance
Enhancement of Motion Control Systems Through Friction Identification and Compensation*), a
datasheet or vendor code, or *assumed, see docs/altino-model.md*.
"""

from __future__ import annotations

from frictiongym.data import device_table
from frictiongym.plants.plant import PlantParams

_SERVO, _ALTINO = device_table("rotary"), device_table("altino")

# --- QUBE-Servo 2 (position in rad, velocity in rad/s, command in V) -------------------------

#: Paper Eq. (2) and §3.1: J_e = 7.143e-3 V·s², B_e = 0.0446 V·s; ±10 V (the amplifier).
ROTARY_PLANT = PlantParams(**_SERVO["plant"])
#: 500 Hz, Quanser's usual QUBE-Servo 2 rate.
ROTARY_DT: float = _SERVO["dt"]
#: Velocity estimate 50 s / (s + 50) of the encoder angle, as in Quanser's QUBE models.
ROTARY_VELOCITY_CUTOFF: float = _SERVO["velocity_cutoff"]
#: The paper's PID for the servo (§3.1), found by random search against its specs.
ROTARY_PAPER_GAINS: dict[str, float] = dict(_SERVO["gains"]["pid"])

# --- Altino (position in cm toward the wall, velocity in cm/s, command in motor units) -------

#: The paper gives no nominal model (§3.2): every number is *assumed, see
#: docs/altino-model.md* (mass 2.2 units·s²/cm, ±1000 units, one period of dead time).
ALTINO_PLANT = PlantParams(**_ALTINO["plant"])
#: 20 Hz. Assumed, see docs/altino-model.md.
ALTINO_DT: float = _ALTINO["dt"]
#: Start of the paper's step (not stated in the paper): the IR sensor's "effective range of up
#: to 30 cm" (paper §2.2). Assumed, see docs/altino-model.md.
ALTINO_START_CM: float = _ALTINO["start"]
#: The paper's Altino experiments (§3.2, §5.2): target 5 cm from a wall at 0, and their gains.
ALTINO_TARGET_CM: float = _ALTINO["references"]["step"]["value"]
ALTINO_PAPER_GAINS_KI10: dict[str, float] = dict(_ALTINO["gains"]["pid"])
ALTINO_PAPER_GAINS_KI20: dict[str, float] = dict(_ALTINO["gains"]["pid-ki20"])
ALTINO_PAPER_GAINS_COMPENSATED: dict[str, float] = dict(_ALTINO["gains"]["compensated"])
