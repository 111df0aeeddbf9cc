//! Hybrid node placement: the next tabulated node of a hybrid NDF goes where the kept model
//! misses the data most, in micro-facet polar angle θm (not at a fixed spacing from θm = 0).
//!
//! Every used point is mapped to the θm of the one interaction with the rough face that sends
//! the beam into its detector: reflection or refraction at the rough face, the polished face
//! passing the light in or out with its tangential momentum (Snell); further bounces are
//! ignored (a placement heuristic: the fit then decides the multipliers, the selection rule
//! whether the node stays). The excess χ² of each point, z² − 1 with
//! z = (s − m)/√(σs² + σm²) at the check seed, is summed in bins of width h centred on k·h;
//! the node goes to the bin with the largest positive sum that holds no fitted node yet
//! ([`Problem::residual_peak`]), with anchors (multiplier 1, not fitted) one step h on either
//! side where the table joins the analytic part ([`with_node`]).
//!
//! Tests: `tests` below (specular directions map to θm = 0, a tilted facet maps back to its
//! tilt for all four paths; the table layout); `round_trip_hybrid` (ignored tier) in
//! `crates/opal-inverse/tests/ndf_fit.rs`.

use super::{Evaluation, Family, Model, Problem};
use opal::gonio::Side;

type D3 = [f64; 3];

fn sub(a: D3, b: D3) -> D3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn scale(a: D3, s: f64) -> D3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// Polar angle θm of the micro-facet normal that turns the beam direction `k` (propagation,
/// z < 0) into the detector direction `a` through one interaction with the rough face of a
/// plate of index `n` (`rough_front`: the lit face is rough); `None` when no such facet exists
/// (total internal reflection on the way).
pub(super) fn theta_m(k: D3, a: D3, side: Side, n: f64, rough_front: bool) -> Option<f64> {
    // the direction inside the glass with the tangential part of the outside direction v
    let inside = |v: D3, up: bool| -> Option<D3> {
        let (tx, ty) = (v[0] / n, v[1] / n);
        let s = 1.0 - tx * tx - ty * ty;
        (s > 0.0).then(|| [tx, ty, if up { s.sqrt() } else { -s.sqrt() }])
    };
    // reflection: m ∥ out − in; refraction from index ni to no: m ∥ ni·in − no·out
    let m = match (rough_front, side) {
        (true, Side::R) => sub(a, k),
        (true, Side::T) => sub(k, scale(inside(a, false)?, n)),
        (false, Side::T) => sub(scale(inside(k, false)?, n), a),
        (false, Side::R) => sub(inside(a, true)?, inside(k, false)?),
    };
    let l = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
    (l > 1e-12).then(|| (m[2].abs() / l).min(1.0).acos())
}

impl Problem {
    /// θm of the rough-face interaction that reaches detector `det` at incidence `inc` (see
    /// the module documentation).
    fn point_theta_m(&self, inc: usize, det: usize) -> Option<f64> {
        let (t, phi) = (self.incidences[inc], self.setup.beam.azimuth);
        let k = [t.sin() * phi.cos(), t.sin() * phi.sin(), -t.cos()];
        let d = &self.gonio.detectors().list()[det];
        let a = [d.axis.x as f64, d.axis.y as f64, d.axis.z as f64];
        theta_m(k, a, d.side, self.setup.plate.ior, self.setup.rough_front)
    }

    /// The node angle k·h (radians) whose bin of width `h` holds the largest positive excess
    /// χ² of `eval` (a check of the kept model), skipping the bins of the angles in `taken`
    /// (the fitted nodes already there); `None` when no free bin has a positive excess.
    pub fn residual_peak(&self, eval: &Evaluation, h: f64, taken: &[f64]) -> Option<f64> {
        let nb = (std::f64::consts::FRAC_PI_2 / h).ceil() as usize + 1;
        let mut excess = vec![0.0; nb];
        for p in &self.points {
            let r = &eval.result.incidences[p.inc];
            let (s, ss) = (r.value[p.det], r.value_stderr[p.det]);
            let var = ss * ss + p.sm * p.sm;
            let Some(tm) = self.point_theta_m(p.inc, p.det) else { continue };
            let b = (tm / h).round() as usize;
            if var > 0.0 && b < nb {
                excess[b] += (s - p.m).powi(2) / var - 1.0;
            }
        }
        let held = |b: usize| taken.iter().any(|&t| (t / h).round() as usize == b);
        (0..nb)
            .filter(|&b| excess[b] > 0.0 && !held(b))
            .max_by(|&x, &y| excess[x].total_cmp(&excess[y]))
            .map(|b| b as f64 * h)
    }
}

/// `model` with one more fitted hybrid node at `theta` (snapped to the grid k·h): the fitted
/// nodes keep their multipliers, the new one starts at the model's current multiplier there,
/// and every run of fitted nodes gets an anchor (multiplier 1, pinned) one step below (unless
/// it starts at θm = 0) and one step above, where the table joins the analytic part.
pub fn with_node(model: &Model, theta: f64, h: f64) -> Model {
    let grid = |t: f64| (t / h).round() as i64;
    let mut free: Vec<(i64, f64)> =
        model.free_nodes().iter().map(|&i| (grid(model.nodes[i].0), model.nodes[i].1)).collect();
    let j = grid(theta).max(0);
    if !free.iter().any(|f| f.0 == j) {
        free.push((j, model.multiplier_at(j as f64 * h)));
    }
    free.sort_by_key(|f| f.0);
    let mut cells: Vec<(i64, f64, bool)> = Vec::new();
    let mut push = |j: i64, m: f64, pinned: bool| {
        if cells.last().is_none_or(|c| c.0 < j) {
            cells.push((j, m, pinned));
        }
    };
    for (i, &(j, m)) in free.iter().enumerate() {
        if j >= 1 && (i == 0 || free[i - 1].0 < j - 1) {
            push(j - 1, 1.0, true);
        }
        push(j, m, false);
        if i + 1 == free.len() || free[i + 1].0 > j + 1 {
            push(j + 1, 1.0, true);
        }
    }
    let mut out = model.clone();
    out.family = Family::Hybrid;
    out.nodes = cells.iter().map(|c| (c.0 as f64 * h, c.1)).collect();
    out.pinned = cells.iter().map(|c| c.2).collect();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(v: D3) -> D3 {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        scale(v, 1.0 / l)
    }
    fn dot(a: D3, b: D3) -> f64 {
        a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    }
    fn reflect(d: D3, m: D3) -> D3 {
        sub(d, scale(m, 2.0 * dot(d, m)))
    }
    /// Refraction of propagation direction d from index ni to no at normal m (either sign).
    /// Refraction of `d` at the facet `m` (`None`: total internal reflection).
    fn refract(d: D3, m: D3, ni: f64, no: f64) -> Option<D3> {
        let m = if dot(d, m) > 0.0 { scale(m, -1.0) } else { m };
        let (eta, c) = (ni / no, -dot(d, m));
        let k = 1.0 - eta * eta * (1.0 - c * c);
        (k > 0.0).then(|| unit(sub(scale(d, eta), scale(m, k.sqrt() - eta * c))))
    }
    /// Flat face refraction (normal z).
    fn flat(d: D3, ni: f64, no: f64) -> Option<D3> {
        refract(d, [0.0, 0.0, 1.0], ni, no)
    }

    #[test]
    fn theta_m_of_specular_and_tilted_facets() {
        let n = 1.5;
        // configurations where a ray is totally reflected inside (no such path) are skipped
        let mut checked = 0;
        for (t, phi) in [(0.3f64, 0.0f64), (0.7, 0.4)] {
            let k = [t.sin() * phi.cos(), t.sin() * phi.sin(), -t.cos()];
            for tilt in [0.0f64, 0.12, 0.3] {
                let m = unit([tilt.sin(), 0.05 * tilt, tilt.cos()]);
                let want = m[2].acos();
                // rough front: reflect / refract at m, the refracted ray leaves the flat back
                let a = reflect(k, m);
                let got = theta_m(k, a, Side::R, n, true).unwrap();
                assert!((got - want).abs() < 1e-9, "front R {tilt}: {got} vs {want}");
                checked += 1;
                if let Some(a) = refract(k, m, 1.0, n).and_then(|r| flat(r, n, 1.0)) {
                    let got = theta_m(k, a, Side::T, n, true).unwrap();
                    assert!((got - want).abs() < 1e-9, "front T {tilt}: {got} vs {want}");
                    checked += 1;
                }
                // rough back: in through the flat front, refract out / reflect back at m
                let t0 = flat(k, 1.0, n).expect("entering the denser medium always refracts");
                if let Some(a) = refract(t0, m, n, 1.0) {
                    let got = theta_m(k, a, Side::T, n, false).unwrap();
                    assert!((got - want).abs() < 1e-9, "back T {tilt}: {got} vs {want}");
                    checked += 1;
                }
                if let Some(a) = flat(reflect(t0, m), n, 1.0) {
                    let got = theta_m(k, a, Side::R, n, false).unwrap();
                    assert!((got - want).abs() < 1e-9, "back R {tilt}: {got} vs {want}");
                    checked += 1;
                }
            }
        }
        // 6 configurations × 4 paths, of which only a few are totally reflected
        assert!(checked >= 20, "{checked} paths checked");
    }

    #[test]
    fn nodes_get_anchors_where_the_table_meets_the_base() {
        let h = 2f64.to_radians();
        let m = with_node(&Model::new(Family::Ggx, 0.2), 6.2f64.to_radians(), h);
        let deg: Vec<i64> = m.nodes.iter().map(|n| n.0.to_degrees().round() as i64).collect();
        assert_eq!(deg, [4, 6, 8]);
        assert_eq!(m.pinned, [true, false, true]);
        assert_eq!((m.free_nodes(), m.parameter_count(), m.family), (vec![1], 2, Family::Hybrid));
        let mut m2 = m.clone();
        m2.nodes[1].1 = 1.7;
        let m3 = with_node(&m2, 0.0, h);
        let deg: Vec<i64> = m3.nodes.iter().map(|n| n.0.to_degrees().round() as i64).collect();
        assert_eq!(deg, [0, 2, 4, 6, 8]);
        assert_eq!(m3.pinned, [false, true, true, false, true]);
        assert_eq!(m3.free_nodes(), [0, 3]);
        assert_eq!(m3.nodes[3].1, 1.7);
        // a neighbour of a fitted node: the runs merge, no anchor between them
        let m4 = with_node(&m3, 8f64.to_radians(), h);
        let deg: Vec<i64> = m4.nodes.iter().map(|n| n.0.to_degrees().round() as i64).collect();
        assert_eq!(deg, [0, 2, 4, 6, 8, 10]);
        assert_eq!(m4.pinned, [false, true, true, false, false, true]);
        assert_eq!(m4.parameter_count(), 4);
    }
}
