"""ROS message decoding and bag access for the `rosbag` loader (terra.datasets.rosbag).

Pure NumPy/Pillow decoders for the wire messages (PointCloud2, Image, CompressedImage,
CameraInfo, TF), a TF tree with time interpolation, and a time-indexed bag reader on top of the
`rosbags` package (ROS 1 .bag, ROS 2 sqlite3 and mcap), so no ROS installation is needed.
"""
