//! Binding of piv-core's Lamb-Oseen fit (`piv_core::vortex_fit`) for the Python facade
//! `rspiv.fit_oseen`, which checks the arguments, finds each core's centroid in grid steps and
//! maps the fitted centres back to the caller's coordinates.

use crate::errors::{invalid, PyRspivErr};
use numpy::{IntoPyArray, PyReadonlyArray1, PyReadonlyArray2};
use piv_core::vortex_fit::{fit_cores, OseenCore, OseenFit, OseenSettings};
use piv_core::vortex_joint::{fit_groups, JointMember};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Fit every core (`col`, `row` in grid steps, `radius` px, `sign` +-1) to the field `u`, `v`
/// (pixel frame) where `valid`, with a background shear if `shear`; returns a dict of per-core
/// arrays `col`, `row`, `radius`, `circulation`, `u`, `v`, `shear`, `fit` (float64) and `ok`
/// (bool) (`piv_core::vortex_fit::OseenFit`).
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn oseen_fit<'py>(
    py: Python<'py>,
    u: PyReadonlyArray2<'py, f64>,
    v: PyReadonlyArray2<'py, f64>,
    valid: PyReadonlyArray2<'py, bool>,
    col: PyReadonlyArray1<'py, f64>,
    row: PyReadonlyArray1<'py, f64>,
    radius: PyReadonlyArray1<'py, f64>,
    sign: PyReadonlyArray1<'py, f64>,
    dx: f64,
    dy: f64,
    reach: f64,
    orient: f64,
    max_evals: usize,
    shear: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let (col, row) = (col.as_array(), row.as_array());
    let (radius, sign) = (radius.as_array(), sign.as_array());
    let n = col.len();
    if row.len() != n || radius.len() != n || sign.len() != n {
        return Err(invalid(
            "oseen: the cores' col, row, radius and sign differ in length",
        ));
    }
    let cores: Vec<OseenCore> = (0..n)
        .map(|k| OseenCore {
            col: col[k],
            row: row[k],
            radius: radius[k],
            sign: sign[k],
        })
        .collect();
    let s = OseenSettings {
        dx,
        dy,
        reach,
        orient,
        max_evals,
        shear,
    };
    let (u, v, valid) = (u.as_array(), v.as_array(), valid.as_array());
    let fits = py
        .detach(|| fit_cores(u, v, valid, &cores, &s))
        .map_err(PyRspivErr::from)?;
    let d = PyDict::new(py);
    let column = |f: fn(&piv_core::vortex_fit::OseenFit) -> f64| -> Vec<f64> {
        fits.iter().map(f).collect()
    };
    d.set_item("col", column(|f| f.col).into_pyarray(py))?;
    d.set_item("row", column(|f| f.row).into_pyarray(py))?;
    d.set_item("radius", column(|f| f.radius).into_pyarray(py))?;
    d.set_item("circulation", column(|f| f.circulation).into_pyarray(py))?;
    d.set_item("u", column(|f| f.u).into_pyarray(py))?;
    d.set_item("v", column(|f| f.v).into_pyarray(py))?;
    d.set_item("shear", column(|f| f.shear).into_pyarray(py))?;
    d.set_item("fit", column(|f| f.fit).into_pyarray(py))?;
    let ok: Vec<bool> = fits.iter().map(|f| f.ok).collect();
    d.set_item("ok", ok.into_pyarray(py))?;
    Ok(d)
}

/// The columns of `oseen_fit_joint`'s `fits`, in order.
const FIT_COLUMNS: [&str; 8] = [
    "col",
    "row",
    "radius",
    "circulation",
    "u",
    "v",
    "shear",
    "fit",
];

/// Fit the groups of kept single fits jointly (`piv_core::vortex_joint`): `cores` (n, 4) the
/// cores' `col`, `row` (grid steps), `radius` (px) and `sign`; `fits` (n, 8) their single fits
/// (`FIT_COLUMNS`, kept: `ok`); `group` each fit's group (-1: none). Returns `fits` with the
/// joint fits in place of the single ones where a group's joint fit was kept, as a dict of
/// per-core arrays (`FIT_COLUMNS`), and `joint` (bool) where it was.
#[pyfunction]
#[allow(clippy::too_many_arguments)]
fn oseen_fit_joint<'py>(
    py: Python<'py>,
    u: PyReadonlyArray2<'py, f64>,
    v: PyReadonlyArray2<'py, f64>,
    valid: PyReadonlyArray2<'py, bool>,
    cores: PyReadonlyArray2<'py, f64>,
    fits: PyReadonlyArray2<'py, f64>,
    group: PyReadonlyArray1<'py, i64>,
    dx: f64,
    dy: f64,
    reach: f64,
    orient: f64,
    max_evals: usize,
    shear: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let (cores, fits, group) = (cores.as_array(), fits.as_array(), group.as_array());
    let n = group.len();
    if cores.dim() != (n, 4) || fits.dim() != (n, FIT_COLUMNS.len()) {
        return Err(invalid(
            "oseen: cores (n, 4), fits (n, 8) and group (n,) do not agree",
        ));
    }
    // the members of each group, in the order of their first appearance
    let mut labels: Vec<i64> = Vec::new();
    let mut index: Vec<Vec<usize>> = Vec::new();
    for (k, &g) in group.iter().enumerate() {
        if g < 0 {
            continue;
        }
        match labels.iter().position(|&l| l == g) {
            Some(at) => index[at].push(k),
            None => {
                labels.push(g);
                index.push(vec![k]);
            }
        }
    }
    let groups: Vec<Vec<JointMember>> = index
        .iter()
        .map(|ks| {
            ks.iter()
                .map(|&k| JointMember {
                    core: OseenCore {
                        col: cores[[k, 0]],
                        row: cores[[k, 1]],
                        radius: cores[[k, 2]],
                        sign: cores[[k, 3]],
                    },
                    fit: OseenFit {
                        col: fits[[k, 0]],
                        row: fits[[k, 1]],
                        radius: fits[[k, 2]],
                        circulation: fits[[k, 3]],
                        u: fits[[k, 4]],
                        v: fits[[k, 5]],
                        shear: fits[[k, 6]],
                        fit: fits[[k, 7]],
                        ok: fits[[k, 2]].is_finite(),
                    },
                })
                .collect()
        })
        .collect();
    let s = OseenSettings {
        dx,
        dy,
        reach,
        orient,
        max_evals,
        shear,
    };
    let (u, v, valid) = (u.as_array(), v.as_array(), valid.as_array());
    let joint = py
        .detach(|| fit_groups(u, v, valid, &groups, &s))
        .map_err(PyRspivErr::from)?;
    let mut out: Vec<Vec<f64>> = (0..FIT_COLUMNS.len())
        .map(|c| fits.column(c).to_vec())
        .collect();
    let mut together = vec![false; n];
    for (ks, got) in index.iter().zip(joint) {
        for (&k, f) in ks.iter().zip(got.iter().flatten()) {
            let vals = [
                f.col,
                f.row,
                f.radius,
                f.circulation,
                f.u,
                f.v,
                f.shear,
                f.fit,
            ];
            for (c, val) in vals.into_iter().enumerate() {
                out[c][k] = val;
            }
            together[k] = true;
        }
    }
    let d = PyDict::new(py);
    for (name, col) in FIT_COLUMNS.iter().zip(out) {
        d.set_item(*name, col.into_pyarray(py))?;
    }
    d.set_item("joint", together.into_pyarray(py))?;
    Ok(d)
}

/// Register the fit in the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(oseen_fit, m)?)?;
    m.add_function(wrap_pyfunction!(oseen_fit_joint, m)?)?;
    m.add("OSEEN_JOINT_MAX", piv_core::vortex_joint::OSEEN_JOINT_MAX)?;
    m.add("OSEEN_MIN_FIT", piv_core::vortex_fit::OSEEN_MIN_FIT)?;
    m.add("OSEEN_MIN_VECTORS", piv_core::vortex_fit::OSEEN_MIN_VECTORS)?;
    Ok(())
}
