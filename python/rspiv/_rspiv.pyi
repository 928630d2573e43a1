"""Type stubs of the native module ``rspiv._rspiv`` (the thin PyO3 binding).

Arrays are float64 unless stated; coordinates follow the pixel frame of the README (x = column,
y = row, origin at the centre of the top-left pixel, y down).
"""

import numpy as np
import numpy.typing as npt

__version__: str

# -- mapping models (crates/rspiv-py/src/mapping.rs) -----------------------------------------

class NativeMapping:
    """Native half of ``rspiv.Mapping`` (object px -> image px); immutable."""

    @property
    def model(self) -> str: ...
    @property
    def coefficients(self) -> npt.NDArray[np.float64]: ...
    @property
    def centre_object(self) -> tuple[float, float]: ...
    @property
    def centre_image(self) -> tuple[float, float]: ...
    @property
    def scale(self) -> float: ...
    @property
    def rotation(self) -> float: ...
    @property
    def residuals(self) -> npt.NDArray[np.float64]: ...
    @property
    def covariance(self) -> npt.NDArray[np.float64]: ...
    @property
    def stats(self) -> dict[str, object]: ...
    def forward(self, pts: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
    def forward_jacobian(self, pts: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]: ...
    def inverse(
        self, pts: npt.NDArray[np.float64]
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.bool_]]: ...
    def with_rotation(self, theta_rad: float) -> NativeMapping: ...
    def to_json(self) -> str: ...
    @staticmethod
    def from_json(text: str) -> NativeMapping: ...

def fit_mapping(
    object_px: npt.NDArray[np.float64],
    image_px: npt.NDArray[np.float64],
    model: str = "p3",
    center_index: int | None = None,
    scale: float | None = None,
) -> NativeMapping: ...
def bench_fit_normalized(
    model: str,
    obj_hat: npt.NDArray[np.float64],
    img_hat: npt.NDArray[np.float64],
    n_points: int,
    repeats: int = 1000,
    warm_start: list[float] | None = None,
) -> float:
    """Seconds per allocation-free refit (FitWorkspace), cycling over stacked data sets."""

# -- calibration (crates/rspiv-py/src/calibration.rs) ---------------------------------------------
def render_target(
    height: int,
    width: int,
    centres: npt.NDArray[np.float64],
    sigma_px: npt.NDArray[np.float64],
    amplitude: npt.NDArray[np.float64],
    background: float = 200.0,
    gradient: tuple[float, float] = (0.08, -0.05),
    vignetting: float = 0.15,
    gain: float = 0.5,
    read_noise: float = 4.0,
    full_scale: float = 4095.0,
    seed: int = 0,
    radius_px: npt.NDArray[np.float64] | None = None,
    plate: float = 0.0,
    sides: npt.NDArray[np.uint32] | None = None,
    orientation_rad: npt.NDArray[np.float64] | None = None,
) -> npt.NDArray[np.uint16]:
    """Render Gaussian dots (or, where ``radius_px > 0``, discs of that radius blurred by
    ``sigma_px``; where ``sides >= 3``, regular polygons of that circumradius with their first
    vertex at ``orientation_rad`` from +x) centred at ``centres`` (N, 2) image px on a plate of
    level ``plate`` under the illumination, with camera noise; negative amplitudes give dark
    dots."""

def detect_markers(
    image: npt.NDArray[np.generic],
    marker: str = "dot",
    size_px: float | None = None,
    threshold: float = 0.25,
    min_snr: float = 8.0,
    dark: bool | None = None,
    profile: str = "auto",
) -> dict[str, object]:
    """Markers of a target image (uint8/uint16/float32/float64): keys ``image_px`` (N, 2),
    ``cov_px2`` (N, 2, 2), ``amplitude``, ``width_px``, ``radius_px``, ``strength`` (N,),
    ``rejected_px`` (K, 2: blobs off the coarse lattice, reported at their coarse positions,
    not fitted),
    ``size_px``, ``downsample``, ``profile`` ("gaussian", "disc" or "cross"), ``dark`` (the
    polarity used) and, when size or polarity were surveyed, ``survey_lattice``,
    ``survey_detected``, ``survey_snr``."""

def index_grid(
    points_px: npt.NDArray[np.float64], centre: tuple[float, float], tol: float = 0.3
) -> tuple[
    npt.NDArray[np.int32], npt.NDArray[np.bool_], int, tuple[float, float], tuple[float, float]
]:
    """Grid index (N, 2), found mask (N,), origin row, grid steps a1 and a2 (px)."""

TOUCH_SHARE: float

def touching_share(
    image: npt.NDArray[np.generic],
    image_px: npt.NDArray[np.float64],
    index: npt.NDArray[np.float64],
    amplitude: npt.NDArray[np.float64],
    dark: bool,
) -> tuple[float, int] | None:
    """Median share of the segments between lattice neighbours (``index`` (N, 2): each point's
    site, NaN for none) as dark as the dots (``amplitude`` counts, ``dark`` polarity), and the
    number of pairs; None under 8 pairs. Above ``TOUCH_SHARE`` the dots touch: a checkerboard's
    squares (``dewarp_core::markers::touching_share``). InvalidInputError for mismatched shapes
    or an image of another dtype."""

def monte_carlo(
    object_px: npt.NDArray[np.float64],
    image_px: npt.NDArray[np.float64],
    model: str,
    n: int,
    sigma_image_px: float,
    sigma_object_px: float,
    centre_index: int,
    scale: float | None = None,
    seed: int = 0,
    hist_bins: int = 0,
    hist_half_range_px: float = 2.0,
    keep_samples: bool = False,
    threads: int | None = None,
) -> dict[str, object]:
    """Monte Carlo study: keys ``n_ok``, ``n_failed``, ``mean_px`` (M, 2), ``cov_px2`` (M, 2, 2),
    ``radius99_px``, ``within1``, ``within2`` (M,), ``nominal_px`` (M, 2), and ``hist``
    (M, bins, bins) / ``samples`` (n_ok, M, 2) float32 when asked."""

# -- remap / dewarp (crates/rspiv-py/src/remap.rs) -------------------------------------------

def dewarp_image(
    image: npt.NDArray[np.uint16] | npt.NDArray[np.float32],
    mapping: NativeMapping,
    out_shape: tuple[int, int] | None = None,
    sampling: str = "auto",
    tol: float = 1e-3,
    step: int = 16,
    fill: float = 0.0,
    out_dtype: str = "float32",
) -> npt.NDArray[np.float32] | npt.NDArray[np.uint16]:
    """``out[y, x] = image(F(x, y))`` with F the native mapping (object px -> image px),
    Keys bicubic (a = -0.5), ``fill`` outside the image. ``sampling``: "auto" (coarsest grid
    within ``tol`` px), "exact" (per pixel) or "grid" (every ``step`` px). ``out_dtype``:
    "float32" or "uint16" (rounded, clipped)."""

def remap_coords(
    image: npt.NDArray[np.uint16] | npt.NDArray[np.float32],
    map_x: npt.NDArray[np.float64] | npt.NDArray[np.float32],
    map_y: npt.NDArray[np.float64] | npt.NDArray[np.float32],
    fill: float = 0.0,
    out_dtype: str = "float32",
) -> npt.NDArray[np.float32] | npt.NDArray[np.uint16]:
    """Keys-bicubic remap at precomputed source positions ``(map_x, map_y)`` (image px); the
    maps' shape is the output shape."""

# --- piv-core (PIV engine; windows are (w, h): w px along x, h px along y) -------------------

# ``settings`` is the JSON of ``rspiv.PivSettings.to_json()`` (the one vocabulary, parsed by
# ``piv_core::PivSettings::from_json``).

def piv(
    frame_a: npt.NDArray[np.generic],
    frame_b: npt.NDArray[np.generic],
    settings: str,
    mask: npt.NDArray[np.bool_] | None = None,
) -> dict[str, object]:
    """Multipass PIV; frames uint8/uint16/float32/float64 of one dtype. Returns a dict with
    x, y, u, v, peak_ratio, coef, sigma_u, sigma_v (float64), valid, replaced, masked (bool),
    peak_choice (uint8), all (ny, nx), grid = (x0, y0, dx, dy) and particle_diameter = (dx, dy)
    px (the first pass's correlation peaks; NaN where not measured)."""

def piv_at(
    frame_a: npt.NDArray[np.generic],
    frame_b: npt.NDArray[np.generic],
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    windows: list[tuple[int, int]],
    settings: str,
    iterations: int = 1,
    predictor_u: npt.NDArray[np.float64] | None = None,
    predictor_v: npt.NDArray[np.float64] | None = None,
    field_grid: tuple[float, float, float, float] | None = None,
    field_u: npt.NDArray[np.float64] | None = None,
    field_v: npt.NDArray[np.float64] | None = None,
    mask: npt.NDArray[np.bool_] | None = None,
) -> dict[str, object]:
    """PIV at points x, y (one 2D shape) with per-point predictors (window offset) or a grid
    predictor field (deformation); ``windows`` and ``iterations`` are the passes at the points
    (the settings' passes and deformation are not used). Same dict as ``piv`` with
    grid = None."""

def piv_final_points(
    frame_a: npt.NDArray[np.generic],
    frame_b: npt.NDArray[np.generic],
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    settings: str,
    mask: npt.NDArray[np.bool_] | None = None,
) -> dict[str, object]:
    """Method II's PIV in one call on one prepared pair: all passes but the last as ``piv`` on
    the regular grid (the predictor), the last (its window and iterations) at the points x, y
    deformed ("symmetric") or offset ("offset") by that field. The final field's dict (as
    ``piv_at``) with the predictor's dict (as ``piv``; None for one pass) under "predictor"."""

# --- correction-core (crates/rspiv-py/src/correction.rs) -------------------------------------

def method_one(
    frame_a: npt.NDArray[np.generic],
    frame_b: npt.NDArray[np.generic],
    mapping: NativeMapping,
    settings: str,
    object_shape: tuple[int, int] | None = None,
    mask: npt.NDArray[np.bool_] | None = None,
    zero_fill: str = "mask",
) -> dict[str, object]:
    """Method I: both frames (and the mask) dewarped through ``mapping``, then ``piv``; the
    dict of ``piv`` in object px (zero fill masked with ``zero_fill="mask"``)."""

def method_two(
    frame_a: npt.NDArray[np.generic],
    frame_b: npt.NDArray[np.generic],
    mapping: NativeMapping,
    settings: str,
    mapping_mode: str = "full",
    object_shape: tuple[int, int] | None = None,
    mask: npt.NDArray[np.bool_] | None = None,
) -> dict[str, object]:
    """Method II: the predictor passes on the raw frames, the last pass at the images of the
    object grid, displacements mapped back ("full": exact inverse; "positions": as measured);
    the dict of ``piv`` on the object grid (object px)."""

def render_particles(
    height: int,
    width: int,
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    intensity: npt.NDArray[np.float64],
    diameter: npt.NDArray[np.float64],
    noise_sigma: float,
    max_count: int = 4095,
    seed: int = 0,
) -> npt.NDArray[np.uint16]:
    """Gaussian particles (e^-2 diameter, px; peak intensity, counts) integrated over the pixel
    area, plus Gaussian noise (counts), rounded and clipped to [0, max_count]. ``diameter`` holds
    one value or one per particle. Deterministic for a seed whatever the thread count."""

def object_grid(
    shape: tuple[int, int], settings: str
) -> tuple[tuple[float, float, float, float, int, int], tuple[int, int], tuple[int, int]]:
    """The grid ``(x0, y0, dx, dy, nx, ny)`` the last pass runs on, on a frame of ``shape``
    (rows, columns): the settings' ``roi`` and the rings around it when given; the
    ``(column, row)`` of the field's own grid in it, and its ``(nx, ny)``."""

def region_around(
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    settings: str,
    shape: tuple[int, int],
) -> tuple[int, int, int, int] | None:
    """The frames' region ``(x0, y0, x1, y1)`` holding the points and the settings' margin
    (``piv_core::roi_margin``), or None when no point is finite."""

def window_response(weighting: str, n: int, wavelength: float) -> float:
    """Amplitude ratio of a sine displacement of ``wavelength`` px returned by an ``n`` px
    window weighted by ``weighting`` ("tophat", "gaussian", "blackman")."""

MIN_MEDIAN_PEAK_RATIO: float
MAX_BLANK_FRACTION: float
MAX_REPLACED_FRACTION: float
BLANK_EDGE: int

def correlation_check(
    peak_ratio: npt.NDArray[np.float64],
    valid: npt.NDArray[np.bool_],
    local: bool,
    masked: npt.NDArray[np.bool_] | None = None,
) -> tuple[bool, str | None]:
    """``(uncorrelated, message)``: whether a field's frames do not correlate (the median peak
    ratio of its correlated windows, ``peak_ratio > 0``, under ``MIN_MEDIAN_PEAK_RATIO``, or
    no window correlated: no measurement), and the one-line warning, also for a field that
    correlates only in part (``local``: on a grid, more than 10 % of the valid vectors in 5 x 5
    neighbourhoods mostly under the limit; with or without it, more than
    ``MAX_BLANK_FRACTION`` of the windows not ``masked`` too blank to be correlated, or more
    than ``MAX_REPLACED_FRACTION`` of their vectors only interpolated, rejected by the
    validation or too blank, both inside the grid's ``BLANK_EDGE`` outer rings); None when the
    frames correlate. ValueError (InvalidInputError) when the arrays differ in shape."""

MIN_PARTICLE_DIAMETER: float

MIN_NOISE: float

def detect_particles(
    frame: npt.NDArray[np.generic],
    block: int,
    k: float,
    rel: float,
    full: float | None = None,
    mask: npt.NDArray[np.bool_] | None = None,
) -> dict[str, npt.NDArray[np.generic]]:
    """The particle images of ``frame`` (``piv_core::ptv::detect``): 1D arrays ``x``, ``y``
    (px), ``height`` (counts above the background), ``diameter_x``, ``diameter_y``,
    ``sigma_x``, ``sigma_y`` (px; NaN where not measured) and ``saturated``."""

def field_at(
    field_grid: tuple[float, float, float, float],
    field_u: npt.NDArray[np.float64],
    field_v: npt.NDArray[np.float64],
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """A regular-grid field ``(x0, y0, dx, dy)``, ``u``, ``v`` at the points ``(x, y)``:
    bilinear, constant beyond the outer nodes (``piv_core::GridField::at``)."""

def track_particles(
    ax: npt.NDArray[np.float64],
    ay: npt.NDArray[np.float64],
    bx: npt.NDArray[np.float64],
    by: npt.NDArray[np.float64],
    du: npt.NDArray[np.float64],
    dv: npt.NDArray[np.float64],
    radius: float,
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.uint8]]:
    """Each particle image of A's partner in B (index or -1) and its status (0 matched, 1
    none within ``radius``, 2 several, 3 claimed by another, 4 no predictor;
    ``piv_core::ptv::track``)."""

def seeding(
    frame: npt.NDArray[np.generic],
    block: int,
    k: float,
    rel: float,
    full: float | None = None,
    mask: npt.NDArray[np.bool_] | None = None,
) -> dict[str, object]:
    """Each ``block`` px block's ``background``, ``noise``, ``top`` (99.5th percentile),
    ``median`` (counts), ``peaks`` (particle images above ``b + max(k s, rel signal)``),
    ``heights`` (their summed heights above ``b``), ``saturated`` (those at ``full`` or above)
    and ``searched`` (pixels), as ``(rows, cols)`` arrays, with the frame's ``signal`` and the
    ``block`` (``piv_core::seeding``)."""

OSEEN_JOINT_MAX: int

OSEEN_MIN_FIT: float

OSEEN_MIN_VECTORS: int

def oseen_fit(
    u: npt.NDArray[np.float64],
    v: npt.NDArray[np.float64],
    valid: npt.NDArray[np.bool_],
    col: npt.NDArray[np.float64],
    row: npt.NDArray[np.float64],
    radius: npt.NDArray[np.float64],
    sign: npt.NDArray[np.float64],
    dx: float,
    dy: float,
    reach: float,
    orient: float,
    max_evals: int,
    shear: bool,
) -> dict[str, npt.NDArray[np.generic]]:
    """A Lamb-Oseen vortex fitted to the ``valid`` vectors of ``u``, ``v`` (pixel frame, grid
    of ``dx`` x ``dy`` px) within ``reach`` core radii of each core (centroid ``col``, ``row``
    in grid steps, ``radius`` px, ``sign`` +-1 in the frame ``orient`` turns the y-up frame
    into), with a uniform background shear if ``shear``, cores in parallel
    (``piv_core::vortex_fit``): per-core ``col``, ``row`` (grid steps), ``radius`` (px),
    ``circulation`` (px^2 per pair), ``u``, ``v`` (px per pair, pixel frame), ``shear``
    (``du/dy``, rows down, 1/pair; NaN without ``shear``), NaN unless ``ok``; ``fit`` (the share
    of the patch's variance about its background explained) and ``ok``. ValueError
    (InvalidInputError) for arrays of other shapes or lengths, a spacing or reach not > 0,
    ``orient`` not +-1 or ``max_evals`` of 0."""

def oseen_fit_joint(
    u: npt.NDArray[np.float64],
    v: npt.NDArray[np.float64],
    valid: npt.NDArray[np.bool_],
    cores: npt.NDArray[np.float64],
    fits: npt.NDArray[np.float64],
    group: npt.NDArray[np.int64],
    dx: float,
    dy: float,
    reach: float,
    orient: float,
    max_evals: int,
    shear: bool,
) -> dict[str, npt.NDArray[np.generic]]:
    """The groups of kept single fits (``group`` >= 0, at most ``OSEEN_JOINT_MAX`` each) fitted
    jointly, one background per group (``piv_core::vortex_joint``): ``cores`` (n, 4) the cores'
    ``col``, ``row`` (grid steps), ``radius`` (px), ``sign``; ``fits`` (n, 8) :func:`oseen_fit`'s
    ``col``, ``row``, ``radius``, ``circulation``, ``u``, ``v``, ``shear``, ``fit`` (NaN where
    not kept). Returns those arrays with the joint fits in place where a group's was kept, and
    ``joint`` (bool) there. ValueError (InvalidInputError) as :func:`oseen_fit`, and for
    ``cores``, ``fits`` and ``group`` of other lengths."""

def particle_diameter(
    frame_a: npt.NDArray[np.generic],
    frame_b: npt.NDArray[np.generic],
    window: tuple[int, int],
    mask: npt.NDArray[np.bool_] | None = None,
    background_a: npt.NDArray[np.float32] | None = None,
    background_b: npt.NDArray[np.float32] | None = None,
) -> tuple[float, float]:
    """The particle images' e^-2 diameter ``(x, y)`` px of a frame pair as recorded, from the
    confident correlation peaks of up to 4096 windows of ``window`` ``(w, h)`` px side by side
    (no offset), the backgrounds subtracted (clipped at 0) when given; NaN where not
    measured."""

def peak_locking_warning(diameter_x: float, diameter_y: float) -> str | None:
    """The one-line warning for particle images of e^-2 diameter ``(diameter_x, diameter_y)``
    px under ``MIN_PARTICLE_DIAMETER`` along either axis (sub-pixel displacements locked
    towards whole pixels); None otherwise or when not measured (NaN)."""

def conditioned(
    frame: npt.NDArray[np.generic],
    hot_pixels: float | None = None,
    high_pass: float | None = None,
    cap: float | None = None,
    min_max: int | None = None,
    background: npt.NDArray[np.float32] | None = None,
    smooth: float | None = None,
) -> npt.NDArray[np.float32]:
    """A new conditioned float32 copy of a uint8/uint16/float32/float64 frame
    (piv_core::conditioned: the conversion fused with the first steps)."""

ENSEMBLE_MIN_PEAK_RATIO: float

MOMENT_ORDERS: int

def moments_add(
    hm: npt.NDArray[np.float64],
    m2: npt.NDArray[np.float64],
    n_old: npt.NDArray[np.int64],
    delta: npt.NDArray[np.float64],
) -> None:
    """Add one sample per position to the central sums M_3 .. M_8 (``hm``, MOMENT_ORDERS x n,
    C-contiguous) in place; ``m2``, ``n_old``: M_2 and the counts before the sample, ``delta``:
    the sample minus the mean before it (0: no sample). (piv_core::moments)"""


def ensemble_stride(w: int, h: int) -> int: ...
def ensemble_add(
    frame_a: npt.NDArray[np.generic],
    frame_b: npt.NDArray[np.generic],
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    du: npt.NDArray[np.float64],
    dv: npt.NDArray[np.float64],
    window: tuple[int, int],
    acc: npt.NDArray[np.float64],
    auto: bool = True,
    mask: npt.NDArray[np.bool_] | None = None,
    interpolation: str = "bspline",
    field_grid: tuple[float, float, float, float] | None = None,
    field_u: npt.NDArray[np.float64] | None = None,
    field_v: npt.NDArray[np.float64] | None = None,
) -> int: ...
def ensemble_peaks(
    acc: npt.NDArray[np.float64], window: tuple[int, int]
) -> dict[str, npt.NDArray[np.float64]]: ...
def pixel_stride(rx: int, ry: int) -> int: ...
def pixel_add(
    frame_a: npt.NDArray[np.generic],
    frame_b: npt.NDArray[np.generic],
    seg: int,
    nseg: int,
    x0: float,
    lags: tuple[int, int],
    y: npt.NDArray[np.float64],
    du: npt.NDArray[np.float64],
    dv: npt.NDArray[np.float64],
    acc: npt.NDArray[np.float64],
    auto: bool = True,
    mask: npt.NDArray[np.bool_] | None = None,
    interpolation: str = "bspline",
) -> int: ...
def pixel_peaks(
    acc: npt.NDArray[np.float64], lags: tuple[int, int]
) -> dict[str, npt.NDArray[np.float64]]: ...
def grid_field_window_mean(
    field_grid: tuple[float, float, float, float],
    field_u: npt.NDArray[np.float64],
    field_v: npt.NDArray[np.float64],
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    window: tuple[int, int],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
