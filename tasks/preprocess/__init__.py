"""The preprocess stage (thesis 5.1): a registered room cloud -> a clean, smoothed, levelled cloud, the room's
floor, ceiling and height, and the furniture slice the walls stage projects. `pipeline.preprocess` runs the
steps of `filters` (voxel grid, outliers, MLS) and `levelling` (levelling, height histogram) in order; its
module docstring says why each choice was made; `stage.run` is the stage around it."""
