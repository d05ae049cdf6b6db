"""ament_python package soil_planner: valid for colcon/ros2 run and for pip."""
from glob import glob

from setuptools import find_packages, setup

package_name = "soil_planner"

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
    description="Planner example: the deepest cut within the machine's force limits from /soil/estimate (ROS-free core and thin rclpy node).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "soil_planner = soil_planner.node:main",
            "soil_planner_calibrate = soil_planner.entry_points:soil_planner_calibrate",
        ],
    },
)
