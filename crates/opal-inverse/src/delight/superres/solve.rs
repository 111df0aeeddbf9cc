//! The solver of the super-resolution: iteratively reweighted least squares on the edge prior,
//! each reweighting by Jacobi-preconditioned conjugate gradients on the normal equations
//! `(AᵀA + λ Σ_e w_e (e_p − e_q)(e_p − e_q)ᵀ) K = Aᵀy`, warm-started from the previous solution,
//! with the stop rule of [`SrSettings::cg_tolerance`] (the remaining correction against the
//! photos' noise). Per-channel step sizes; the dot products are summed in fixed chunks, so the
//! result does not depend on the thread count. Tests: those of [`super`].

use super::operator::Csr;
use super::settings::SrSettings;
use rayon::prelude::*;

/// The linear system of one object: the weighted operator `A` (rows = pixels, columns =
/// unknown texels), its transpose, the right-hand side `Aᵀy`, and the prior's edges between
/// unknowns as a per-unknown adjacency `(neighbour, edge index)`.
pub(super) struct System {
    pub(super) amat: Csr,
    pub(super) at: Csr,
    pub(super) aty: Vec<[f32; 3]>,
    pub(super) edges: Vec<(u32, u32)>,
    pub(super) adj_ptr: Vec<usize>,
    pub(super) adj: Vec<(u32, u32)>,
}

impl System {
    /// The system from the operator, the weighted observations and the prior's edges.
    pub(super) fn new(amat: Csr, y: &[[f32; 3]], edges: Vec<(u32, u32)>) -> System {
        let m = amat.ncols;
        let at = amat.transpose();
        let mut aty = vec![[0f32; 3]; m];
        at.mul(y, &mut aty);
        // edges as per-texel adjacency: the prior's operator is then a gather, parallel over
        // texels and independent of the thread count
        let mut adj_ptr = vec![0usize; m + 1];
        for e in &edges {
            adj_ptr[e.0 as usize + 1] += 1;
            adj_ptr[e.1 as usize + 1] += 1;
        }
        for j in 0..m {
            adj_ptr[j + 1] += adj_ptr[j];
        }
        let mut fill = adj_ptr.clone();
        let mut adj = vec![(0u32, 0u32); adj_ptr[m]];
        for (k, e) in edges.iter().enumerate() {
            adj[fill[e.0 as usize]] = (e.1, k as u32);
            fill[e.0 as usize] += 1;
            adj[fill[e.1 as usize]] = (e.0, k as u32);
            fill[e.1 as usize] += 1;
        }
        System { amat, at, aty, edges, adj_ptr, adj }
    }

    fn unknowns(&self) -> usize {
        self.amat.ncols
    }

    /// out = (AᵀA + prior) v, with `ax` a scratch vector of the rows.
    fn apply(&self, wts: &[f32], v: &[[f32; 3]], ax: &mut [[f32; 3]], out: &mut [[f32; 3]]) {
        self.amat.mul(v, ax);
        let ax = &*ax;
        let at = &self.at;
        out.par_iter_mut().enumerate().with_min_len(256).for_each(|(j, o)| {
            let mut acc = [0f32; 3];
            for k in at.ptr[j]..at.ptr[j + 1] {
                let (val, r) = (at.val[k], ax[at.col[k] as usize]);
                for c in 0..3 {
                    acc[c] += val * r[c];
                }
            }
            let vj = v[j];
            for &(q, e) in &self.adj[self.adj_ptr[j]..self.adj_ptr[j + 1]] {
                let (w, vq) = (wts[e as usize], v[q as usize]);
                for c in 0..3 {
                    acc[c] += w * (vj[c] - vq[c]);
                }
            }
            *o = acc;
        });
    }
}

/// How a solve ended (see [`super::SrInfo`]).
pub(super) struct Convergence {
    pub(super) reweightings: usize,
    pub(super) cg_steps: usize,
    pub(super) residual_to_noise: Option<f64>,
    pub(super) relative_residual: f64,
    pub(super) converged: bool,
}

/// Deterministic parallel dot product per channel: fixed chunks, partial sums added in order.
fn dot(a: &[[f32; 3]], b: &[[f32; 3]]) -> [f64; 3] {
    const CHUNK: usize = 4096;
    let parts: Vec<[f64; 3]> = a
        .par_chunks(CHUNK)
        .zip(b.par_chunks(CHUNK))
        .map(|(ca, cb)| {
            let mut s = [0f64; 3];
            for (u, v) in ca.iter().zip(cb) {
                for c in 0..3 {
                    s[c] += u[c] as f64 * v[c] as f64;
                }
            }
            s
        })
        .collect();
    parts.iter().fold([0f64; 3], |acc, p| std::array::from_fn(|c| acc[c] + p[c]))
}

/// Solves for `x` (warm start in, solution out) with the prior weight `lambda`. `row_noise2` is
/// the variance a weighted row has from the photos' noise (`None`: not measured; then the
/// step limits alone stop the solve).
pub(super) fn irls(
    sys: &System,
    x: &mut [[f32; 3]],
    lambda: f32,
    row_noise2: Option<f64>,
    s: &SrSettings,
) -> Convergence {
    let m = sys.unknowns();
    let mut diag_a = vec![0f32; m];
    for k in 0..sys.amat.val.len() {
        diag_a[sys.amat.col[k] as usize] += sys.amat.val[k] * sys.amat.val[k];
    }
    // the stop threshold of rᵀD⁻¹r per channel
    let stop = match row_noise2 {
        Some(v) if s.cg_tolerance > 0.0 => Some((s.cg_tolerance as f64).powi(2) * v * m as f64),
        _ => None,
    };
    let mut wts = vec![0f32; sys.edges.len()];
    let mut diag = vec![0f32; m];
    let mut conv = Convergence {
        reweightings: 0,
        cg_steps: 0,
        residual_to_noise: None,
        relative_residual: 1.0,
        converged: false,
    };
    for it in 0..s.irls.max(1) {
        reweight(sys, x, lambda, s, &mut wts);
        // Jacobi preconditioner diag(M)
        diag.par_iter_mut().enumerate().with_min_len(1024).for_each(|(j, d)| {
            let prior: f32 =
                sys.adj[sys.adj_ptr[j]..sys.adj_ptr[j + 1]].iter().map(|&(_, k)| wts[k as usize]).sum();
            *d = (diag_a[j] + prior).max(1e-12);
        });
        let (steps, rz0, rz) = pcg(sys, &wts, &diag, x, stop, s, it);
        conv.reweightings = it + 1;
        conv.cg_steps += steps;
        conv.relative_residual =
            (0..3).map(|c| if rz0[c] > 0.0 { (rz[c] / rz0[c]).sqrt() } else { 0.0 }).fold(0.0, f64::max);
        conv.residual_to_noise =
            row_noise2.map(|v| (0..3).map(|c| (rz[c] / (v * m as f64)).sqrt()).fold(0.0, f64::max));
        conv.converged = stop.is_some_and(|t| (0..3).all(|c| rz[c] <= t));
        // a reweighting that starts within the tolerance: the new weights no longer move the
        // solution by what the noise resolves
        if conv.converged && steps == 0 {
            break;
        }
    }
    conv
}

/// The IRLS weights of the edge prior at `x`.
fn reweight(sys: &System, x: &[[f32; 3]], lambda: f32, s: &SrSettings, wts: &mut [f32]) {
    wts.par_iter_mut().zip(sys.edges.par_iter()).with_min_len(1024).for_each(|(w, e)| {
        let (p, q) = (x[e.0 as usize], x[e.1 as usize]);
        let g = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
        *w = if s.exponent == 1.0 {
            lambda / g.max(s.eps)
        } else {
            lambda * (g * g + s.eps * s.eps).powf(0.5 * (s.exponent - 2.0))
        };
    });
}

/// Jacobi-preconditioned CG of one reweighting from `x`; stops at `s.cg_iters` steps or once
/// `rᵀD⁻¹r ≤ stop` in every channel. Returns (steps, rᵀD⁻¹r at the start, at the end).
fn pcg(
    sys: &System,
    wts: &[f32],
    diag: &[f32],
    x: &mut [[f32; 3]],
    stop: Option<f64>,
    s: &SrSettings,
    it: usize,
) -> (usize, [f64; 3], [f64; 3]) {
    let m = sys.unknowns();
    let mut ax = vec![[0f32; 3]; sys.amat.rows()];
    let mut mx = vec![[0f32; 3]; m];
    sys.apply(wts, x, &mut ax, &mut mx);
    let mut r: Vec<[f32; 3]> = (0..m).map(|j| std::array::from_fn(|c| sys.aty[j][c] - mx[j][c])).collect();
    let mut z: Vec<[f32; 3]> = (0..m).map(|j| r[j].map(|v| v / diag[j])).collect();
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let rz0 = rz;
    let mut mp = mx;
    let trace = s.diagnostics.trace;
    for cg in 0..s.cg_iters {
        if trace && cg % 10 == 0 {
            eprintln!(
                "  irls {it} cg {cg}: rz/rz0 {:.3e}, rz {rz:?}, stop {stop:?}",
                rz.iter().sum::<f64>() / rz0.iter().sum::<f64>()
            );
        }
        if let Some(t) = stop
            && (0..3).all(|c| rz[c] <= t)
        {
            if trace {
                eprintln!("  irls {it}: converged after {cg} CG steps");
            }
            return (cg, rz0, rz);
        }
        sys.apply(wts, &p, &mut ax, &mut mp);
        let pmp = dot(&p, &mp);
        let alpha: [f32; 3] =
            std::array::from_fn(|c| if pmp[c] > 0.0 { (rz[c] / pmp[c]) as f32 } else { 0.0 });
        x.par_iter_mut().zip(r.par_iter_mut()).zip(z.par_iter_mut()).enumerate().with_min_len(1024).for_each(
            |(j, ((xj, rj), zj))| {
                for c in 0..3 {
                    xj[c] += alpha[c] * p[j][c];
                    rj[c] -= alpha[c] * mp[j][c];
                    zj[c] = rj[c] / diag[j];
                }
            },
        );
        let rz_new = dot(&r, &z);
        let beta: [f32; 3] =
            std::array::from_fn(|c| if rz[c] > 0.0 { (rz_new[c] / rz[c]) as f32 } else { 0.0 });
        rz = rz_new;
        p.par_iter_mut().zip(z.par_iter()).with_min_len(1024).for_each(|(pj, zj)| {
            for c in 0..3 {
                pj[c] = zj[c] + beta[c] * pj[c];
            }
        });
    }
    (s.cg_iters, rz0, rz)
}
