import os
import subprocess
import sys
from glob import glob

from setuptools import find_packages, setup
from setuptools.command.install import install

PACKAGE = "regor_ros"


class InstallAndCompileKernels(install):
    """colcon build (setup.py install): compile the numba kernels into the installed package's
    cache, so that a user's first start only loads them. A build machine without numba still
    installs (the first start compiles)."""

    def run(self):
        super().run()
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [self.install_lib,
                                                                      os.environ.get("PYTHONPATH")]))}
        done = subprocess.run([sys.executable, "-c", "from regor_ros.core import warm_up; warm_up()"],
                              cwd="/", env=env, capture_output=True, text=True)
        if done.returncode != 0:
            print(f"regor_ros: kernels not compiled at install (the first start will): {done.stderr[-300:]}")


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={"regor_ros.core": ["__init__.pyi"]},   # the core's public face, typed (public_stub)
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
    cmdclass={"install": InstallAndCompileKernels},
    entry_points={
        "console_scripts": [
            "register_node = regor_ros.ros.run:main",
            "regor-pair-client = regor_ros.tools.pair_client:main",
            "regor-relocalize = regor_ros.tools.relocalize_client:main",
            "regor-bench = regor_ros.bench.cli:main",
            "regor-register = regor_ros.tools.register_cli:main",
            "regor-verify = regor_ros.tools.verify_cli:main",
            "regor-replay = regor_ros.tools.replay:main",
            "regor-batch = regor_ros.tools.batch:main",
            "regor-calibrate-gate = regor_ros.bench.calibrate_gate:main",
        ],
    },
)
