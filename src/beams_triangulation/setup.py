from glob import glob

from setuptools import find_packages, setup

PACKAGE = "beams_triangulation"

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
    description="ToTal triangulation (thesis ch. 6) with 1/|D| gating and pose covariance.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "triangulation_node = beams_triangulation.triangulation_node:main",
            "error_map = beams_triangulation.error_map:main",
        ],
    },
)
