//! Settings of the super-resolved luminance map ([`SrSettings`], [`SrDiagnostics`]) and what a
//! solve reports ([`SrInfo`]). Tests: those of [`super`].

/// Settings of the super-resolved luminance map.
#[derive(Clone, Debug)]
pub struct SrSettings {
    /// Sub-pixel positions per axis (S): the pixel integral uses S² rays.
    pub subsamples: u32,
    /// TV weight λ (in units of the mean radiance, at 2.5 pixels per unknown).
    pub lambda: f32,
    /// IRLS floor ε of |∇B| (units of the mean radiance).
    pub eps: f32,
    /// Exponent p of the edge penalty `(|∇B|² + ε²)^{p/2}`: 1 = total variation (with the
    /// IRLS weight `λ/max(|∇B|, ε)`), < 1 = a non-convex sparse-gradient prior that shrinks strong
    /// edges (the texture's thin lines) less than TV at the same smoothing of flat areas.
    pub exponent: f32,
    /// IRLS reweightings (at most: they stop once a reweighting starts within the tolerance,
    /// see [`SrSettings::cg_tolerance`]).
    pub irls: usize,
    /// Conjugate-gradient iterations per reweighting (at most).
    pub cg_iters: usize,
    /// Stop rule of the conjugate gradients, in units of the photos' noise: a reweighting's CG
    /// stops once, in every channel, the Jacobi-preconditioned residual `rᵀD⁻¹r` is at most
    /// `(τ σ_row)² · m` (m unknowns, σ_row the standard deviation the photos' relative noise σ
    /// gives a weighted row), i.e. once the correction still to come is, as an rms over the
    /// texels, τ times the noise of a texel's own estimate (D = diag of the normal equations:
    /// a texel's estimate from its pixels has variance σ_row²/D_jj, so `rᵀD⁻¹r ≈ Σ D_jj e_j²`
    /// is the remaining error in units of that noise). The IRLS loop stops when a reweighting
    /// starts within it (the new weights moved the solution by less than that). 0 = always run
    /// `irls` × `cg_iters`; also the fallback when the noise is not measured.
    pub cg_tolerance: f32,
    /// Minimum total pixel weight for a texel to count as observed (default 1/16: one of the
    /// 4 × 4 sub-pixel rays' worth; a texel seen at a grazing angle takes a small share of each
    /// pixel whose footprint covers many texels, and the solve's value there, fitted to those
    /// pixels' averages, beats inpainting it).
    pub min_weight: f32,
    /// Relative noise σ_ref above which the prior weight is scaled: the reading on the reference
    /// Cornell box's back wall, where [`SrSettings::lambda`] was chosen, of the photo-noise
    /// estimate over all texels (0.022; the estimate now used,
    /// [`super::photo_noise::relative_photo_noise`] over the flattest texels, reads 0.0137 there:
    /// the back wall's texture had inflated it; kept, docs/delight.md "Texture detail is not
    /// noise"). Where the pixel rows per unknown are below the reference density (2.5), the prior
    /// weight is multiplied by `max(1, (σ/σ_ref)²)` with σ the photos' relative noise measured on
    /// the object (the MAP weight for noisier photos); when it cannot be
    /// measured (no texel seen by two views) the solve returns `None` (the caller keeps the
    /// back-projected map). 0 = no scaling.
    pub reference_noise: f32,
    /// Error-analysis hooks (all off by default; no effect on the results unless `synth` is set).
    pub diagnostics: SrDiagnostics,
}

/// Error-analysis hooks of the super-resolution (see the module documentation); [`Default`] =
/// all off.
#[derive(Clone, Debug, Default)]
pub struct SrDiagnostics {
    /// A radiance map (EXR on the atlas grid, e.g. the true one) whose operator residual against
    /// each photo is printed; only with [`SrDiagnostics::residual_dir`].
    pub truth: Option<std::path::PathBuf>,
    /// Directory of the per-view residual images (`<view>_res.exr`, `<view>_z.exr`); only with
    /// [`SrDiagnostics::truth`].
    pub residual_dir: Option<std::path::PathBuf>,
    /// Replace the photos by the truth through the operator plus noise (`stderr`, `stderrcorr`,
    /// a relative level such as `0.02`, `shuffle`, `relshuffle`, `clipK`); only with `truth` and
    /// `residual_dir`.
    pub synth: Option<String>,
    /// Sub-pixel rays per axis of the synthetic photos (0 = those of the solve).
    pub synth_subsamples: u32,
    /// Print the problem size and the conjugate-gradient residuals.
    pub trace: bool,
}

impl Default for SrSettings {
    fn default() -> Self {
        SrSettings {
            subsamples: 4,
            lambda: 0.004,
            eps: 0.022,
            exponent: 0.5,
            irls: 6,
            cg_iters: 60,
            cg_tolerance: 0.005,
            min_weight: 0.0625,
            reference_noise: 0.022,
            diagnostics: SrDiagnostics::default(),
        }
    }
}

/// What a super-resolution solve used: the photos' relative noise measured on the object
/// ([`super::photo_noise::relative_photo_noise`]; `None` when not measured) and the prior weight
/// λ after the density and noise scaling.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SrInfo {
    /// Relative noise σ of the photos on the object.
    pub photo_noise: Option<f64>,
    /// Prior weight used.
    pub lambda: f32,
    /// IRLS reweightings run.
    pub reweightings: usize,
    /// Conjugate-gradient steps run, summed over the reweightings.
    pub cg_steps: usize,
    /// The last reweighting's final residual in units of the noise (see
    /// [`SrSettings::cg_tolerance`]): `max_c sqrt(rᵀD⁻¹r / (m σ_row²))`; `None` when the noise
    /// was not measured.
    pub residual_to_noise: Option<f64>,
    /// The last reweighting's final residual relative to its start, `max_c sqrt(rᵀD⁻¹r /
    /// r₀ᵀD⁻¹r₀)`.
    pub relative_residual: f64,
    /// Whether the stop rule ended the solve (else the step limits did).
    pub converged: bool,
}
