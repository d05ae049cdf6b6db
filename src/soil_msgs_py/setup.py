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
    package_data={package_name: ["*.yaml", "*.xml"]},
    include_package_data=True,
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="insitu-soil maintainers",
    maintainer_email="maintainers@insitu-soil.invalid",
    description="The graph contract of insitu-soil: the soil parameter vector and Table 1 bounds, topic names, QoS and /sim/status events, labelled message layouts, episode metadata, rclpy glue and the one stamp joiner every node uses.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
        ],
    },
)
