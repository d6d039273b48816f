from glob import glob

from setuptools import find_packages, setup

package_name = "densecalib_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml") + glob("config/*.xml")),
        ("share/" + package_name + "/launch", glob("launch/*.launch.xml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="densecalib_ros maintainers",
    maintainer_email="densecalib@example.org",
    description="Target-free multi-camera rig calibration from dense matches (ROS 2 node, CLI, library)",
    license="BSD-3-Clause",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "densecalib = densecalib_ros.cli:main",
            "densecalib_node = densecalib_ros.ros.main:main",
        ],
    },
)
