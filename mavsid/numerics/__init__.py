"""Numerical building blocks mavsid's stages share, each in one place with its reference test.

- :mod:`mavsid.numerics.filters`: the difference equation (its recursion compiled as
  ``mavsid._filter``, scipy's banded solve without it), Butterworth and the autopilots'
  second-order low-pass.
- :mod:`mavsid.numerics.spectra`: Welch spectra with the windows' transforms reused.
- :mod:`mavsid.numerics.lti`: zero-order hold and its inverse (``c2d``, ``d2c``), ``tf2ss``,
  the matrix exponential and logarithm.
- :mod:`mavsid.numerics.rotations`: ZYX Euler angles and Hamilton quaternions.
- :mod:`mavsid.numerics.stats`: the chi-square tail, the Newey-West (Bartlett) sum.

Nothing is imported here: ``import mavsid.numerics.stats`` loads only what it needs.
"""
