"""Package layout (the rest of the metadata is in pyproject.toml).

``drivers/`` is installed as the subpackage ``ins_hil.drivers`` (ARCHITECTURE.md),
for regular and editable installs alike.
"""

from setuptools import find_packages, setup

packages = find_packages(include=["ins_hil", "ins_hil.*"])
packages += ["ins_hil.drivers"] + [f"ins_hil.drivers.{p}" for p in find_packages("drivers")]

setup(
    packages=packages,
    package_dir={"ins_hil": "ins_hil", "ins_hil.drivers": "drivers"},
)
