//! The batched forward pass with optional forward-mode tangents (formulas in the parent).

use faer::{MatRef, Par};

use super::Mlp;
use crate::nn::code::CodeBatch;
use crate::nn::error::NnError;
use crate::nn::lipschitz::normalize;
use crate::nn::matrix::{Buf, for_cols, for_cols2, for_cols3, matmul_into};
use crate::nn::real::Real;
use crate::nn::tape::{LayerTape, Pass, Tape};

impl<T: Real> Mlp<T> {
    /// Batched forward pass over the N points (rows) of `x` (N × input_dim), recording what
    /// `pass` asks for on `tape` (read the outputs with [`Tape::output`], the Jacobian with
    /// [`Tape::jacobian`]). `codes` is required exactly when the network has a code.
    ///
    /// `Pass::Value` runs the points in fixed-size row chunks, each through all layers while
    /// its activations stay in cache, the chunks split over `par`'s tasks. The recording
    /// passes run layer by layer over the whole batch: dense products with faer under `par`,
    /// element-wise work split over columns. Either way the bits do not depend on `par`.
    pub fn forward(
        &self,
        x: MatRef<'_, T>,
        codes: Option<&CodeBatch<T>>,
        pass: Pass,
        tape: &mut Tape<T>,
        par: Par,
    ) -> Result<(), NnError> {
        self.prepare(x.nrows(), x.ncols(), codes, pass, tape)?;
        match pass {
            Pass::Value => self.forward_value(x, tape, par),
            Pass::Gradient | Pass::Jacobian => self.forward_recorded(x, pass, tape, par),
        }
        tape.pass = Some(pass);
        Ok(())
    }

    /// Validates the input shape (N × `input_cols`) and the codes; sets the tape's sizes, codes and code ranges; computes each
    /// layer's effective weight (Lipschitz layers) and its bias per code run, b + W̃_z z_g.
    pub(super) fn prepare(
        &self,
        n: usize,
        input_cols: usize,
        codes: Option<&CodeBatch<T>>,
        pass: Pass,
        tape: &mut Tape<T>,
    ) -> Result<(), NnError> {
        let din = self.spec.input_dim;
        if input_cols != din {
            return Err(NnError::Shape {
                what: "network input",
                expected: (n, din),
                found: (n, input_cols),
            });
        }
        tape.pass = None;
        tape.has_backward = false;
        match (self.spec.code_dim, codes) {
            (0, None) => {
                tape.codes.clear();
                tape.code_dim = 0;
                tape.ranges.clear();
                tape.ranges.push(0..n);
            }
            (0, Some(_)) => return Err(NnError::UnexpectedCode),
            (k, None) => return Err(NnError::MissingCode(k)),
            (k, Some(c)) => {
                if c.dim() != k {
                    return Err(NnError::CodeDim {
                        expected: k,
                        found: c.dim(),
                    });
                }
                tape.ranges = c.ranges(n)?;
                tape.codes.clear();
                tape.codes.extend_from_slice(c.values());
                tape.code_dim = k;
            }
        }
        tape.n = n;
        tape.d = if pass.tangents() { din } else { 0 };
        tape.layers
            .resize_with(self.layout.len(), LayerTape::default);
        let cd = tape.code_dim;
        for (l, lt) in tape.layers.iter_mut().enumerate() {
            let lay = self.layout[l];
            let (out, fan_in) = (lay.out_dim, lay.fan_in());
            if let Some(ci) = lay.c {
                lt.w_eff.reshape(out, fan_in);
                lt.row_sums.resize(out, T::ZERO);
                normalize(
                    &self.params[lay.w..lay.b],
                    out,
                    fan_in,
                    self.params[ci],
                    lt.w_eff.as_mut_slice(),
                    &mut lt.row_sums,
                );
            }
            let b = &self.params[lay.b..lay.b + out];
            let mut bias = std::mem::take(&mut lt.bias);
            bias.clear();
            let w_full = self.weight(l, lt);
            for g in 0..tape.ranges.len() {
                for j in 0..out {
                    let mut v = b[j];
                    for k in 0..lay.code_dim {
                        v += w_full[(j, lay.in_dim + k)] * tape.codes[g * cd + k];
                    }
                    bias.push(v);
                }
            }
            lt.bias = bias;
        }
        Ok(())
    }

    /// The `Gradient`/`Jacobian` pass: whole batch, layer by layer, recording σ′ (σ″ and the
    /// tangents for `Jacobian`).
    fn forward_recorded(&self, x: MatRef<'_, T>, pass: Pass, tape: &mut Tape<T>, par: Par) {
        let (n, d) = (tape.n, tape.d);
        let dn = d * n;
        let tangents = pass.tangents();
        let Tape {
            x: tx,
            xt,
            ranges,
            layers,
            ..
        } = tape;
        tx.copy_from(x);
        if tangents {
            xt.reshape_zeroed(dn, d);
            for k in 0..d {
                xt.col_mut(k)[k * n..(k + 1) * n].fill(T::ONE);
            }
        }
        let ranges = &*ranges;
        for l in 0..self.layout.len() {
            let lay = self.layout[l];
            let act = self.spec.layers[l].activation;
            let (prev, rest) = layers.split_at_mut(l);
            let lt = &mut rest[0];
            let (a, at): (&Buf<T>, &Buf<T>) = if l == 0 {
                (tx, xt)
            } else {
                (&prev[l - 1].h, &prev[l - 1].ht)
            };
            let out = lay.out_dim;
            let LayerTape {
                h,
                d1,
                d2,
                zt,
                ht,
                w_eff,
                bias,
                ..
            } = lt;
            let w_full = if lay.c.is_some() {
                w_eff.view()
            } else {
                MatRef::from_column_major_slice(&self.params[lay.w..lay.b], out, lay.fan_in())
            };
            let w_h = w_full.subcols(0, lay.in_dim);

            // z = a W̃_hᵀ, then h = σ(z + b + W̃_z z_g) per code run.
            h.reshape(n, out);
            matmul_into(h.view_mut(), false, a.view(), w_h.transpose(), par);
            let bias = &*bias;
            d1.reshape(n, out);
            if tangents {
                d2.reshape(n, out);
                for_cols3(par, h, d1, d2, |j, hc, c1, c2| {
                    for (g, r) in ranges.iter().enumerate() {
                        let b = bias[g * out + j];
                        let (c1, c2) = (&mut c1[r.clone()], &mut c2[r.clone()]);
                        act.apply(&mut hc[r.clone()], b, Some(c1), Some(c2));
                    }
                });
            } else {
                for_cols2(par, h, d1, |j, hc, dc| {
                    for (g, r) in ranges.iter().enumerate() {
                        let b = bias[g * out + j];
                        act.apply(&mut hc[r.clone()], b, Some(&mut dc[r.clone()]), None);
                    }
                });
            }

            if tangents {
                // ż_k = ȧ_k W̃_hᵀ (all k in one product), ḣ_k = σ′(z) ⊙ ż_k.
                zt.reshape(dn, out);
                matmul_into(zt.view_mut(), false, at.view(), w_h.transpose(), par);
                ht.reshape(dn, out);
                let (d1r, ztr) = (&*d1, &*zt);
                for_cols(par, ht, |j, hc| {
                    let dc = d1r.col(j);
                    let zc = ztr.col(j);
                    for k in 0..d {
                        let (hk, zk) = (&mut hc[k * n..(k + 1) * n], &zc[k * n..(k + 1) * n]);
                        for ((o, &z), &s) in hk.iter_mut().zip(zk).zip(dc) {
                            *o = s * z;
                        }
                    }
                });
            }
        }
    }
}
