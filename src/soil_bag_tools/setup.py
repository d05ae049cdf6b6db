"""ament_python package soil_bag_tools: valid for colcon/ros2 run and for pip."""
from glob import glob

from setuptools import find_packages, setup

package_name = "soil_bag_tools"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    package_data={package_name: ["*.yaml"]},
    include_package_data=True,
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="insitu-soil maintainers",
    maintainer_email="maintainers@insitu-soil.invalid",
    description="rosbag2 MCAP episode bags: reading and writing, the crash-safe recorder (journal + repair) and the player.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "soil_bag_record = soil_bag_tools.record_node:main",
            "soil_bag_play = soil_bag_tools.play_node:main",
            "soil_bag_repair = soil_bag_tools.entry_points:soil_bag_repair",
        ],
    },
)
