from setuptools import find_packages, setup

setup(
    name="yowo_sim",
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/yowo_sim"]),
        ("share/yowo_sim", ["package.xml"]),
    ],
    zip_safe=True,
    # Verbs of the `yowo` command line (found by yowo_bringup.plugins).
    entry_points={"yowo.verbs": ["yowo_sim = yowo_sim.verbs:add_verbs"]},
)
