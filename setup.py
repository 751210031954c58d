"""The package list, which pyproject.toml cannot express: every package found under vecu/ plus
vecu.dbc, whose files live in the top-level dbc/ (pyproject.toml's package-dir maps it there)."""

from setuptools import find_namespace_packages, setup

setup(packages=[*find_namespace_packages(include=["vecu", "vecu.*"]), "vecu.dbc"])
