"""ament_python package soil_discrepancy: valid for colcon/ros2 run and for pip."""
from glob import glob

from setuptools import find_packages, setup

package_name = "soil_discrepancy"

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
    description="Discrepancy workflow: find where the model and measured data disagree, name the missing effect, add it and show the gap shrink.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "soil_discrepancy = soil_discrepancy.entry_points:soil_discrepancy",
        ],
    },
)
