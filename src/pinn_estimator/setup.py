"""ament_python package pinn_estimator: valid for colcon/ros2 run and for pip."""
from glob import glob

from setuptools import find_packages, setup

package_name = "pinn_estimator"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    package_data={package_name: ["*.yaml", "models/*"]},
    include_package_data=True,
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="insitu-soil maintainers",
    maintainer_email="maintainers@insitu-soil.invalid",
    description="Physics-infused neural network soil-property estimator: model, loss, dataset, offline trainer, evaluation with its baselines, shipped models, online core and node.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "pinn_train = pinn_estimator.entry_points:pinn_train",
            "pinn_eval = pinn_estimator.entry_points:pinn_eval",
            "pinn_fusion_calibrate = pinn_estimator.entry_points:pinn_fusion_calibrate",
            "pinn_estimator = pinn_estimator.node:main",
        ],
    },
)
