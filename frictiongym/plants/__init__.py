"""Nominal plants with friction, actuator and sensors; the batched stick/slip step."""

from frictiongym.plants.plant import Plant, PlantParams, plant_row

__all__ = ["Plant", "PlantParams", "plant_row"]
