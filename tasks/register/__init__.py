"""The register stage (thesis 3.1.3, 3.2): a room's frames placed in one metric room frame by SfM and scale,
or by the foot-mounted IMU track and the coarse plan, and fused into a coloured room cloud. `stage.run` is
the entry; `config` holds its settings (and those of sfm and scale) and imports nothing but the standard
library."""
