from setuptools import find_packages, setup

setup(
    name="yowo_fusion",
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/yowo_fusion"]),
        ("share/yowo_fusion", ["package.xml"]),
    ],
    zip_safe=True,
    # Node executables (ros2 run yowo_fusion <node>) and command-line tools.
    entry_points={
        "console_scripts": [
            "fusion_node = yowo_fusion.fusion_node:main",
        ]
    },
)
