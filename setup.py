"""Packages found at build time (pyproject.toml holds the metadata): every ``windbench``
package, plus ``windbench.conf`` built from ``conf/``, so that an installed wheel carries
the configs while a checkout keeps them where users edit them."""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["windbench", "windbench.*"]), "windbench.conf"],
    package_dir={"windbench.conf": "conf"},
    package_data={
        "windbench.conf": ["*.yaml", "*/*.yaml", "*/*/*.yaml", "mesh/*.ply", "mesh/*.obj"]
    },
)
