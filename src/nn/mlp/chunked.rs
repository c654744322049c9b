//! Data-parallel loss gradients over large batches, for losses that are sums over points
//! (φ's vertex and elastic terms, N_A's actuation term).
//!
//! The N points are cut into chunks of `chunk_rows`; chunk c belongs to lane c mod `lanes`.
//! Each lane runs its chunks in order — forward (`Par::Seq`), the caller's per-chunk loss,
//! backward — accumulating its own gradient; lanes are spread over `par`'s tasks, and the lane
//! results are summed in lane order. The result depends on `chunk_rows` and `lanes`, never on
//! the number of threads, and memory is one chunk's tape per task plus one gradient per lane.

use std::ops::Range;

use faer::{Mat, MatMut, MatRef, Par};
use rayon::prelude::*;

use super::Mlp;
use crate::nn::code::CodeBatch;
use crate::nn::error::NnError;
use crate::nn::matrix::n_tasks;
use crate::nn::real::Real;
use crate::nn::tape::{Pass, Tape};

/// Settings and reusable buffers of [`Mlp::gradient_chunked`].
#[derive(Clone, Debug)]
pub struct ChunkedGradient<T> {
    chunk_rows: usize,
    lanes: usize,
    tapes: Vec<Tape<T>>,
    dys: Vec<Mat<T>>,
    djs: Vec<Mat<T>>,
    lane_grads: Vec<Vec<T>>,
    lane_code_grads: Vec<Vec<T>>,
    lane_loss: Vec<T>,
    /// Per task: (chunk index, chunk input gradient) in processing order.
    input_parts: Vec<Vec<(usize, Mat<T>)>>,
    input_grad: Mat<T>,
    code_grad: Vec<T>,
}

impl<T: Real> ChunkedGradient<T> {
    /// `chunk_rows` points per chunk, `lanes` independent accumulators (≥ the thread count
    /// you will use; 8 is a good default).
    pub fn new(chunk_rows: usize, lanes: usize) -> Result<Self, NnError> {
        if chunk_rows == 0 || lanes == 0 {
            return Err(NnError::InvalidSpec(
                "chunk_rows and lanes must be positive".into(),
            ));
        }
        Ok(ChunkedGradient {
            chunk_rows,
            lanes,
            tapes: Vec::new(),
            dys: Vec::new(),
            djs: Vec::new(),
            lane_grads: Vec::new(),
            lane_code_grads: Vec::new(),
            lane_loss: Vec::new(),
            input_parts: Vec::new(),
            input_grad: Mat::zeros(0, 0),
            code_grad: Vec::new(),
        })
    }

    /// ∂L/∂x (N × in) of the last call.
    pub fn input_grad(&self) -> MatRef<'_, T> {
        self.input_grad.as_ref()
    }

    /// ∂L/∂z per code (G × code_dim, row-major) of the last call; empty without codes.
    pub fn code_grad(&self) -> &[T] {
        &self.code_grad
    }
}

/// What a task works on: its tape and loss buffers, its lanes' accumulators, its input-gradient
/// parts.
struct TaskBufs<'a, T> {
    tape: &'a mut Tape<T>,
    dy: &'a mut Mat<T>,
    dj: &'a mut Mat<T>,
    lanes: Vec<(usize, &'a mut Vec<T>, &'a mut Vec<T>, &'a mut T)>,
    parts: &'a mut Vec<(usize, Mat<T>)>,
}

impl<T: Real> Mlp<T> {
    /// Loss and gradient of L = Σ_chunks ℓ(chunk) over the points `x` (N × in) with `codes`.
    /// For each chunk (global rows `rows`), after a forward pass of kind `pass` (`Gradient`,
    /// or `Jacobian` for losses on ∂y/∂x), `loss(rows, tape, dy, dj)` returns ℓ and writes
    /// ∂ℓ/∂y into `dy` (rows × out, zeroed) and, for `Pass::Jacobian`, ∂ℓ/∂J into `dj`
    /// (d·rows × out in the layout of [`Tape::jacobian`], zeroed). **Adds** ∂L/∂θ into `grad`
    /// and returns L; ∂L/∂x and ∂L/∂z are left in `ws`. See the module docs for the order of
    /// summation (thread-count independent).
    #[allow(clippy::too_many_arguments)]
    pub fn gradient_chunked<F>(
        &self,
        x: MatRef<'_, T>,
        codes: Option<&CodeBatch<T>>,
        pass: Pass,
        ws: &mut ChunkedGradient<T>,
        grad: &mut [T],
        par: Par,
        loss: F,
    ) -> Result<T, NnError>
    where
        F: Fn(Range<usize>, &Tape<T>, MatMut<'_, T>, Option<MatMut<'_, T>>) -> T + Sync,
    {
        if pass == Pass::Value {
            return Err(NnError::Pass {
                needed: Pass::Gradient,
                found: Some(Pass::Value),
            });
        }
        if grad.len() != self.num_params() {
            return Err(NnError::ParamCount {
                expected: self.num_params(),
                found: grad.len(),
            });
        }
        let n = x.nrows();
        let (p, cd, out) = (self.num_params(), self.spec.code_dim, self.output_dim());
        let n_codes = match (cd, codes) {
            (0, _) => 0,
            (_, Some(c)) => {
                c.ranges(n)?;
                c.len()
            }
            (k, None) => return Err(NnError::MissingCode(k)),
        };
        let chunk_rows = ws.chunk_rows;
        let n_chunks = n.div_ceil(chunk_rows);
        let lanes = ws.lanes.min(n_chunks).max(1);
        let tasks = n_tasks(par).min(lanes);
        let d = if pass == Pass::Jacobian {
            self.spec.input_dim
        } else {
            0
        };

        ws.tapes.resize_with(tasks, Tape::new);
        ws.dys.resize_with(tasks, || Mat::zeros(0, 0));
        ws.djs.resize_with(tasks, || Mat::zeros(0, 0));
        ws.input_parts.resize_with(tasks, Vec::new);
        ws.lane_grads.resize_with(lanes, Vec::new);
        ws.lane_code_grads.resize_with(lanes, Vec::new);
        ws.lane_loss.clear();
        ws.lane_loss.resize(lanes, T::ZERO);
        for g in ws.lane_grads.iter_mut().take(lanes) {
            g.clear();
            g.resize(p, T::ZERO);
        }
        for g in ws.lane_code_grads.iter_mut().take(lanes) {
            g.clear();
            g.resize(n_codes * cd, T::ZERO);
        }

        // Hand each task its buffers and the lanes t, t + tasks, ...
        let mut bufs: Vec<TaskBufs<'_, T>> = ws
            .tapes
            .iter_mut()
            .zip(ws.dys.iter_mut())
            .zip(ws.djs.iter_mut())
            .zip(ws.input_parts.iter_mut())
            .map(|(((tape, dy), dj), parts)| TaskBufs {
                tape,
                dy,
                dj,
                lanes: Vec::new(),
                parts,
            })
            .collect();
        let lane_iter = ws
            .lane_grads
            .iter_mut()
            .zip(ws.lane_code_grads.iter_mut())
            .zip(ws.lane_loss.iter_mut())
            .take(lanes)
            .enumerate();
        for (l, ((g, cg), ls)) in lane_iter {
            bufs[l % tasks].lanes.push((l, g, cg, ls));
        }

        let work = |b: &mut TaskBufs<'_, T>| -> Result<(), NnError> {
            b.parts.clear();
            for (lane, g, cg, ls) in b.lanes.iter_mut() {
                for c in (*lane..n_chunks).step_by(lanes) {
                    let rows = c * chunk_rows..((c + 1) * chunk_rows).min(n);
                    let m = rows.len();
                    let sliced = match codes {
                        Some(cb) if cd > 0 => Some(cb.slice(n, rows.clone())?),
                        _ => None,
                    };
                    let xc = x.subrows(rows.start, m);
                    self.forward(xc, sliced.as_ref().map(|s| &s.0), pass, b.tape, Par::Seq)?;
                    *b.dy = Mat::zeros(m, out);
                    let jac = pass == Pass::Jacobian;
                    if jac {
                        *b.dj = Mat::zeros(d * m, out);
                    }
                    let dj_mut = jac.then(|| b.dj.as_mut());
                    **ls += loss(rows.clone(), b.tape, b.dy.as_mut(), dj_mut);
                    let dj_ref = jac.then(|| b.dj.as_ref());
                    self.backward(b.tape, Some(b.dy.as_ref()), dj_ref, &mut g[..], Par::Seq)?;
                    if let Some(ig) = b.tape.input_grad() {
                        b.parts.push((c, ig.to_owned()));
                    }
                    if let (Some((s, g0)), Some(cgc)) = (&sliced, b.tape.code_grad()) {
                        let base = *g0 * cd;
                        for (i, v) in cgc.iter().enumerate().take(s.len() * cd) {
                            cg[base + i] += *v;
                        }
                    }
                }
            }
            Ok(())
        };
        if tasks > 1 {
            bufs.par_iter_mut()
                .map(work)
                .collect::<Result<Vec<()>, _>>()?;
        } else {
            work(&mut bufs[0])?;
        }
        drop(bufs);

        let mut total = T::ZERO;
        for l in 0..lanes {
            total += ws.lane_loss[l];
            for (g, &v) in grad.iter_mut().zip(&ws.lane_grads[l]) {
                *g += v;
            }
        }
        ws.code_grad.clear();
        ws.code_grad.resize(n_codes * cd, T::ZERO);
        for l in 0..lanes {
            for (g, &v) in ws.code_grad.iter_mut().zip(&ws.lane_code_grads[l]) {
                *g += v;
            }
        }
        ws.input_grad = Mat::zeros(n, self.spec.input_dim);
        for parts in &ws.input_parts {
            for (c, ig) in parts {
                let r0 = c * chunk_rows;
                ws.input_grad
                    .as_mut()
                    .subrows_mut(r0, ig.nrows())
                    .copy_from(ig.as_ref());
            }
        }
        Ok(total)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::bench::actuation_like_spec;
    use crate::nn::{CodeBatch, MlpSpec};

    fn inner(a: MatRef<'_, f64>, b: MatRef<'_, f64>) -> f64 {
        let mut s = 0.0;
        for j in 0..a.ncols() {
            for i in 0..a.nrows() {
                s += a[(i, j)] * b[(i, j)];
            }
        }
        s
    }

    /// L = ⟨R_y, y⟩ + ⟨R_J, J⟩ computed chunked (several chunk sizes, lanes, thread counts)
    /// and on the whole batch agree; the chunked results do not depend on the thread count.
    #[test]
    fn chunked_gradient_equals_whole_batch_gradient() {
        let net = Mlp::<f64>::new(actuation_like_spec(12, 2, 3), 6).unwrap();
        let n = 203;
        let x = Mat::from_fn(n, 3, |i, j| ((i * 13 + j * 7) % 41) as f64 / 20.5 - 1.0);
        let codes = CodeBatch::segments(
            3,
            (0..9).map(|i| (i as f64).sin()).collect(),
            vec![50, 0, 153],
        )
        .unwrap();
        let ry = Mat::from_fn(n, 6, |i, j| ((i + 2 * j) % 5) as f64 - 2.0);
        let rj = Mat::from_fn(3 * n, 6, |i, j| ((3 * i + j) % 7) as f64 * 0.3 - 1.0);

        let mut tape = Tape::new();
        net.forward(
            x.as_ref(),
            Some(&codes),
            Pass::Jacobian,
            &mut tape,
            Par::Seq,
        )
        .unwrap();
        let l_ref = inner(tape.output().unwrap(), ry.as_ref())
            + inner(tape.jacobian().unwrap(), rj.as_ref());
        let mut g_ref = vec![0.0; net.num_params()];
        net.backward(
            &mut tape,
            Some(ry.as_ref()),
            Some(rj.as_ref()),
            &mut g_ref,
            Par::Seq,
        )
        .unwrap();
        let ig_ref = tape.input_grad().unwrap().to_owned();
        let cg_ref = tape.code_grad().unwrap().to_vec();

        let loss = |rows: Range<usize>,
                    t: &Tape<f64>,
                    mut dy: MatMut<'_, f64>,
                    dj: Option<MatMut<'_, f64>>| {
            let m = rows.len();
            let ryc = ry.as_ref().subrows(rows.start, m);
            dy.copy_from(ryc);
            let mut l = inner(t.output().unwrap(), ryc);
            if let Some(mut dj) = dj {
                for k in 0..3 {
                    let rjc = rj.as_ref().subrows(k * n + rows.start, m);
                    dj.as_mut().subrows_mut(k * m, m).copy_from(rjc);
                    l += inner(t.jacobian_column(k).unwrap(), rjc);
                }
            }
            l
        };
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-10 * (1.0 + b.abs());
        for (chunk, lanes) in [(16, 3), (64, 8), (500, 2)] {
            let mut bits = Vec::new();
            for par in [Par::Seq, Par::rayon(2), Par::rayon(3)] {
                let mut ws = ChunkedGradient::new(chunk, lanes).unwrap();
                let mut g = vec![0.0; net.num_params()];
                let l = net
                    .gradient_chunked(
                        x.as_ref(),
                        Some(&codes),
                        Pass::Jacobian,
                        &mut ws,
                        &mut g,
                        par,
                        loss,
                    )
                    .unwrap();
                assert!(close(l, l_ref), "loss {l} vs {l_ref}");
                assert!(
                    g.iter().zip(&g_ref).all(|(a, b)| close(*a, *b)),
                    "chunk {chunk}"
                );
                assert!((ws.input_grad() - &ig_ref).norm_max() < 1e-10);
                assert!(
                    ws.code_grad()
                        .iter()
                        .zip(&cg_ref)
                        .all(|(a, b)| close(*a, *b))
                );
                bits.push((
                    l.to_bits(),
                    g.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                ));
            }
            assert!(
                bits.windows(2).all(|w| w[0] == w[1]),
                "thread count changed the bits"
            );
        }
    }

    #[test]
    fn chunked_gradient_rejects_misuse() {
        let net = Mlp::<f64>::new(MlpSpec::siren(3, 4, 2, 5.0, 3), 1).unwrap();
        let x = Mat::<f64>::zeros(10, 3);
        let mut ws = ChunkedGradient::new(4, 2).unwrap();
        let mut g = vec![0.0; net.num_params()];
        let loss =
            |_: Range<usize>, _: &Tape<f64>, _: MatMut<'_, f64>, _: Option<MatMut<'_, f64>>| 0.0;
        assert!(
            net.gradient_chunked(
                x.as_ref(),
                None,
                Pass::Value,
                &mut ws,
                &mut g,
                Par::Seq,
                loss
            )
            .is_err()
        );
        assert!(
            net.gradient_chunked(
                x.as_ref(),
                None,
                Pass::Gradient,
                &mut ws,
                &mut g[1..],
                Par::Seq,
                loss
            )
            .is_err()
        );
        assert!(ChunkedGradient::<f64>::new(0, 1).is_err());
    }
}
