"""The calibrate stage (thesis 3.1.2, 3.1.3, 6.1): the survey's RGB-D sensor calibration from target images,
else the sensor profile's values. `stage.run` is the entry; `config` holds its settings and imports nothing
but the standard library; the camera model itself is `tasks.camera`."""
