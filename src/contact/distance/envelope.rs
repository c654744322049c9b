//! Closed-form gradient and Hessian of a squared distance between two flat features
//! (point, line, plane), by the envelope theorem.
//!
//! Every distance of this module is `d(x) = min_β ‖v(x, β)‖²` with `v = Σᵢ aᵢ(β)·xᵢ` affine in
//! the free parameters β (the closest point's coordinates on an infinite line or plane) and
//! linear in the stencil vertices `xᵢ`: `∂aᵢ/∂β_k = c_{k,i}` are constants. At the minimizer,
//! `D_k·v = 0` with `D_k = Σᵢ c_{k,i}·xᵢ`. Then
//!
//! - gradient: `∂d/∂xᵢ = 2·aᵢ·v` (the β-derivative vanishes at the minimum),
//! - Hessian (value function of a quadratic minimization, `F_xx − F_xβ F_ββ⁻¹ F_βx`):
//!   `∂²d/∂xᵢ∂xⱼ = 2·aᵢaⱼ·N − 2·(m_ij·v vᵀ + aⱼ·v qᵢᵀ + aᵢ·qⱼ vᵀ)`,
//!   where `G_kl = D_k·D_l`, `M = G⁻¹`, `P_k = Σ_l M_kl D_l`, `qᵢ = Σ_k c_{k,i} P_k`,
//!   `m_ij = Σ_kl c_{k,i} M_kl c_{l,j}`, and `N = I − Σ_kl M_kl D_k D_lᵀ` is the projector on
//!   the directions orthogonal to the features (`I` for two points, `I − êêᵀ` for a point
//!   and a line, `n̂n̂ᵀ` for a point and a plane or two lines).
//!
//! No term of the Hessian cancels catastrophically: `N` is formed directly, and the other
//! terms scale with the (small) distance vector `v`.

use nalgebra::Matrix3;

use crate::contact::math::{Matrix12, Vec3, Vector12};

/// The closest-point parametrization of one distance type on a 4-vertex stencil. Stencil
/// vertices that the type does not involve have `aᵢ = c_{k,i} = 0`. Only `a` and `v` are
/// computed up front (all the gradient needs); the Hessian's terms come from `curvature`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Envelope {
    /// `aᵢ`: the distance vector is `v = Σ aᵢ xᵢ`.
    pub a: [f64; 4],
    /// `v`, computed as accurately as the type allows.
    pub v: Vec3,
    curvature: Curvature,
}

/// What the Hessian needs beyond `a` and `v`: the free parameters' coefficients `c_k`,
/// directions `D_k`, `M = G⁻¹`, and the normal projector `N`.
#[derive(Clone, Copy, Debug)]
enum Curvature {
    /// Two points: no parameter, `N = I`.
    Points,
    /// Point and line: `c`, `D = −e`, `M = 1/‖e‖²`, `N = I − eeᵀ/‖e‖²`.
    Line { c: [f64; 4], e: Vec3, ee: f64 },
    /// Point and plane, or two lines: two parameters, `N = nnᵀ/‖n‖²`.
    TwoParameters {
        c: [[f64; 4]; 2],
        d: [Vec3; 2],
        minv: [[f64; 2]; 2],
        n: Vec3,
        nn: f64,
    },
}

impl Envelope {
    /// Two points `xᵢ`, `xⱼ`: `v = xᵢ − xⱼ`, no free parameter.
    pub fn point_point(i: usize, j: usize, x: &[Vec3; 4]) -> Self {
        let mut a = [0.0; 4];
        a[i] = 1.0;
        a[j] = -1.0;
        Self {
            a,
            v: x[i] - x[j],
            curvature: Curvature::Points,
        }
    }

    /// Point `xₚ` and the line through `x₀`, `x₁`: `v = p − e0 − s·e`, `e = e1 − e0`,
    /// `s = (p − e0)·e / ‖e‖²`, one parameter with `c = (p: 0, e0: 1, e1: −1)`, `D = −e`.
    /// Requires `‖e‖ > 0`.
    pub fn point_line(p: usize, e0: usize, e1: usize, x: &[Vec3; 4]) -> Self {
        let e = x[e1] - x[e0];
        let r = x[p] - x[e0];
        let ee = e.norm_squared();
        let s = r.dot(&e) / ee;
        let v = r - s * e;
        let mut a = [0.0; 4];
        a[p] = 1.0;
        a[e0] = s - 1.0;
        a[e1] = -s;
        let mut c = [0.0; 4];
        c[e0] = 1.0;
        c[e1] = -1.0;
        Self {
            a,
            v,
            curvature: Curvature::Line { c, e, ee },
        }
    }

    /// Point `xₚ` and the plane through `x₀, x₁, x₂`: `v = ((p − t0)·n)·n/‖n‖²` with
    /// `n = (t1 − t0) × (t2 − t0)`; barycentric parameters `β₁, β₂` with `D₁ = −(t1 − t0)`,
    /// `D₂ = −(t2 − t0)`. Requires `‖n‖ > 0`.
    pub fn point_plane(p: usize, t: [usize; 3], x: &[Vec3; 4]) -> Self {
        let e1 = x[t[1]] - x[t[0]];
        let e2 = x[t[2]] - x[t[0]];
        let r = x[p] - x[t[0]];
        let n = e1.cross(&e2);
        let nn = n.norm_squared();
        let v = (r.dot(&n) / nn) * n;
        // Barycentric coordinates of the projection: G β = [e1·r, e2·r], det G = ‖n‖².
        let (g11, g12, g22) = (e1.dot(&e1), e1.dot(&e2), e2.dot(&e2));
        let (r1, r2) = (e1.dot(&r), e2.dot(&r));
        let b1 = (g22 * r1 - g12 * r2) / nn;
        let b2 = (g11 * r2 - g12 * r1) / nn;
        let mut a = [0.0; 4];
        a[p] = 1.0;
        a[t[0]] = b1 + b2 - 1.0;
        a[t[1]] = -b1;
        a[t[2]] = -b2;
        let mut c1 = [0.0; 4];
        c1[t[0]] = 1.0;
        c1[t[1]] = -1.0;
        let mut c2 = [0.0; 4];
        c2[t[0]] = 1.0;
        c2[t[2]] = -1.0;
        // G = [[e1·e1, e1·e2], [e1·e2, e2·e2]] (D = −e, signs cancel in G).
        let minv = [[g22 / nn, -g12 / nn], [-g12 / nn, g11 / nn]];
        Self {
            a,
            v,
            curvature: Curvature::TwoParameters {
                c: [c1, c2],
                d: [-e1, -e2],
                minv,
                n,
                nn,
            },
        }
    }

    /// The lines through `a0, a1` and `b0, b1`: `v = ((a0 − b0)·n)·n/‖n‖²` with
    /// `n = (a1 − a0) × (b1 − b0)`; parameters `s, t` of the closest points with
    /// `D_s = a1 − a0`, `D_t = −(b1 − b0)`. Requires `‖n‖ > 0`.
    pub fn line_line(ea: [usize; 2], eb: [usize; 2], x: &[Vec3; 4]) -> Self {
        let u = x[ea[1]] - x[ea[0]];
        let w = x[eb[1]] - x[eb[0]];
        let w0 = x[ea[0]] - x[eb[0]];
        let n = u.cross(&w);
        let nn = n.norm_squared();
        let v = (w0.dot(&n) / nn) * n;
        let (uu, uw, ww) = (u.dot(&u), u.dot(&w), w.dot(&w));
        let (d, e) = (u.dot(&w0), w.dot(&w0));
        let s = (uw * e - ww * d) / nn;
        let t = (uu * e - uw * d) / nn;
        let mut a = [0.0; 4];
        a[ea[0]] = 1.0 - s;
        a[ea[1]] = s;
        a[eb[0]] = t - 1.0;
        a[eb[1]] = -t;
        let mut cs = [0.0; 4];
        cs[ea[0]] = -1.0;
        cs[ea[1]] = 1.0;
        let mut ct = [0.0; 4];
        ct[eb[0]] = 1.0;
        ct[eb[1]] = -1.0;
        // G = [[u·u, −u·w], [−u·w, w·w]], det G = ‖n‖².
        let minv = [[ww / nn, uw / nn], [uw / nn, uu / nn]];
        Self {
            a,
            v,
            curvature: Curvature::TwoParameters {
                c: [cs, ct],
                d: [u, -w],
                minv,
                n,
                nn,
            },
        }
    }

    /// `∇d`, 12 entries: `∂d/∂xᵢ = 2·aᵢ·v`.
    pub fn gradient(&self) -> Vector12 {
        let mut g = Vector12::zeros();
        for i in 0..4 {
            if self.a[i] != 0.0 {
                g.fixed_rows_mut::<3>(3 * i)
                    .copy_from(&(2.0 * self.a[i] * self.v));
            }
        }
        g
    }

    /// `qᵢ`, `m_ij` and `N` of the module documentation.
    fn curvature_terms(&self) -> ([Vec3; 4], [[f64; 4]; 4], Matrix3<f64>) {
        match self.curvature {
            Curvature::Points => ([Vec3::zeros(); 4], [[0.0; 4]; 4], Matrix3::identity()),
            Curvature::Line { c, e, ee } => {
                // M = 1/‖e‖², P = M·D = −e/‖e‖².
                let pk = -e / ee;
                (
                    c.map(|ci| ci * pk),
                    outer(&c, &c, 1.0 / ee),
                    Matrix3::identity() - e * e.transpose() / ee,
                )
            }
            Curvature::TwoParameters { c, d, minv, n, nn } => {
                let p = [
                    minv[0][0] * d[0] + minv[0][1] * d[1],
                    minv[1][0] * d[0] + minv[1][1] * d[1],
                ];
                let q = std::array::from_fn(|i| c[0][i] * p[0] + c[1][i] * p[1]);
                let m = std::array::from_fn(|i| {
                    std::array::from_fn(|j| {
                        let mut sum = 0.0;
                        for k in 0..2 {
                            for l in 0..2 {
                                sum += c[k][i] * minv[k][l] * c[l][j];
                            }
                        }
                        sum
                    })
                });
                (q, m, n * n.transpose() / nn)
            }
        }
    }

    /// `∇²d`, 12×12, from the formula in the module documentation. Exactly symmetric.
    pub fn hessian(&self) -> Matrix12 {
        let (q, m, normal_projector) = self.curvature_terms();
        let mut h = Matrix12::zeros();
        let vvt = self.v * self.v.transpose();
        for i in 0..4 {
            for j in i..4 {
                let (ai, aj) = (self.a[i], self.a[j]);
                let block = 2.0 * ai * aj * normal_projector
                    - 2.0
                        * (m[i][j] * vvt
                            + aj * self.v * q[i].transpose()
                            + ai * q[j] * self.v.transpose());
                h.fixed_view_mut::<3, 3>(3 * i, 3 * j).copy_from(&block);
                if i != j {
                    h.fixed_view_mut::<3, 3>(3 * j, 3 * i)
                        .copy_from(&block.transpose());
                }
            }
        }
        // The diagonal blocks are symmetric in exact arithmetic; make them so in floating point.
        for i in 0..4 {
            let b = h.fixed_view::<3, 3>(3 * i, 3 * i).into_owned();
            h.fixed_view_mut::<3, 3>(3 * i, 3 * i)
                .copy_from(&(0.5 * (b + b.transpose())));
        }
        h
    }
}

/// `s·c₁c₂ᵀ` for coefficient vectors over the 4 stencil vertices.
fn outer(c1: &[f64; 4], c2: &[f64; 4], s: f64) -> [[f64; 4]; 4] {
    std::array::from_fn(|i| std::array::from_fn(|j| s * c1[i] * c2[j]))
}
