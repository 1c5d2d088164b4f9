from glob import glob

from setuptools import find_packages, setup

PACKAGE = "beams_sim"

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
        "The simulated world: a robot on the Eurobot table with drifting wheel odometry, offline "
        "simulated matches, sim_world_node, the virtual turret (the turret firmware in simavr)."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "sim_world_node = beams_sim.sim_world_node:main",
            "virtual_turret = beams_sim.virtual_turret_command:main",
        ],
        "beams_driver.edge_sources": ["sim = beams_sim.sim_source:EDGE_SOURCE"],
    },
)
