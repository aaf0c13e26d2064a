"""ROS adapters: message conversion, the nodes, and the graph runner of `ntcr-recon run` (graph.py)."""
