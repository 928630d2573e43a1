//! VarPro refits against the generic LM.
use super::super::*;
use super::*;

/// VarPro refits land on the same optimum as the generic LM at tight tolerances.
#[test]
fn varpro_matches_generic_lm() {
    let s = 8423.924;
    let pitch = 19.51 * 34.538 / s;
    for model in [Model::R1, Model::R2] {
        let k = 0.0088;
        let c: Vec<f64> = if model == Model::R2 {
            vec![
                1.0004, 0.0003, 2e-4, 1.5e-4, -1e-4, 0.5e-4, -0.0002, 0.9997, -3e-4, -0.5e-4,
                1.2e-4, 2e-4, 0.0004, -0.0003, -k, 0.0, -k,
            ]
        } else {
            vec![
                1.0004, 0.0003, 2e-4, -0.0002, 0.9997, -3e-4, 0.0025, -0.0015,
            ]
        };
        let mut o = Vec::new();
        let mut i = Vec::new();
        let mut t = 0.0f64;
        for r in 0..7 {
            for q in 0..13 {
                let (x, y) = ((q as f64 - 6.0) * pitch, (r as f64 - 3.0) * pitch);
                let (fx, fy) = eval_normalized(model, &c, x, y);
                t += 1.0;
                let nz = (t * 12.9898).sin() * 43758.5453;
                o.push([x + 0.38 / s * (nz.fract() - 0.5) * 3.4, y]);
                i.push([fx, fy + 0.057 / s * ((nz * 1.7).fract() - 0.5) * 3.4]);
            }
        }
        let prob = MappingProblem {
            model,
            obj: &o,
            img: &i,
        };
        let reference = lm::minimize(&prob, &c, &LmConfig::tight()).unwrap();
        let mut ws = FitWorkspace::new();
        ws.config = LmConfig::tight();
        for warm in [None, Some(c.as_slice())] {
            let got = ws.fit_normalized(model, &o, &i, warm).unwrap().to_vec();
            let last = ws.last.unwrap();
            assert!(last.termination.converged());
            assert!(last.cost <= reference.cost * (1.0 + 1e-9));
            for p in &o {
                let a = eval_normalized(model, &got, p[0], p[1]);
                let b = eval_normalized(model, &reference.params, p[0], p[1]);
                assert!((a.0 - b.0).abs() * s < 1e-6 && (a.1 - b.1).abs() * s < 1e-6);
            }
        }
    }
}
