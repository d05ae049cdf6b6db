"""ament_python package soil_msgs_py: valid for colcon/ros2 run and for pip."""
from glob import glob

from setuptools import find_packages, setup

package_name = "soil_msgs_py"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    package_data={package_name: ["*.yaml", "data/*"]},
    include_package_data=True,
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="insitu-soil maintainers",
    maintainer_email="maintainers@insitu-soil.invalid",
    description="Shared vocabulary of insitu-soil: soil parameter vector (paper Table 1), the FEE (one implementation for NumPy and torch), soil catalogue, topic names, QoS, message layouts and rosbag2 MCAP bag I/O.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "soil_bag_record = soil_msgs_py.record_node:main",
            "soil_bag_play = soil_msgs_py.play_node:main",
            "soil_bag_repair = soil_msgs_py.repair:main",
        ],
    },
)
