from setuptools import find_packages, setup

PACKAGE = "beams_tools"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="BeAMS ROS maintainers",
    maintainer_email="maintainers@beams-ros.org",
    description=(
        "The tools of the BeAMS suite: the offline bag replay, bag and trajectory tooling, the node "
        "reference's generator and the fault campaign."
    ),
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "fault_campaign = beams_tools.campaign_command:main",
            "fault_relay_node = beams_tools.fault_relay_node:main",
            "replay_bag = beams_tools.bag_replay:main",
        ]
    },
)
