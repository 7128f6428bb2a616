"""Fusion of the room models into the coarse plan (thesis 7.1, 7.2): correspondence, 2D registration, wall
thickness, gap filling and the fused floor."""
