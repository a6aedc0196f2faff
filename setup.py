"""The compiled pieces, optional: where they do not build (no C compiler), the package
installs without them and reads logs with the numpy scans they replace (same results,
slower; see ``mavsid.readers.dataflash_scan.find_headers``), and filters with
``scipy.signal.lfilter`` (``mavsid.numerics.filters.lfilter``). Everything else is in
pyproject.toml."""

from setuptools import Extension, setup

setup(ext_modules=[Extension("mavsid.readers._scan", ["mavsid/readers/_scan.c"],
                             optional=True),
                   Extension("mavsid._filter", ["mavsid/_filter.c"], optional=True)])
