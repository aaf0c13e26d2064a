"""ROS-free input and output: PointCloud2 <-> arrays (rclpy and rosbags messages), rosbag2 bags, the camera
sources (bag, live D405, librealsense recording), files written whole or not at all and the paper's figures (PNG).
Nothing under this package imports rclpy or ntcr_recon.ros."""
