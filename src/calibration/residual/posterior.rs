//! The two posteriors, each with its log marginal likelihood and that
//! likelihood's gradient with respect to the log hyperparameters:
//!
//! * exact: `K + σ²I` factored whole, `O(n³)`; used up to the inducing-point
//!   count, where it costs no more than the sparse one;
//! * VFE (Titsias 2009, "Variational learning of inducing variables in sparse
//!   Gaussian processes"): `m` inducing points `Z`, the collapsed bound
//!   `log N(y | 0, Q + σ²I) − tr(K − Q)/(2σ²)` with `Q = K_fu K_uu⁻¹ K_uf`,
//!   `O(n m²)`. Its predictive variance `k** − q** + k*uᵀ Σ k*u` keeps the
//!   `k** − q**` term, so it returns to the prior `s²` away from `Z`, where a
//!   DTC/SoR variance would fall to zero.
//!
//! The three residual axes are three outputs sharing the kernel and the noise:
//! one factorisation serves all three, and the likelihood is their sum.
//! Computations follow the stable forms of GPflow's `SGPR` (`A = L⁻¹K_uf/σ`,
//! `B = I + AAᵀ`); the gradient is derived by hand in those terms and checked
//! against finite differences in the tests.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::llt;
use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve::{
    solve_lower_triangular_in_place, solve_upper_triangular_in_place,
};
use faer::{Accum, Mat, Par};
use rayon::prelude::*;

use super::kernel::{CHUNK, Kernel, Rows};
use crate::calibration::dense::clear_upper_vector_state;

/// Residual axes (outputs).
pub(super) const AXES: usize = 3;

const LOG_2PI: f64 = 1.837_877_066_409_345_5;

/// Hyperparameters in the optimiser's coordinates.
#[derive(Debug, Clone, Copy)]
pub(super) struct Hyper<'a> {
    pub signal_variance: f64,
    pub noise_variance: f64,
    pub length_scales: &'a [f64],
    pub groups: &'a [usize],
}

impl<'a> Hyper<'a> {
    pub fn kernel(&self) -> Kernel<'a> {
        Kernel {
            signal_variance: self.signal_variance,
            length_scales: self.length_scales,
            groups: self.groups,
        }
    }
}

/// The log marginal likelihood (or VFE bound) and its gradient with respect to
/// `[log s², log σ², log ℓ_0, …]`.
#[derive(Debug, Clone)]
pub(super) struct Evaluation {
    pub value: f64,
    pub gradient: Vec<f64>,
}

/// The lower Cholesky factor of `a`, sequential; `None` when `a` is not
/// numerically positive definite.
pub(super) fn cholesky(mut a: Mat<f64>) -> Option<Mat<f64>> {
    let n = a.nrows();
    let par = Par::Seq;
    llt::factor::cholesky_in_place(
        a.as_mut(),
        Default::default(),
        par,
        MemStack::new(&mut MemBuffer::new(
            llt::factor::cholesky_in_place_scratch::<f64>(n, par, Default::default()),
        )),
        Default::default(),
    )
    .ok()?;
    clear_upper_vector_state();
    Some(Mat::from_fn(
        n,
        n,
        |i, j| if i >= j { a[(i, j)] } else { 0.0 },
    ))
}

fn lower_solve(l: &Mat<f64>, mut rhs: Mat<f64>) -> Mat<f64> {
    solve_lower_triangular_in_place(l.as_ref(), rhs.as_mut(), Par::Seq);
    clear_upper_vector_state();
    rhs
}

/// `L⁻ᵀ rhs`.
fn upper_solve(l: &Mat<f64>, mut rhs: Mat<f64>) -> Mat<f64> {
    solve_upper_triangular_in_place(l.transpose(), rhs.as_mut(), Par::Seq);
    clear_upper_vector_state();
    rhs
}

/// `(L Lᵀ)⁻¹`.
fn inverse_from_factor(l: &Mat<f64>) -> Mat<f64> {
    let n = l.nrows();
    upper_solve(l, lower_solve(l, Mat::identity(n, n)))
}

fn product(a: faer::MatRef<'_, f64>, b: faer::MatRef<'_, f64>) -> Mat<f64> {
    let mut out = Mat::zeros(a.nrows(), b.ncols());
    matmul(out.as_mut(), Accum::Replace, a, b, 1.0, Par::Seq);
    clear_upper_vector_state();
    out
}

fn elementwise_dot(a: &Mat<f64>, b: &Mat<f64>) -> f64 {
    let mut sum = 0.0;
    for j in 0..a.ncols() {
        for i in 0..a.nrows() {
            sum += a[(i, j)] * b[(i, j)];
        }
    }
    sum
}

fn identity(i: usize, j: usize) -> f64 {
    if i == j { 1.0 } else { 0.0 }
}

fn scale(a: &mut Mat<f64>, factor: f64) {
    for j in 0..a.ncols() {
        for i in 0..a.nrows() {
            a[(i, j)] *= factor;
        }
    }
}

fn add_into(total: &mut Mat<f64>, part: &Mat<f64>) {
    for j in 0..total.ncols() {
        for i in 0..total.nrows() {
            total[(i, j)] += part[(i, j)];
        }
    }
}

fn column_squared(a: &Mat<f64>, j: usize) -> f64 {
    (0..a.nrows()).map(|i| a[(i, j)] * a[(i, j)]).sum()
}

fn trace(a: &Mat<f64>) -> f64 {
    (0..a.nrows()).map(|i| a[(i, i)]).sum()
}

fn targets(y: &[[f64; AXES]], start: usize, end: usize) -> Mat<f64> {
    Mat::from_fn(end - start, AXES, |i, a| y[start + i][a])
}

/// Per prediction row: the mean (mm) and the latent variance (mm²).
pub(super) type Predicted = ([f64; AXES], f64);

/// The exact posterior: `L` of `K + σ²I` (plus jitter·s² on the diagonal)
/// and `α = (K + σ²I)⁻¹ Y`.
#[derive(Debug, Clone)]
pub(super) struct Exact {
    factor: Mat<f64>,
    alpha: Mat<f64>,
    pub log_likelihood: f64,
}

impl Exact {
    /// `None` when `K + σ²I` is not positive definite.
    pub fn new(hyper: &Hyper<'_>, x: Rows<'_>, y: &[[f64; AXES]], jitter: f64) -> Option<Self> {
        Self::evaluate(hyper, x, y, jitter, false).map(|(exact, _)| exact)
    }

    /// The posterior and, if `gradient`, the likelihood's gradient:
    /// `∂F/∂θ = tr(G ∂K_y/∂θ)` with `G = ½(ααᵀ − p K_y⁻¹)`.
    pub fn evaluate(
        hyper: &Hyper<'_>,
        x: Rows<'_>,
        y: &[[f64; AXES]],
        jitter: f64,
        gradient: bool,
    ) -> Option<(Self, Option<Evaluation>)> {
        let n = x.len();
        let kernel = hyper.kernel();
        let k = kernel.matrix(x, x);
        let diagonal = hyper.noise_variance + jitter * hyper.signal_variance;
        let ky = Mat::from_fn(n, n, |i, j| k[(i, j)] + diagonal * identity(i, j));
        let factor = cholesky(ky)?;
        let targets = targets(y, 0, n);
        let alpha = upper_solve(&factor, lower_solve(&factor, targets.clone()));
        let log_det: f64 = (0..n).map(|i| 2.0 * factor[(i, i)].ln()).sum();
        let p = AXES as f64;
        let log_likelihood = -0.5 * elementwise_dot(&targets, &alpha)
            - 0.5 * p * log_det
            - 0.5 * p * n as f64 * LOG_2PI;
        let evaluation = gradient.then(|| {
            let inverse = inverse_from_factor(&factor);
            let outer = product(alpha.as_ref(), alpha.transpose());
            let g = Mat::from_fn(n, n, |i, j| 0.5 * (outer[(i, j)] - p * inverse[(i, j)]));
            let mut gradient = vec![
                elementwise_dot(&g, &k) + jitter * hyper.signal_variance * trace(&g),
                hyper.noise_variance * trace(&g),
            ];
            gradient.extend(kernel.log_length_scale_gradient(x, x, &g, &k));
            Evaluation {
                value: log_likelihood,
                gradient,
            }
        });
        Some((
            Exact {
                factor,
                alpha,
                log_likelihood,
            },
            evaluation,
        ))
    }

    /// Mean `K*ᵀα` and latent variance `s² − ‖L⁻¹k*‖²`.
    pub fn predict(&self, hyper: &Hyper<'_>, x: Rows<'_>, at: Rows<'_>) -> Vec<Predicted> {
        let kernel = hyper.kernel();
        chunks_of(at.len())
            .into_par_iter()
            .flat_map_iter(|(start, end)| {
                let cross = kernel.matrix(x, at.slice(start, end));
                let mean = product(cross.transpose(), self.alpha.as_ref());
                let v = lower_solve(&self.factor, cross);
                (0..end - start)
                    .map(|j| {
                        let explained = column_squared(&v, j);
                        (
                            std::array::from_fn(|a| mean[(j, a)]),
                            hyper.signal_variance - explained,
                        )
                    })
                    .collect::<Vec<_>>()
            })
            .collect()
    }
}

fn chunks_of(n: usize) -> Vec<(usize, usize)> {
    (0..n.div_ceil(CHUNK))
        .map(|c| (c * CHUNK, ((c + 1) * CHUNK).min(n)))
        .collect()
}

/// The VFE posterior: `L` of `K_uu` (+ jitter·s²·I), `L_B` of `B`, and
/// `c = L_B⁻¹ A Y / σ`.
#[derive(Debug, Clone)]
pub(super) struct Sparse {
    factor: Mat<f64>,
    factor_b: Mat<f64>,
    c: Mat<f64>,
    pub log_likelihood: f64,
}

/// One chunk of rows' share of the first pass.
struct ChunkPass {
    u: Mat<f64>,
    a: Mat<f64>,
    aat: Mat<f64>,
    ay: Mat<f64>,
}

impl Sparse {
    /// `None` when `K_uu` or `B` is not positive definite.
    pub fn new(
        hyper: &Hyper<'_>,
        x: Rows<'_>,
        z: Rows<'_>,
        y: &[[f64; AXES]],
        jitter: f64,
    ) -> Option<Self> {
        Self::evaluate(hyper, x, z, y, jitter, false).map(|(sparse, _)| sparse)
    }

    /// The posterior and, if `gradient`, the bound's gradient. With `M = K_uu +
    /// K_uf K_fu/σ²`, `β = M⁻¹K_uf Y/σ²` and `p` axes, the gradient with respect
    /// to `K_uu` is `G_K = p/2 (K_uu⁻¹ − M⁻¹) − ½ββᵀ − p/(2σ²) K_uu⁻¹K_uf K_fu K_uu⁻¹`
    /// and with respect to `K_uf` is `G_U = [p(K_uu⁻¹ − M⁻¹)K_uf + β(Yᵀ − βᵀK_uf)]/σ²`,
    /// both rewritten in `L`, `A`, `B` below; then `∂F/∂log s² = Σ G_K∘K_uu +
    /// Σ G_U∘K_uf − p·n·s²/(2σ²)` and each log length scale contracts `G_K`
    /// and `G_U` with the kernel's derivative.
    pub fn evaluate(
        hyper: &Hyper<'_>,
        x: Rows<'_>,
        z: Rows<'_>,
        y: &[[f64; AXES]],
        jitter: f64,
        gradient: bool,
    ) -> Option<(Self, Option<Evaluation>)> {
        let (n, m) = (x.len(), z.len());
        let p = AXES as f64;
        let s2 = hyper.signal_variance;
        let noise = hyper.noise_variance;
        let sigma = noise.sqrt();
        let kernel = hyper.kernel();
        let kuu0 = kernel.matrix(z, z);
        let kuu = Mat::from_fn(m, m, |i, j| kuu0[(i, j)] + jitter * s2 * identity(i, j));
        let factor = cholesky(kuu.clone())?;
        let chunks = chunks_of(n);
        let passes: Vec<ChunkPass> = chunks
            .par_iter()
            .map(|(start, end)| {
                let u = kernel.matrix(z, x.slice(*start, *end));
                let mut a = lower_solve(&factor, u.clone());
                scale(&mut a, 1.0 / sigma);
                let aat = product(a.as_ref(), a.transpose());
                let ay = product(a.as_ref(), targets(y, *start, *end).as_ref());
                ChunkPass { u, a, aat, ay }
            })
            .collect();
        let mut aat = Mat::<f64>::zeros(m, m);
        let mut ay = Mat::<f64>::zeros(m, AXES);
        for pass in &passes {
            add_into(&mut aat, &pass.aat);
            add_into(&mut ay, &pass.ay);
        }
        let b = Mat::from_fn(m, m, |i, j| aat[(i, j)] + identity(i, j));
        let factor_b = cholesky(b)?;
        let mut c = lower_solve(&factor_b, ay);
        scale(&mut c, 1.0 / sigma);
        let y_squared: f64 = y.iter().flatten().map(|v| v * v).sum();
        let c_squared = elementwise_dot(&c, &c);
        let log_det_b: f64 = (0..m).map(|i| factor_b[(i, i)].ln()).sum();
        let nf = n as f64;
        let log_likelihood = -0.5 * p * nf * LOG_2PI
            - p * log_det_b
            - 0.5 * p * nf * noise.ln()
            - 0.5 * y_squared / noise
            + 0.5 * c_squared
            - 0.5 * p * nf * s2 / noise
            + 0.5 * p * trace(&aat);
        let evaluation = gradient.then(|| {
            // G_K = L⁻ᵀ [p/2 (I − B⁻¹ − AAᵀ)] L⁻¹ − ½ββᵀ, β = L⁻ᵀ L_B⁻ᵀ c.
            let b_inverse = inverse_from_factor(&factor_b);
            let inner = Mat::from_fn(m, m, |i, j| {
                0.5 * p * (identity(i, j) - b_inverse[(i, j)] - aat[(i, j)])
            });
            let half = upper_solve(&factor, inner);
            let beta = upper_solve(&factor, upper_solve(&factor_b, c.clone()));
            let first = upper_solve(&factor, half.transpose().to_owned());
            let g_k = Mat::from_fn(m, m, |i, j| {
                first[(i, j)] - 0.5 * (0..AXES).map(|a| beta[(i, a)] * beta[(j, a)]).sum::<f64>()
            });
            let mut gradient_s2 = elementwise_dot(&g_k, &kuu) - 0.5 * p * nf * s2 / noise;
            let mut gradient_ell = kernel.log_length_scale_gradient(z, z, &g_k, &kuu0);
            // G_U = (p/σ) P A + (1/σ²) β (Yᵀ − βᵀU), P = L⁻ᵀ(I − B⁻¹); per chunk.
            let projector = upper_solve(
                &factor,
                Mat::from_fn(m, m, |i, j| identity(i, j) - b_inverse[(i, j)]),
            );
            let partials: Vec<(f64, f64, Vec<f64>)> = chunks
                .par_iter()
                .zip(passes.par_iter())
                .map(|((start, end), pass)| {
                    let mut g_u = product(projector.as_ref(), pass.a.as_ref());
                    scale(&mut g_u, p / sigma);
                    let beta_u = product(beta.transpose(), pass.u.as_ref());
                    let fitted_squared = elementwise_dot(&beta_u, &beta_u);
                    let misfit = Mat::from_fn(AXES, end - start, |a, i| {
                        (y[start + i][a] - beta_u[(a, i)]) / noise
                    });
                    matmul(
                        g_u.as_mut(),
                        Accum::Add,
                        beta.as_ref(),
                        misfit.as_ref(),
                        1.0,
                        Par::Seq,
                    );
                    clear_upper_vector_state();
                    let ell =
                        kernel.log_length_scale_gradient(z, x.slice(*start, *end), &g_u, &pass.u);
                    (elementwise_dot(&g_u, &pass.u), fitted_squared, ell)
                })
                .collect();
            let mut fitted_squared = 0.0;
            for (s2_part, fitted, ell) in &partials {
                gradient_s2 += s2_part;
                fitted_squared += fitted;
                for (g, e) in gradient_ell.iter_mut().zip(ell) {
                    *g += e;
                }
            }
            let gradient_noise = 0.5 * p * elementwise_dot(&b_inverse, &aat) - 0.5 * p * nf
                + 0.5 * y_squared / noise
                - c_squared
                + 0.5 * fitted_squared / noise
                + 0.5 * p * nf * s2 / noise
                - 0.5 * p * trace(&aat);
            let mut gradient = vec![gradient_s2, gradient_noise];
            gradient.extend(gradient_ell);
            Evaluation {
                value: log_likelihood,
                gradient,
            }
        });
        Some((
            Sparse {
                factor,
                factor_b,
                c,
                log_likelihood,
            },
            evaluation,
        ))
    }

    /// Mean `V₂ᵀc` and latent variance `s² − ‖V₁‖² + ‖V₂‖²` with
    /// `V₁ = L⁻¹k_u*`, `V₂ = L_B⁻¹V₁`.
    pub fn predict(&self, hyper: &Hyper<'_>, z: Rows<'_>, at: Rows<'_>) -> Vec<Predicted> {
        let kernel = hyper.kernel();
        chunks_of(at.len())
            .into_par_iter()
            .flat_map_iter(|(start, end)| {
                let v1 = lower_solve(&self.factor, kernel.matrix(z, at.slice(start, end)));
                let v2 = lower_solve(&self.factor_b, v1.clone());
                let mean = product(v2.transpose(), self.c.as_ref());
                (0..end - start)
                    .map(|j| {
                        let q = column_squared(&v1, j);
                        let r = column_squared(&v2, j);
                        (
                            std::array::from_fn(|a| mean[(j, a)]),
                            hyper.signal_variance - q + r,
                        )
                    })
                    .collect::<Vec<_>>()
            })
            .collect()
    }
}
