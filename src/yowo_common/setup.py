from setuptools import find_packages, setup

setup(
    name="yowo_common",
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/yowo_common"]),
        ("share/yowo_common", ["package.xml"]),
    ],
    zip_safe=True,
    # Node executables (ros2 run yowo_common <node>) and command-line tools.
    entry_points={"console_scripts": []},
)
