"""Fiducials that fix a plate's origin and axes (issue 15): printed squares, triangles and rings
read from the image, the origin on the highest-ranked one, +u towards a second one on a lattice
line, so that calibrations of one plate agree however the camera is turned. Every case is
rendered with an exact answer (rspiv.synth)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from rspiv import _rspiv, calibrate
from rspiv.errors import InvalidInputError
from rspiv.fiducial import classify_shape
from rspiv.synth import calibration_target
from rspiv.synth.target import PAPER_OPTICS
from scipy.spatial import cKDTree

PITCH = PAPER_OPTICS.pitch_mm


def _mark(
    sides: int, radius: float, seed: int, dark: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """One printed mark (0: a disc) of circumradius ``radius`` px, blur 1 px, 12-bit noise, at a
    random sub-pixel centre and orientation."""
    rng = np.random.default_rng(seed)
    size = int(4 * radius + 24)
    c = np.array([[0.5 * size, 0.5 * size]]) + rng.uniform(-0.5, 0.5, (1, 2))
    img = _rspiv.render_target(
        size, size, c, np.array([1.0]), np.array([-1500.0 if dark else 1500.0]),
        radius_px=np.array([radius]), sides=np.array([sides], dtype=np.uint32),
        orientation_rad=np.array([rng.uniform(0, 2 * np.pi)]), seed=seed,
        plate=2500.0 if dark else 0.0,
    )  # fmt: skip
    return img, c[0]


@pytest.mark.parametrize("radius", [4.0, 6.0, 10.0, 20.0, 40.0])
@pytest.mark.parametrize("dark", [False, True])
def test_shapes_are_read_from_the_image(radius, dark):
    for sides, kind in ((0, None), (3, "triangle"), (4, "square")):
        for seed in range(3):
            img, c = _mark(sides, radius, seed, dark)
            got, centroid, m = classify_shape(img, c, 1.6 * radius, dark)
            assert got == kind, (sides, radius, seed, m)
            # A regular polygon's centroid is its centre.
            assert np.hypot(*(centroid - c)) < 0.05 * radius + 0.1


def test_a_ring_is_read_as_a_ring_and_nothing_as_nothing():
    size, c = 80, np.array([[40.3, 39.6]])
    ring = _rspiv.render_target(
        size, size, np.vstack([c, c]), np.array([1.0, 1.0]), np.array([1500.0, -1500.0]),
        radius_px=np.array([14.0, 9.0]),
    )  # fmt: skip
    assert classify_shape(ring, c[0], 25.0, False)[0] == "ring"
    blank = _rspiv.render_target(size, size, c, np.array([1.0]), np.array([0.0]))
    assert classify_shape(blank, c[0], 25.0, False)[0] is None


@pytest.mark.parametrize(
    ("rotation", "dot", "square_plate"),
    [(0.0, "disc", False), (180.0, "gaussian", False), (90.0, "gaussian", True),
     (-30.0, "disc", True)],
)  # fmt: skip
def test_square_and_triangle_fix_origin_and_axes_however_the_camera_is_turned(
    rotation, dot, square_plate
):
    optics = dataclasses.replace(PAPER_OPTICS, n_markers=(7, 7)) if square_plate else PAPER_OPTICS
    t = calibration_target(
        scale=0.25, optics=optics, seed=2, dot=dot, dot_diameter_px=14.0, rotation_deg=rotation,
        fiducial=("square", "triangle", "ring"), fiducial_site=((1, 0), (3, 0), (-1, 2)),
    )  # fmt: skip
    cal = calibrate(t.image, PITCH, model="auto")
    la = cal.lattice
    fx = la["fiducial"]
    assert fx["kind"] == "square" and fx["axis"]["kind"] == "triangle"
    truth = t.extra["fiducial_px"]
    assert np.hypot(*(np.array(fx["image_px"]) - truth[0])) < 0.5
    assert np.hypot(*(np.array(fx["axis"]["image_px"]) - truth[1])) < 1.0
    # Object coordinates in the plate's own frame (origin on the square, +u towards the
    # triangle), whatever the camera's turn; the marks themselves are not fitted.
    d, k = cKDTree(t.markers_px).query(cal.markers.image_px)
    assert np.max(d) < 0.1 and len(cal.markers) >= len(t.markers_px) - 2
    rel = (t.index[k] - t.extra["fiducial_index"]) * PITCH
    assert np.allclose(cal.markers.object_mm, rel)
    assert np.min(cKDTree(cal.markers.image_px).query(truth)[0]) > 10.0
    assert "origin on the square fiducial" in cal.lattice_summary()
    assert "+u towards the triangle fiducial" in cal.lattice_summary()


@pytest.mark.parametrize(("fiducial", "dot"), [("square", "gaussian"), ("triangle", "disc")])
def test_two_level_plate_with_a_printed_fiducial(fiducial, dot):
    t = calibration_target(
        scale=0.25, seed=1, levels=2, level_scale=0.995, fiducial=fiducial, dot=dot,
        dot_diameter_px=14.0,
    )  # fmt: skip
    cal = calibrate(t.image, PITCH, model="auto")
    la = cal.lattice
    assert la["levels"] == 2 and la["level"] == 1 and la["fiducial"]["kind"] == fiducial
    assert cal.magnification == pytest.approx(t.optics.magnification, rel=2e-3)
    d, k = cKDTree(t.markers_px).query(cal.markers.image_px)
    assert np.max(d) < 0.1
    assert np.allclose(cal.markers.object_mm, (t.index[k] - t.extra["fiducial_index"]) * PITCH)


def test_two_marks_of_the_top_kind_give_no_origin():
    # Two squares: which is the origin cannot be told; the central marker is, and it is said.
    t = calibration_target(
        scale=0.25, seed=3, fiducial=("square", "square"), fiducial_site=((1, 0), (-2, 1))
    )
    cal = calibrate(t.image, PITCH, model="auto")
    assert cal.lattice["fiducial"] is None
    assert "origin on the central marker" in cal.lattice_summary()


def test_bad_fiducial_options_are_one_line_errors():
    for kw, msg in (
        ({"fiducial": ("square", "star")}, "fiducial must be"),
        ({"fiducial": ("square", "triangle"), "fiducial_site": (1, 0)}, "one .i, j. site"),
        ({"fiducial": "square", "fiducial_site": (0.3, 0)}, "half-integers"),
        ({"fiducial": "square", "fiducial_site": (0.5, 0.5), "levels": 2}, "level-2 dot"),
        ({"fiducial": ("square", "ring"), "fiducial_site": ((1, 0), (1, 0))}, "two fiducials"),
    ):
        with pytest.raises(InvalidInputError, match=msg) as e:
            calibration_target(scale=0.25, **kw)
        assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="orientation_rad without sides"):
        _rspiv.render_target(
            20, 20, np.array([[10.0, 10.0]]), np.array([1.0]), np.array([100.0]),
            orientation_rad=np.array([0.0]),
        )  # fmt: skip
    with pytest.raises(ValueError, match="3-64 sides"):
        _rspiv.render_target(
            20, 20, np.array([[10.0, 10.0]]), np.array([1.0]), np.array([100.0]),
            radius_px=np.array([5.0]), sides=np.array([2], dtype=np.uint32),
        )  # fmt: skip


@pytest.mark.parametrize("rotation", [0.0, 180.0])
def test_marks_between_the_sites_of_a_two_level_plate(rotation):
    # As commercial two-level plates print them: a square and a triangle half-way between two
    # level-1 dots (the centre of a cell of the union), every dot in place; object coordinates
    # are half-integer multiples of the pitch from the square, +u towards the triangle.
    t = calibration_target(
        scale=0.25, seed=4, levels=2, level_scale=0.995, dot="disc", dot_diameter_px=14.0,
        rotation_deg=rotation, fiducial=("square", "triangle"),
        fiducial_site=((0.5, 0), (2.5, 0)),
    )  # fmt: skip
    cal = calibrate(t.image, PITCH, model="auto")
    la = cal.lattice
    fx = la["fiducial"]
    assert la["levels"] == 2 and la["level"] == 1
    assert fx["kind"] == "square" and fx["axis"]["kind"] == "triangle"
    assert np.hypot(*(np.array(fx["image_px"]) - t.extra["fiducial_px"][0])) < 0.5
    # (The level's four corner markers touch one union neighbour each and may be pruned.)
    d, k = cKDTree(t.markers_px).query(cal.markers.image_px)
    assert np.max(d) < 0.1 and len(cal.markers) >= len(t.markers_px) - 4
    rel = (t.index[k] - np.array([0.5, 0.0])) * PITCH
    assert np.allclose(cal.markers.object_mm, rel)
    assert cal.magnification == pytest.approx(t.optics.magnification, rel=2e-3)


@pytest.mark.parametrize("shift", [(12.0, 4.0), (45.0, -20.0)])
def test_two_level_plate_seen_obliquely(shift):
    # The second level shifted by a parallax of 10 % of the union's pitch (OpenPTV's 4-camera
    # plate shows 9-10 %): the union is no lattice, its two parity classes are (grid.rs). At
    # 42 % the grid takes one level, and the other is found as a second lattice at one offset
    # from its half-sites (plate.union_of_levels).
    t = calibration_target(
        scale=0.25, seed=5, levels=2, level_scale=0.995, level_shift_px=shift, dot="disc",
        dot_diameter_px=14.0, fiducial=("square", "triangle"), fiducial_site=((0.5, 0), (2.5, 0)),
    )  # fmt: skip
    cal = calibrate(t.image, PITCH, model="auto")
    la = cal.lattice
    assert la["levels"] == 2 and la["fiducial"]["kind"] == "square"
    assert la["plate"]["other_scale"] == pytest.approx(0.995, abs=5e-4)
    assert len(la["other_level_px"]) >= len(t.extra["level2_px"]) - 4
    d, k = cKDTree(t.markers_px).query(cal.markers.image_px)
    assert np.max(d) < 0.1 and len(cal.markers) >= len(t.markers_px) - 4
    assert np.allclose(cal.markers.object_mm, (t.index[k] - np.array([0.5, 0.0])) * PITCH)
    assert cal.magnification == pytest.approx(t.optics.magnification, rel=2e-3)
    cal2 = calibrate(t.image, PITCH, model="auto", level=2)
    assert cal2.magnification == pytest.approx(0.995 * t.optics.magnification, rel=2e-3)
    d2, _ = cKDTree(t.extra["level2_px"]).query(cal2.markers.image_px)
    assert np.max(d2) < 0.1


def test_a_stepped_target_is_calibrated_on_one_section_and_says_so():
    # Two flat sections side by side at different depths (MyPTV's stepped body): 9 x 15 dots at
    # 40 px, and 5 x 15 at 39.6 px beyond a gap, off the first's lattice. A planar calibration
    # takes the larger section alone and says what it left out.
    ii, jj = np.meshgrid(np.arange(9), np.arange(15), indexing="ij")
    a = np.column_stack([150.0 + 40.0 * ii.ravel(), 100.0 + 40.0 * jj.ravel()])
    ii, jj = np.meshgrid(np.arange(5), np.arange(15), indexing="ij")
    b = np.column_stack([550.0 + 13.7 + 39.6 * ii.ravel(), 100.0 + 9.3 + 39.6 * jj.ravel()])
    pts = np.vstack([a, b])
    img = _rspiv.render_target(
        720, 900, pts, np.full(len(pts), 3.0), np.full(len(pts), 1500.0), seed=3
    )
    cal = calibrate(img, 1.0, model="r1")
    d, _ = cKDTree(a).query(cal.markers.image_px)
    assert np.max(d) < 0.1 and len(cal.markers) >= len(a) - 2
    assert cal.lattice["other_lattices"] == [len(b)]
    assert "1 other lattice(s) of the same pitch (75 markers) not used" in cal.lattice_summary()
    assert any("stepped or 3-D target" in w for w in cal.warnings)
    assert cal.magnification == pytest.approx(40.0, rel=2e-3)


def test_a_dot_half_hidden_is_left_out_and_said():
    # A dot whose left edge is covered (the plate's edge, a clamp, 3 of its 14 px): its fitted
    # centre moves by 1 px, 150 times the markers' scatter. It is left out with a line that
    # names it; the others still fit to their noise and give the right magnification.
    t = calibration_target(scale=0.25, seed=6, dot="disc", dot_diameter_px=14.0)
    img = t.image.copy()
    k = 20
    x, y = t.markers_px[k]
    img[int(y) - 10 : int(y) + 11, int(x) - 10 : int(x) - 4] = int(np.median(img))
    cal = calibrate(img, PITCH, model="p3")
    d, _ = cKDTree(cal.markers.image_px).query(t.markers_px[k])
    assert d > 1.0 and len(cal.markers) == len(t.markers_px) - 1
    note = [w for w in cal.warnings if "left out at" in w]
    # (named at its measured place, 1 px right of the true one)
    named = f"1 indexed marker(s) left out at ({x + 1:.0f}, {y:.0f}) px"
    assert len(note) == 1 and named in note[0], cal.warnings
    assert not any("follows the target less closely" in w for w in cal.warnings)
    assert cal.magnification == pytest.approx(t.optics.magnification, rel=2e-3)
    assert cal.lattice["n_rejected"] >= 1


def test_lattice_outliers_takes_out_isolated_markers_only():
    from rspiv.calibration_fit import lattice_outliers

    rng = np.random.default_rng(0)
    ii, jj = np.meshgrid(np.arange(20), np.arange(20), indexing="ij")
    uv = np.column_stack([ii.ravel(), jj.ravel()]).astype(np.float64)
    # A smooth lattice (a 2 % barrel) with 0.01 px of noise.
    c = uv - 9.5
    r2 = np.sum(c**2, axis=1) / 200.0
    px = 500.0 + 40.0 * c * (1.0 - 0.02 * r2)[:, None] + rng.normal(0, 0.01, uv.shape)
    one = px.copy()
    one[123] += (0.7, -0.4)
    rows, scale = lattice_outliers(uv - 0.5, one)  # an origin between sites changes nothing
    # (the scale holds the barrel's own second differences, 0.06 px, besides the noise)
    assert rows.tolist() == [123] and 0.01 < scale < 0.1
    assert lattice_outliers(uv, px)[0].size == 0
    # Many markers off (more than 1 % of 400, or 2): no isolated outlier, none taken out.
    many = px.copy()
    many[[5, 77, 150, 222, 301, 380]] += 0.5
    assert lattice_outliers(uv, many)[0].size == 0
