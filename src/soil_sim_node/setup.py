"""ament_python package soil_sim_node: valid for colcon/ros2 run and for pip."""
from glob import glob

from setuptools import find_packages, setup

package_name = "soil_sim_node"

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
    description="Planar soil and bladed-vehicle simulator (ROS-free core, thin rclpy node with its own pacing module), closed-loop rollout, batch dataset generator, episode plots and the phenomena report.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "soil_sim_batch = soil_sim_node.entry_points:soil_sim_batch",
            "soil_plot_episode = soil_sim_node.entry_points:soil_plot_episode",
            "soil_sim_report = soil_sim_node.entry_points:soil_sim_report",
            "soil_sim_node = soil_sim_node.node:main",
        ],
    },
)
