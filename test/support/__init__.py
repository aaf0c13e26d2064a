"""The tests' helpers, in one place: every test imports them from here (`from support import tiny_rig`; test/ is
on sys.path as the folder of the rootdir conftest.py). REPO and BAGS: the checkout and its sample bags."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / "bags"
# the console script of each node (setup.py), as `ros2 run ntcr_recon <node>` and the launch files start them
NODE_EXECUTABLES = ("transform_node", "camera_node", "fusion_node", "filter_node", "relocation_node", "mesh_node")
