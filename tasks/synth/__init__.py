"""Synthetic building surveys with ground truth (issue 3): geometry, plan raster, sensors, assembly."""

from tasks.synth.scene import Material, SceneMesh

__all__ = ["Material", "SceneMesh"]
