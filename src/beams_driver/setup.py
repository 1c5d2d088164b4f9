from glob import glob

from setuptools import find_packages, setup

PACKAGE = "beams_driver"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="BeAMS ROS maintainers",
    maintainer_email="maintainers@beams-ros.org",
    description=(
        "The BeAMS sensor: codes, exact variance, decoder, edge sources (serial, or a plugin), driver_node."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "driver_node = beams_driver.driver_node:main",
            "estimate_noise = beams_driver.estimate_noise:main",
        ]
    },
)
