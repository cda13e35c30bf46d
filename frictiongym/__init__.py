"""frictiongym: friction as a first-class part of motion-control simulation and control."""

__version__ = "0.1.0"
