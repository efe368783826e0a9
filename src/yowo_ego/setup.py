from setuptools import find_packages, setup

setup(
    name="yowo_ego",
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/yowo_ego"]),
        ("share/yowo_ego", ["package.xml"]),
    ],
    zip_safe=True,
    # Node executables (ros2 run yowo_ego <node>) and command-line tools.
    entry_points={
        "console_scripts": [
            "ego_mapper_node = yowo_ego.ego_mapper_node:main",
        ]
    },
)
