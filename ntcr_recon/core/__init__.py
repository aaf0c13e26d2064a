"""ROS-free core library, in layers, lowest first: base, robot, config, cloud, relocation, quality, reconstruction
(a layer imports only those below it; test/test_layers.py asserts it). Nothing under this package may import a
ROS module."""
