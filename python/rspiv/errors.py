"""Exceptions and warnings raised by rspiv.

Every error derives from :class:`RspivError`.

- :class:`InvalidInputError` (also a :class:`ValueError`): input that rspiv cannot use: wrong
  shape, NaN or inf, too few points, degenerate geometry, a corrupt or foreign file.
- :class:`ConvergenceError` (also an :class:`ArithmeticError`): an iterative method (the inverse
  map, a fit) did not converge where the caller required it to.

- :class:`CorrelationWarning` (a :class:`UserWarning`): a PIV field whose frames do not
  correlate (:meth:`rspiv.PivField.warning`): as a whole (its vectors are no measurement,
  :meth:`rspiv.PivField.uncorrelated`) or in a part where they hardly do.

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


__all__ = ["RspivError", "InvalidInputError", "ConvergenceError", "CorrelationWarning"]
