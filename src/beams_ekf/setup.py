from glob import glob

from setuptools import find_packages, setup

PACKAGE = "beams_ekf"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="BeAMS ROS maintainers",
    maintainer_email="maintainers@beams-ros.org",
    description="EKF (filterpy) fusing wheel odometry with every BeAMS bearing.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "ekf_node = beams_ekf.ekf_node:main",
        ],
    },
)
