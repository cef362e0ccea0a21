from glob import glob

from setuptools import find_packages, setup

PACKAGE = "regor_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        (f"share/{PACKAGE}/rviz", glob("rviz/*.rviz")),
        (f"share/{PACKAGE}/demo", glob("demo/*")),
    ],
    install_requires=["setuptools", "numpy", "scipy", "numba", "threadpoolctl", "open3d"],
    zip_safe=True,
    maintainer="regor_ros developers",
    maintainer_email="regor_ros@example.com",
    description="Global point cloud registration (Regor, CVPR 2025) as a ROS 2 node",
    license="MIT",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "register_node = regor_ros.ros.node:main",
            "regor-pair-client = regor_ros.tools.pair_client:main",
            "regor-relocalize = regor_ros.tools.relocalize_client:main",
            "regor-bench = regor_ros.tools.benchmark:main",
            "regor-register = regor_ros.tools.register_cli:main",
            "regor-batch = regor_ros.tools.batch:main",
            "regor-calibrate-gate = regor_ros.tools.calibrate_gate:main",
        ],
    },
)
