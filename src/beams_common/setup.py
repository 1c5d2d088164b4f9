from setuptools import find_packages, setup

PACKAGE = "beams_common"

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
        "Shared concepts of the BeAMS suite by sub-package: geometry, intake (input checks), status, "
        "calibration (file, schema, checks, corrections), config (parameter specs), interfaces (topics, "
        "message builders); beams_common.ros: node runner, hot standby, diagnostics, conversions."
    ),
    license="Apache-2.0",
    entry_points={"console_scripts": []},
)
