"""LiDAR odometry when a log has no poses: KISS-ICP over the scans (terra.odometry.kiss), the
trajectory in KITTI and TUM formats (terra.odometry.trajectory), and its error against ground
truth when the source has it (terra.odometry.metrics)."""
