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
    description="The fault campaign of the BeAMS suite (issue 18): seeded faults against the running system.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "fault_campaign = beams_tools.campaign_command:main",
            "fault_relay_node = beams_tools.fault_relay_node:main",
        ]
    },
)
