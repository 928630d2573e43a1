"""Exceptions and warnings raised by rspiv.

Every error derives from :class:`RspivError`.

- :class:`InvalidInputError` (also a :class:`ValueError`): input that rspiv cannot use: wrong
  shape, NaN or inf, too few points, degenerate geometry, a corrupt or foreign file.
- :class:`ConvergenceError` (also an :class:`ArithmeticError`): an iterative method (the inverse
  map, a fit) did not converge where the caller required it to.

- :class:`CorrelationWarning` (a :class:`UserWarning`): a PIV field whose frames do not
  correlate (:meth:`rspiv.PivField.warning`): as a whole (its vectors are no measurement,
  :meth:`rspiv.PivField.uncorrelated`) or in a part where they hardly do.
- :class:`ParticleSizeWarning` (a :class:`UserWarning`): particle images too small for a
  sub-pixel fit (:meth:`rspiv.PivField.peak_locking`: the displacements lean towards whole
  pixels), or for the preprocessing's hot-pixel rule.

The native module raises these very classes (it looks them up here), so ``except
rspiv.InvalidInputError`` catches errors from Rust and from Python alike.
"""

from __future__ import annotations


class RspivError(Exception):
    """Base class of every rspiv error."""


class InvalidInputError(RspivError, ValueError):
    """Input that rspiv cannot use; the message names the input and the problem."""


class ConvergenceError(RspivError, ArithmeticError):
    """An iterative method did not converge; the message says where."""


class CorrelationWarning(UserWarning):
    """A PIV field whose frames do not correlate, as a whole (wrong pairing, missing laser
    pulse, noise) or in a part where they hardly do: :meth:`rspiv.PivField.warning` says
    what was seen. ``warnings.simplefilter("error", rspiv.CorrelationWarning)`` turns it into
    an error."""


class ParticleSizeWarning(UserWarning):
    """Particle images under 2 px across (:attr:`rspiv.PivField.particle_diameter`): every
    sub-pixel displacement leans towards whole pixels (peak locking), a bias that neither the
    per-vector uncertainty nor averaging removes (:meth:`rspiv.PivField.peak_locking`), and
    the preprocessing's hot-pixel rule takes their brightest pixels for sensor defects
    (:func:`rspiv.particle_size.warnings_for`). ``warnings.simplefilter("error",
    rspiv.ParticleSizeWarning)`` turns it into an error."""


__all__ = [
    "RspivError",
    "InvalidInputError",
    "ConvergenceError",
    "CorrelationWarning",
    "ParticleSizeWarning",
]
