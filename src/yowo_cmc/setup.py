from setuptools import find_packages, setup

setup(
    name="yowo_cmc",
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/yowo_cmc"]),
        ("share/yowo_cmc", ["package.xml"]),
    ],
    zip_safe=True,
    # Node executables (ros2 run yowo_cmc <node>) and command-line tools.
    entry_points={
        "console_scripts": [
            "keypoint_tracker_node = yowo_cmc.keypoint_tracker_node:main",
            "group_sfm_node = yowo_cmc.group_sfm_node:main",
        ]
    },
)
