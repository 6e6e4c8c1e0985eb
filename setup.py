"""Package layout and the C reference core extension (the rest of the metadata is in pyproject.toml).

``drivers/`` is installed as the subpackage ``ins_hil.drivers`` (ARCHITECTURE.md),
for regular and editable installs alike. ``firmware_ref/cffi_build.py`` compiles the
C99 reference core (firmware_ref/src) into ``ins_hil._cref`` (double) and
``ins_hil._cref_f32`` (float) with cffi in API mode, at every install.
"""

from setuptools import find_packages, setup

packages = find_packages(include=["ins_hil", "ins_hil.*"])
packages += ["ins_hil.drivers"] + [f"ins_hil.drivers.{p}" for p in find_packages("drivers")]

setup(
    packages=packages,
    package_dir={"ins_hil": "ins_hil", "ins_hil.drivers": "drivers"},
    cffi_modules=["firmware_ref/cffi_build.py:ffi_double", "firmware_ref/cffi_build.py:ffi_float"],
)
