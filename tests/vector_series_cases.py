"""Series of exact boundary-layer vector fields written as another tool's files (the tests of
:mod:`rspiv.vector_statistics`).

Each field is the synthetic layer's exact displacement (:func:`rspiv.synth.tbl.tbl_scene`, one
seed per field: independent fields) at a DaVis grid, with what PIV measures behind the wall:
the particles' reflection moving as the flow's mirror image (``u - 2 (u.n) n``). Through a
camera (``camera``: object px -> image px) the field is the one a tool measures on the raw
frames, ``d = F(X + D/2) - F(X - D/2)`` at the image grid, ``X = F^-1(x)``.
"""

from __future__ import annotations

import pathlib

import numpy as np
import pytest
from rspiv.synth.tbl import tbl_scene

SCALE = 0.25  # a 2216 x 1322 px sensor, M = 8.63 px/mm, l_v = 0.37 px
GRID = 16


def exact_field(
    seed: int, *, angle: float = 0.0, wall_y0: float | None = None, camera=None, scale=SCALE,
    **scene,
):  # fmt: skip
    """(truth, x, y, u, v) of one field at the DaVis grid (positions in the recorded frame) of
    the synthetic sensor at ``scale`` (1.0: 8864 x 5288 px); ``scene``: more of
    :func:`rspiv.synth.tbl.tbl_scene`'s keywords (planted vortices)."""
    tr = tbl_scene(scale, seed=seed, lens=None, wall_angle_deg=angle, wall_y0_px=wall_y0,
                   **scene)  # fmt: skip
    h, w = tr.shape
    xs = (np.arange(w // GRID) + 0.5) * GRID - 0.5
    ys = (np.arange(h // GRID) + 0.5) * GRID - 0.5
    x, y = np.meshgrid(xs, ys)
    pts = np.column_stack([x.ravel(), y.ravel()])
    obj = pts if camera is None else camera.inverse(pts)
    ox, oy = obj[:, 0], obj[:, 1]
    d = tr.wall_distance(ox, oy)
    mx, my = tr.mirror(ox, oy)
    u, v = tr.displacement(np.where(d > 0, ox, mx), np.where(d > 0, oy, my))
    a = np.deg2rad(angle)
    n = np.array([np.sin(a), -np.cos(a)])
    dn = np.where(d > 0, 0.0, u * n[0] + v * n[1])
    disp = np.column_stack([u - 2 * dn * n[0], v - 2 * dn * n[1]])
    if camera is not None:
        ends = camera.forward(np.concatenate([obj - disp / 2, obj + disp / 2]))
        disp = ends[len(obj) :] - ends[: len(obj)]
    return tr, x, y, disp[:, 0].reshape(x.shape), disp[:, 1].reshape(x.shape)


def write_vc7(
    path: pathlib.Path, u: np.ndarray, v: np.ndarray, mm_per_px: float, dt: float, choice: int = 0
):
    """A DaVis vector buffer of one field (lvpyio's writer), its scales giving mm/px and dt;
    every vector of DaVis' ``choice`` (0: the highest peak, 4: filled by DaVis)."""
    lv = pytest.importorskip("lvpyio", reason="DaVis files need lvpyio (rspiv[davis])")
    from lvpyio.types.buffer import Buffer
    from lvpyio.types.component import Component, Components
    from lvpyio.types.frame import VectorFrame

    vel = lv.Scale(mm_per_px * 1e-3 / dt, 0.0, "m/s", "velocity")
    counts = lv.Scale(1.0, 0.0, "counts", "")
    comps = Components()
    for k in range(4):
        comps[f"U{k}"] = Component(vel, [u.astype(np.float32)])
        comps[f"V{k}"] = Component(vel, [v.astype(np.float32)])
    comps["ACTIVE_CHOICE"] = Component(counts, [np.full(u.shape, choice, np.int32)])
    comps["ENABLED"] = Component(counts, [np.ones(u.shape, np.uint8)])
    scales = lv.Scales(
        lv.Scale(mm_per_px, 0.0, "mm", "position"), lv.Scale(-mm_per_px, 0.0, "mm", "position"),
        lv.Scale(1.0, 0.0, "pixel", ""), vel,
    )  # fmt: skip
    frame = VectorFrame(comps, scales, {"InterrogationWindowSize": "32"}, lv.Grid(GRID, GRID, 1), 4)
    lv.write_buffer(Buffer([frame], {}), str(path))
    return path


def write_series(folder: pathlib.Path, n: int, **kw) -> tuple[list[pathlib.Path], object]:
    """``n`` fields (seeds 0..n-1) as ``folder/B00000.vc7`` ...; returns the files and the
    first field's truth."""
    folder.mkdir(parents=True, exist_ok=True)
    files, truth = [], None
    for s in range(n):
        tr, _, _, u, v = exact_field(s, **kw)
        truth = truth or tr
        files.append(write_vc7(folder / f"B{s:05d}.vc7", u, v, 1.0 / tr.magnification, tr.dt))
    return files, truth


def write_insight(
    path: pathlib.Path, x, y, u, v, chc=None, *, mm_per_px=None, dt=None, origin=(0.0, 0.0),
    dewarped="0", fmt="%.12g", extra_aux="",
):  # fmt: skip
    """A TSI Insight ``.vec`` file of a field given in rspiv's frame (px; v down), in Insight's
    layout (``rspiv.insight``): positions from ``origin`` with y up, at ``x + 1/2``; in mm and
    m/s when ``mm_per_px`` and ``dt`` are given, else in pixel per pair; one line per vector,
    x fastest, the top row first."""
    ox, oy = origin
    px, py = x + 0.5 - ox, oy - (y + 0.5)  # Insight's px from its origin, y up
    if mm_per_px is None:
        names = '"X pixel", "Y pixel", "U pixel", "V pixel", "CHC"'
        cols = [px, py, u, -v]
        aux = 'DATASETAUXDATA LengthUnit="pixel" DATASETAUXDATA TimeUnit="deltaT" '
    else:
        k = mm_per_px * 1e-3 / dt
        names = '"X mm", "Y mm", "U m/s", "V m/s", "CHC"'
        cols = [px * mm_per_px, py * mm_per_px, u * k, -v * k]
        aux = (f'DATASETAUXDATA MicrometersPerPixelX="{mm_per_px * 1e3:.6f}" '
               f'DATASETAUXDATA MicrometersPerPixelY="{mm_per_px * 1e3:.6f}" '
               'DATASETAUXDATA LengthUnit="mm" DATASETAUXDATA TimeUnit="ms" ')  # fmt: skip
    if dt is not None:
        aux += f'DATASETAUXDATA MicrosecondsPerDeltaT="{dt * 1e6:.6f}" '
    chc = np.ones(u.shape) if chc is None else chc
    ny, nx = u.shape
    head = (
        f'TITLE="C:\\Analysis\\{path.name}" VARIABLES={names}, DATASETAUXDATA Application="PIV" '
        f'{aux}DATASETAUXDATA OriginInImageX="{ox:.6f}" DATASETAUXDATA OriginInImageY="{oy:.6f}" '
        f'DATASETAUXDATA DewarpedImageSource="{dewarped}" {extra_aux}ZONE I={nx}, J={ny}, F=POINT'
    )
    rows = np.column_stack([c.ravel() for c in cols] + [np.asarray(chc).ravel()])
    body = "\n".join(", ".join([fmt % r for r in row[:4]] + [str(int(row[4]))]) for row in rows)
    path.write_text(head + "\n" + body + "\n")
    return path
