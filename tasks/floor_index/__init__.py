"""floor_index: one row per survey room (a building-after stage: it reads every room's results)."""
