"""frictiongym: friction as a first-class part of motion-control simulation and control.

Importing the package registers its Gymnasium ids (``frictiongym/RotaryServo-v0``,
``frictiongym/AltinoDistance-v0``).
"""

from frictiongym.envs import register_envs

__version__ = "0.1.0"

register_envs()
