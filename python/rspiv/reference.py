"""DNS reference profiles of a zero-pressure-gradient turbulent boundary layer.

The data are those of Schlatter & Örlü (2010), J. Fluid Mech. 659, 116-126, released by KTH
Mechanics; four stations (Re_theta = 1000, 2000, 3030, 4060) are vendored with the package in
``rspiv/data/dns`` (see the README there) and read with :mod:`importlib.resources`, so they are
found from an installed wheel.

All profile quantities are in wall units (``+``): ``y+ = y u_tau / nu``, ``U+ = U / u_tau``,
``uu+ = <u'u'> / u_tau^2``. ``uv_plus`` is negative in a boundary layer (the Reynolds shear
stress is ``-uv+``).
"""

from __future__ import annotations

import dataclasses
import functools
from importlib import resources

import numpy as np

from rspiv.errors import InvalidInputError

_FILES = {
    1000: "schlatter_orlu_2010_retheta1000.prof",
    2000: "schlatter_orlu_2010_retheta2000.prof",
    3030: "schlatter_orlu_2010_retheta3030.prof",
    4060: "schlatter_orlu_2010_retheta4060.txt",
}

#: Nominal Re_theta of the vendored stations, ascending.
AVAILABLE_RE_THETA: tuple[int, ...] = tuple(sorted(_FILES))

CITATION = (
    "P. Schlatter and R. Örlü (2010), Assessment of direct numerical simulation data of "
    "turbulent boundary layers, J. Fluid Mech. 659, 116-126 (data: KTH Mechanics)"
)


@dataclasses.dataclass(frozen=True)
class DNSProfile:
    """One wall-normal DNS profile in wall units.

    Attributes
    ----------
    re_theta, re_tau : float
        Momentum-thickness and friction Reynolds numbers of the station (``re_tau`` = delta99+).
    y_delta99, y_plus, u_plus, urms_plus, vrms_plus, wrms_plus, uv_plus : ndarray
        Columns of the file (``uv_plus`` < 0).
    skewness_u, flatness_u : ndarray
        Skewness ``S(u)`` and flatness ``F(u)`` of the streamwise fluctuations (columns 11, 12;
        the values at the wall itself, ``y+ = 0``, are the DNS's limits, not a measurement).
    dudy_plus, omzrms_plus : ndarray
        The mean shear ``dU+/dy+`` and the spanwise vorticity's rms ``omega_z,rms nu / u_tau^2``
        (columns 13 and 17).
    re_delta_star, h12, cf : float or None
        Integral quantities stated in the file header (only the ``.txt`` station has them).
    source : str
        File name inside ``rspiv/data/dns``.
    """

    re_theta: float
    re_tau: float
    y_delta99: np.ndarray
    y_plus: np.ndarray
    u_plus: np.ndarray
    urms_plus: np.ndarray
    vrms_plus: np.ndarray
    wrms_plus: np.ndarray
    uv_plus: np.ndarray
    skewness_u: np.ndarray
    flatness_u: np.ndarray
    dudy_plus: np.ndarray
    omzrms_plus: np.ndarray
    re_delta_star: float | None
    h12: float | None
    cf: float | None
    source: str

    @property
    def uu_plus(self) -> np.ndarray:
        """Streamwise Reynolds normal stress ``<u'u'>+``."""
        return self.urms_plus**2

    @property
    def vv_plus(self) -> np.ndarray:
        """Wall-normal Reynolds normal stress ``<v'v'>+``."""
        return self.vrms_plus**2

    @property
    def u_inf_plus(self) -> float:
        """Free-stream velocity in wall units (the value at the top of the domain)."""
        return float(self.u_plus[-1])

    def label(self) -> str:
        """Legend label, e.g. ``"DNS Re_theta=4061 (Schlatter & Örlü 2010)"``."""
        return f"DNS Re_theta={self.re_theta:.0f} (Schlatter & Örlü 2010)"


def _parse(name: str, text: str) -> DNSProfile:
    header: dict[str, float] = {}
    rows: list[list[float]] = []
    first_plain: list[float] | None = None
    for line in text.splitlines():
        s = line.strip()
        if not s:
            continue
        if s.startswith("%"):
            body = s.lstrip("%").strip()
            if "=" in body:
                key, _, val = body.partition("=")
                key = key.strip().replace("\\", "").replace("{", "").replace("}", "")
                try:
                    header[key.strip()] = float(val)
                except ValueError:
                    pass
            continue
        vals = [float(t) for t in s.split()]
        if len(vals) == 2 and first_plain is None and not rows:
            first_plain = vals
            continue
        if len(vals) != 17:
            raise InvalidInputError(f"{name}: expected 17 columns, got {len(vals)}")
        rows.append(vals)
    data = np.asarray(rows, dtype=np.float64)
    if first_plain is not None:
        re_tau, re_theta = first_plain
    else:
        try:
            re_tau, re_theta = header["Re_tau"], header["Re_theta"]
        except KeyError as exc:
            raise InvalidInputError(f"{name}: no Re_tau/Re_theta in the header") from exc
    return DNSProfile(
        re_theta=float(re_theta),
        re_tau=float(re_tau),
        y_delta99=data[:, 0],
        y_plus=data[:, 1],
        u_plus=data[:, 2],
        urms_plus=data[:, 3],
        vrms_plus=data[:, 4],
        wrms_plus=data[:, 5],
        uv_plus=data[:, 6],
        skewness_u=data[:, 10],
        flatness_u=data[:, 11],
        dudy_plus=data[:, 12],
        omzrms_plus=data[:, 16],
        re_delta_star=header.get("Re_delta^*"),
        h12=header.get("H_12"),
        cf=header.get("c_f"),
        source=name,
    )


@functools.lru_cache(maxsize=8)
def _load_file(name: str) -> DNSProfile:
    path = resources.files("rspiv").joinpath("data").joinpath("dns").joinpath(name)
    return _parse(name, path.read_text(encoding="utf-8"))


def load_dns(re_theta: float = 4060) -> DNSProfile:
    """Load the vendored DNS station whose nominal Re_theta is nearest to ``re_theta``.

    Parameters
    ----------
    re_theta : float
        Wanted momentum-thickness Reynolds number; one of :data:`AVAILABLE_RE_THETA` or a value
        within 10 % of one of them.

    Returns
    -------
    DNSProfile

    Raises
    ------
    InvalidInputError
        If no station lies within 10 % of ``re_theta``.
    """
    key = min(AVAILABLE_RE_THETA, key=lambda r: abs(r - float(re_theta)))
    if not np.isfinite(re_theta) or abs(key - re_theta) > 0.1 * key:
        raise InvalidInputError(
            f"re_theta: no DNS station near {re_theta!r}; available {list(AVAILABLE_RE_THETA)}"
        )
    return _load_file(_FILES[key])


def all_dns() -> list[DNSProfile]:
    """All vendored stations, ascending in Reynolds number."""
    return [_load_file(_FILES[k]) for k in AVAILABLE_RE_THETA]


def dns_profile_for_re_tau(re_tau: float) -> DNSProfile:
    """The vendored station closest to ``re_tau`` (nearest in ``log Re_tau``).

    No interpolation between stations is done: the outer-layer profiles do not scale with one
    variable, and an interpolated profile would be no DNS result. Above the highest station
    (Re_tau = 1271.5) the highest is returned; the inner layer (y+ < ~0.1 Re_tau) is what a
    comparison at higher Re_tau should rely on.
    """
    if not np.isfinite(re_tau) or re_tau <= 0:
        raise InvalidInputError(f"re_tau: must be a positive number, got {re_tau!r}")
    profs = all_dns()
    return min(profs, key=lambda p: abs(np.log(p.re_tau) - np.log(re_tau)))


__all__ = [
    "AVAILABLE_RE_THETA",
    "CITATION",
    "DNSProfile",
    "all_dns",
    "dns_profile_for_re_tau",
    "load_dns",
]
