"""The plan stage (thesis 4.2.3): a coarse floor-plan raster -> metric wall centrelines, thicknesses, rooms
and doors. `parse.parse_plan` runs the steps of `raster` (enhancement, symbols, text, wall raster),
`vectorize` (skeleton, Hough, straight walls, thickness), `doors` and `rooms` (scale, rooms, preview);
`truth` compares a result with CAD ground truth; `stage.run` is the stage around it."""
