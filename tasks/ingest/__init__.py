"""Ingest (thesis 3.1): read a room capture into the pipeline's own artefacts.

Captures come in these shapes, each behind a reader:
- an MCAP recording of ROS 2 messages (sensor_msgs/Image, CompressedImage, CameraInfo, Imu and
  geometry_msgs/PoseStamped), decoded without a ROS install; topic names from the sensor profile
  (`mcap_reader`);
- a TUM RGB-D folder (rgb.txt, depth.txt, associated by timestamp) or a 7-Scenes folder
  (frame-XXXXXX.color.jpg / .depth.png / .pose.txt) (`folders`);
- a registered room cloud: PLY or PCD (metres) as it is (`clouds`), or what laser scanners export, E57
  (several setups merged by their poses) and LAS / LAZ (national-grid offsets moved to a local origin),
  voxel-reduced while streamed in (`scanners`, `e57_reader`, `las_reader`, `voxels`).

RGB-D captures become `frames.parquet` (one row per depth frame with its nearest colour image, depth as a
lossless 16-bit PNG) plus `camera_info.json`, and, when the capture has them, `imu.parquet` and
`device_poses.parquet` (`frames`). Frames are streamed: memory does not grow with the recording's length.

`capture` tells the kind of a capture and dispatches to its reader; `stage` is the pipeline's entry point;
`config` holds the stage's settings and imports nothing but the standard library.
"""
