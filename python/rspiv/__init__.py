"""rspiv: large-sensor PIV with lens-distortion correction.

Coordinates (everywhere, unless a name says otherwise): pixel frame with x = column, y = row,
origin at the centre of the top-left pixel, y growing downward; displacements follow the same
axes. "Object px" is the dewarped image's pixel frame. Flow outputs use x streamwise and y
wall-normal from the wall, in metres and wall units.
"""

from rspiv._rspiv import __version__
from rspiv.errors import ConvergenceError, InvalidInputError, RspivError

__all__ = ["__version__", "RspivError", "InvalidInputError", "ConvergenceError"]
