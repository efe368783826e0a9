from setuptools import find_packages, setup

setup(
    name="yowo_eval",
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/yowo_eval"]),
        ("share/yowo_eval", ["package.xml"]),
    ],
    zip_safe=True,
    # Found by yowo_bringup.plugins: the runtime never imports this package by name.
    entry_points={
        "yowo.verbs": ["yowo_eval = yowo_eval.plugin:add_verbs"],
        "yowo.evaluator": ["yowo_eval = yowo_eval.plugin"],
        "console_scripts": ["yowo_ego_bench = yowo_eval.ego_bench:main"],
    },
)
