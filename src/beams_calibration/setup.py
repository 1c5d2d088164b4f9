from glob import glob

from setuptools import find_packages, setup

PACKAGE = "beams_calibration"

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
    description=(
        "Chapter-7 calibration of BeAMS as ROS services: power bias, rotation bias, turret offset, beacons."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "calibration_node = beams_calibration.calibration_node:main",
            "calibrate = beams_calibration.calibrate_command:main",
            "calibration_session = beams_calibration.session_command:main",
        ],
    },
)
