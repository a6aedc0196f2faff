"""The one compiled piece, optional: where it does not build (no C compiler), the package
installs without it and reads DataFlash logs with the numpy scan it replaces (same results,
slower; see ``mavsid.readers.dataflash._find_headers``). Everything else is in
pyproject.toml."""

from setuptools import Extension, setup

setup(ext_modules=[Extension("mavsid.readers._scan", ["mavsid/readers/_scan.c"],
                             optional=True)])
