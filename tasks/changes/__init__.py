"""Change detection between the fused floor and its plan (thesis 7.2): added, removed and unknown walls,
moved doors and room-level changes."""
