//! The hand-written backward pass through the primal and tangent computation (formulas in
//! the parent).

use faer::{MatRef, Par};

use super::Mlp;
use crate::nn::error::NnError;
use crate::nn::lipschitz::normalize_backward;
use crate::nn::matrix::{Buf, col_sums_into, for_cols, for_cols2, matmul_into};
use crate::nn::real::Real;
use crate::nn::tape::{Pass, Tape};

impl<T: Real> Mlp<T> {
    /// Backward pass for a loss L(y, ∂y/∂x) over the batch on `tape`: `dy` = ∂L/∂y (N × out)
    /// and, after a `Jacobian` pass, `dj` = ∂L/∂J in the stacked layout of
    /// [`Tape::jacobian`] (d·N × out); `None` means zero. **Adds** ∂L/∂θ into `grad`
    /// (zero it at the start of an iteration; accumulate over chunks of a large batch), and
    /// leaves ∂L/∂x in [`Tape::input_grad`] and ∂L/∂z_g in [`Tape::code_grad`].
    /// The parameters must be those of the forward pass.
    pub fn backward(
        &self,
        tape: &mut Tape<T>,
        dy: Option<MatRef<'_, T>>,
        dj: Option<MatRef<'_, T>>,
        grad: &mut [T],
        par: Par,
    ) -> Result<(), NnError> {
        let needed = if dj.is_some() {
            Pass::Jacobian
        } else {
            Pass::Gradient
        };
        match tape.pass {
            Some(Pass::Jacobian) => {}
            Some(Pass::Gradient) if dj.is_none() => {}
            found => return Err(NnError::Pass { needed, found }),
        }
        self.check_grad_len(grad)?;
        let (n, d) = (tape.n, tape.d);
        let dn = d * n;
        let n_layers = self.layout.len();
        let out_dim = self.output_dim();
        if tape.layers.len() != n_layers
            || tape.x.cols() != self.spec.input_dim
            || tape.layers[n_layers - 1].h.cols() != out_dim
        {
            return Err(NnError::InvalidSpec(
                "the tape was recorded by a different network".into(),
            ));
        }
        if let Some(dy) = dy
            && (dy.nrows(), dy.ncols()) != (n, out_dim)
        {
            return Err(NnError::Shape {
                what: "output gradient",
                expected: (n, out_dim),
                found: (dy.nrows(), dy.ncols()),
            });
        }
        if let Some(dj) = dj
            && (dj.nrows(), dj.ncols()) != (dn, out_dim)
        {
            return Err(NnError::Shape {
                what: "Jacobian gradient",
                expected: (dn, out_dim),
                found: (dj.nrows(), dj.ncols()),
            });
        }

        let Tape {
            x,
            xt,
            codes,
            code_dim,
            ranges,
            layers,
            gh,
            gh2,
            gt,
            gt2,
            gw,
            seg_sums,
            input_grad,
            code_grad,
            ..
        } = tape;
        let cd = *code_dim;
        let n_codes = ranges.len();
        match dy {
            Some(dy) => gh.copy_from(dy),
            None => gh.reshape_zeroed(n, out_dim),
        }
        let tan = dj.is_some();
        if let Some(dj) = dj {
            gt.copy_from(dj);
        }
        code_grad.clear();
        code_grad.resize(n_codes * cd, T::ZERO);

        for l in (0..n_layers).rev() {
            let lay = self.layout[l];
            let act = self.spec.layers[l].activation;
            let lt = &layers[l];
            let (a, at): (&Buf<T>, &Buf<T>) = if l == 0 {
                (x, xt)
            } else {
                (&layers[l - 1].h, &layers[l - 1].ht)
            };
            let (out, in_dim) = (lay.out_dim, lay.in_dim);

            // 1. Pre-activation adjoints, in place: gh ← z̄, gt ← ż̄.
            let d1 = &lt.d1;
            if tan {
                let (d2, zt) = (&lt.d2, &lt.zt);
                let linear = act.is_linear();
                for_cols2(par, gh, gt, |j, ghc, gtc| {
                    let d1c = d1.col(j);
                    for (g, &s) in ghc.iter_mut().zip(d1c) {
                        *g *= s;
                    }
                    if !linear {
                        let (d2c, ztc) = (d2.col(j), zt.col(j));
                        for k in 0..d {
                            let zk = &ztc[k * n..(k + 1) * n];
                            let tk = &gtc[k * n..(k + 1) * n];
                            for (((g, &s2), &z), &t) in ghc.iter_mut().zip(d2c).zip(zk).zip(tk) {
                                *g += s2 * (z * t);
                            }
                        }
                    }
                    for k in 0..d {
                        for (t, &s) in gtc[k * n..(k + 1) * n].iter_mut().zip(d1c) {
                            *t *= s;
                        }
                    }
                });
            } else {
                for_cols(par, gh, |j, ghc| {
                    for (g, &s) in ghc.iter_mut().zip(d1.col(j)) {
                        *g *= s;
                    }
                });
            }

            // 2. ∂L/∂W̃ into gw (out × fan_in), ∂L/∂b, code terms.
            gw.reshape(out, lay.fan_in());
            matmul_into(
                gw.view_mut().subcols_mut(0, in_dim),
                false,
                gh.view().transpose(),
                a.view(),
                par,
            );
            if tan {
                matmul_into(
                    gw.view_mut().subcols_mut(0, in_dim),
                    true,
                    gt.view().transpose(),
                    at.view(),
                    par,
                );
            }
            seg_sums.resize(n_codes * out, T::ZERO);
            for (g, r) in ranges.iter().enumerate() {
                col_sums_into(gh, r.clone(), &mut seg_sums[g * out..(g + 1) * out]);
            }
            for j in 0..out {
                let mut s = T::ZERO;
                for g in 0..n_codes {
                    s += seg_sums[g * out + j];
                }
                grad[lay.b + j] += s;
            }
            let w_full = self.weight(l, lt);
            if lay.code_dim > 0 {
                for k in 0..lay.code_dim {
                    let col = gw.col_mut(in_dim + k);
                    for (j, v) in col.iter_mut().enumerate() {
                        let mut s = T::ZERO;
                        for g in 0..n_codes {
                            s += seg_sums[g * out + j] * codes[g * cd + k];
                        }
                        *v = s;
                    }
                }
                for g in 0..n_codes {
                    for k in 0..lay.code_dim {
                        let mut s = T::ZERO;
                        for j in 0..out {
                            s += w_full[(j, in_dim + k)] * seg_sums[g * out + j];
                        }
                        code_grad[g * cd + k] += s;
                    }
                }
            }

            // 3. Through the normalization to the raw parameters.
            match lay.c {
                Some(ci) => {
                    let gc = normalize_backward(
                        &self.params[lay.w..lay.b],
                        out,
                        self.params[ci],
                        &lt.row_sums,
                        gw.as_slice(),
                        &mut grad[lay.w..lay.b],
                    );
                    grad[ci] += gc;
                }
                None => {
                    for (g, &v) in grad[lay.w..lay.b].iter_mut().zip(gw.as_slice()) {
                        *g += v;
                    }
                }
            }

            // 4. Adjoints of the layer input: ā = z̄ W̃_h, ǡ = ż̄ W̃_h.
            let w_h = w_full.subcols(0, in_dim);
            gh2.reshape(n, in_dim);
            matmul_into(gh2.view_mut(), false, gh.view(), w_h, par);
            std::mem::swap(gh, gh2);
            if tan && l > 0 {
                gt2.reshape(dn, in_dim);
                matmul_into(gt2.view_mut(), false, gt.view(), w_h, par);
                std::mem::swap(gt, gt2);
            }
        }
        std::mem::swap(input_grad, gh);
        tape.has_backward = true;
        Ok(())
    }
}
