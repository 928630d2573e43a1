"""Type stubs of the native module ``rspiv._rspiv`` (the thin PyO3 binding).

Arrays are float64 unless stated; coordinates follow the pixel frame of the README (x = column,
y = row, origin at the centre of the top-left pixel, y down).
"""

import numpy as np
import numpy.typing as npt

__version__: str



