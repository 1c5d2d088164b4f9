from glob import glob

from setuptools import find_packages, setup

PACKAGE = "beams_bringup"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*")),
        (f"share/{PACKAGE}/launch", glob("launch/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="BeAMS ROS maintainers",
    maintainer_email="maintainers@beams-ros.org",
    description="Launch file, Fast DDS profile, parameter files and the demo of the BeAMS suite.",
    license="Apache-2.0",
    entry_points={"console_scripts": ["demo = beams_bringup.demo:main", "robot = beams_bringup.robot:main"]},
)
