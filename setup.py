"""ament_python build script for ompn_ros (works with colcon and with plain pip)."""

from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "ompn_ros"
# The shipped checkpoints (ompn_ros/checkpoints/<name>/*.json, *.safetensors) are package data of their
# own directories; naming those as packages keeps setuptools from warning that they are left out.
CHECKPOINTS = sorted(f"{PACKAGE}.checkpoints.{Path(d).name}" for d in glob(f"{PACKAGE}/checkpoints/*/"))

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=["ompn_ros", "ompn_ros.*", "sim_nodes", "sim_nodes.*"]) + CHECKPOINTS,
    package_data={name: ["*.json", "*.safetensors"] for name in CHECKPOINTS},
    include_package_data=True,
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml") + glob("config/*.xml"))),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.py"))),
    ],
    python_requires=">=3.10",
    install_requires=[
        "numpy>=1.26",
        "numba>=0.60",  # the compiled streaming step (ompn_ros/model/_jit_stream.py)
        "scipy>=1.10",  # BLAS for numba's np.dot
        "PyYAML>=6",
        "torch>=2.4,<3",
        "llvmlite>=0.43",  # imported directly by the numba step
        "safetensors>=0.4",
        "rosbags>=0.11.9,<0.12",
        "ruamel.yaml.clib>=0.2.7",  # the C parser for rosbags' metadata.yaml reading (else pure Python)
        "mcap>=1.2",  # damaged-bag salvage in the bag reader
        "gymnasium>=1.0",
        "mujoco>=3.2",
        "dm_control>=1.0.20",
        "tqdm>=4.60",
        "matplotlib>=3.8",
        "pillow>=10",
        "tensorboard>=2.15",  # optional TensorBoard scalars (train.tensorboard: true)
    ],
    extras_require={"test": ["pytest>=8", "pytest-timeout", "hypothesis>=6", "mcap-ros2-support>=0.5"]},
    zip_safe=False,
    maintainer="ompn_ros maintainers",
    maintainer_email="maintainers@ompn-ros.invalid",
    description="Online subtask segmentation with the Ordered Memory Policy Network for ROS 2 Jazzy",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "ompn_node = ompn_ros.nodes.ompn_node:main",
            "bag_recorder = ompn_ros.nodes.bag_recorder:main",
            "smoke_talker = ompn_ros.nodes.dds_probe:talker_main",
            "smoke_listener = ompn_ros.nodes.dds_probe:listener_main",
            "craft_sim = sim_nodes.craft.node:main",
            "dial_sim = sim_nodes.dial.node:main",
            "ompn_train = ompn_ros.cli.train:main",
            "ompn_collect = ompn_ros.cli.collect:main",
            "ompn_segment = ompn_ros.cli.segment:main",
            "ompn_ensemble = ompn_ros.cli.ensemble:main",
            "ompn_closed_loop = ompn_ros.cli.closed_loop:main",
            "episode_monitor = ompn_ros.nodes.episode_monitor:main",
        ],
    },
)
