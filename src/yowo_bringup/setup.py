from setuptools import find_packages, setup

setup(
    name="yowo_bringup",
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={"yowo_bringup": ["config/*.xml", "config/*.yaml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/yowo_bringup"]),
        ("share/yowo_bringup", ["package.xml"]),
        ("share/yowo_bringup/launch", ["launch/yowo.launch.py"]),
        ("share/yowo_bringup/config", ["yowo_bringup/config/yowo.yaml"]),
    ],
    zip_safe=True,
    # Node executables (ros2 run yowo_bringup <node>) and command-line tools.
    entry_points={
        "console_scripts": [
            "yowo = yowo_bringup.cli:main",
            "replay_node = yowo_bringup.replay_node:main",
        ]
    },
)
