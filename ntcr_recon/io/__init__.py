"""ROS-free input and output: PointCloud2 <-> arrays (rclpy and rosbags messages), rosbag2 bags, the camera
sources (bag, live D405, librealsense recording) and files written whole or not at all. Nothing under this
package imports rclpy or ntcr_recon.ros."""
