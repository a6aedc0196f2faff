"""Numerical building blocks mavsid's stages share, each in one place with its reference test.

- :mod:`mavsid.numerics.rotations`: ZYX Euler angles and Hamilton quaternions.
- :mod:`mavsid.numerics.stats`: the chi-square tail, the Newey-West (Bartlett) sum.

Nothing is imported here: ``import mavsid.numerics.stats`` loads only what it needs.
"""
