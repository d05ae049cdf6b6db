"""ament_python package soil_bringup: valid for colcon/ros2 run and for pip."""
from glob import glob

from setuptools import find_packages, setup

package_name = "soil_bringup"

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
    description="Composition: the soil_launch launcher and the main-job demo (launch, live monitor, scoring from the bags, report).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "soil_launch = soil_bringup.entry_points:soil_launch",
            "soil_demo = soil_bringup.entry_points:soil_demo",
            "soil_cut_report = soil_bringup.entry_points:soil_cut_report",
        ],
    },
)
