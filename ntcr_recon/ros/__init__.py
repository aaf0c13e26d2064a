"""ROS adapters: message conversion, the nodes and the replay."""
