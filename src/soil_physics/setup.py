"""ament_python package soil_physics: valid for colcon/ros2 run and for pip."""
from glob import glob

from setuptools import find_packages, setup

package_name = "soil_physics"

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
    description="Soil-tool physics without ROS: the fundamental earthmoving equation (one implementation for NumPy and torch), the soil catalogue, the one vocabulary of force terms the FEE lacks (shared by the simulator's effects and the discrepancy catalogue), the augmented FEE and the blade's travel in soil.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
        ],
    },
)
