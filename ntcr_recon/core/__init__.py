"""ROS-free core library: clouds, transforms, filters, fusion, reference model, relocation,
meshing and metrics. Nothing under this package may import a ROS module."""
