from setuptools import find_packages, setup

PACKAGE = "beams_thesis"

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
    description="The thesis's reproductions and the offline evaluations of the BeAMS suite.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "simulate_thesis_dataset = beams_thesis.thesis_setup:entry_point",
            "variance_plot = beams_thesis.variance_plot:main",
        ]
    },
)
