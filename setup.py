"""ament_python package: `colcon build` on a rig, `pip install -e .` anywhere else."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "ntcr_recon"

# One console script per node, so `ros2 run ntcr_recon <node>` finds it under lib/ntcr_recon.
NODES = {
    "transform_node": "ntcr_recon.ros.transform_node:main",
    "camera_node": "ntcr_recon.ros.camera_node:main",
    "fusion_node": "ntcr_recon.ros.fusion_node:main",
    "filter_node": "ntcr_recon.ros.filter_node:main",
    "relocation_node": "ntcr_recon.ros.relocation_node:main",
    "mesh_node": "ntcr_recon.ros.mesh_node:main",
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "benchmarks"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.rviz")),
    ],
    install_requires=["setuptools"],
    python_requires=">=3.10",
    zip_safe=True,
    maintainer="ntcr_recon maintainers",
    maintainer_email="ntcr-recon@example.org",
    description="3-D morphological reconstruction of notched tubular continuum robots from two D405 cameras",
    license="Apache-2.0",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": ["ntcr-recon = ntcr_recon.cli:main"]
        + [f"{name} = {target}" for name, target in NODES.items()],
    },
)
