//! The `Value` (inference) pass: the batch in fixed-size row chunks, each chunk through all
//! layers while its activations stay in cache; chunk c goes to task c mod tasks. A point's
//! arithmetic does not depend on the chunking or the task count.
//!
//! [`PointCache`] keeps the part of the pass that does not depend on the code for a fixed set
//! of points (N_A's canonical sample points): every layer before the first one that takes the
//! code, and that layer's product W̃_h a. A new code then costs only the remaining layers.

use faer::{MatRef, Par};
use rayon::prelude::*;

use super::Mlp;
use crate::nn::code::CodeBatch;
use crate::nn::error::NnError;
use crate::nn::matrix::{Buf, matmul_into, n_tasks};
use crate::nn::real::Real;
use crate::nn::tape::{ChunkScratch, Pass, Tape};

/// Rows per chunk: 256 points × 128 features × 8 bytes = 256 KiB per activation buffer.
pub(crate) const VALUE_CHUNK: usize = 256;

/// The code-independent part of a value pass over a fixed point set (see the module docs),
/// from [`Mlp::cache_points`]; valid for the parameters it was made with (checked).
#[derive(Clone, Debug)]
pub struct PointCache<T> {
    /// First layer that takes the code (the number of layers if none does).
    layer: usize,
    /// Pre-activation product W̃_h a of that layer (N × width), or the outputs if none.
    z: Buf<T>,
    fingerprint: u64,
}

impl<T: Real> PointCache<T> {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.z.rows()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes held.
    pub fn memory_bytes(&self) -> usize {
        self.z.bytes()
    }
}

/// Where the chunk runner starts and stops.
#[derive(Clone, Copy)]
enum Run<'a, T> {
    /// From the input through all layers.
    Full(MatRef<'a, T>),
    /// From the input up to the product W̃_h a of layer `stop` (no bias, no activation).
    Prefix(MatRef<'a, T>, usize),
    /// From a cache through all layers.
    Cached(&'a PointCache<T>),
}

impl<T: Real> Mlp<T> {
    /// Runs the chunks and gathers the outputs into the last layer's `h` (N × out).
    /// Expects [`Mlp::prepare`] to have run.
    pub(super) fn forward_value(&self, x: MatRef<'_, T>, tape: &mut Tape<T>, par: Par) {
        let mut y = std::mem::take(&mut tape.layers[self.layout.len() - 1].h);
        self.run_chunks(Run::Full(x), tape, par, &mut y);
        tape.layers[self.layout.len() - 1].h = y;
    }

    /// Caches the code-independent part of the value pass over the points `x`
    /// (N × input_dim); see [`PointCache`]. Parameters must not change while it is used.
    pub fn cache_points(&self, x: MatRef<'_, T>, par: Par) -> Result<PointCache<T>, NnError> {
        let layer = self
            .spec
            .layers
            .iter()
            .position(|l| l.takes_code)
            .unwrap_or(self.layout.len());
        let mut tape = Tape::new();
        let codes =
            (self.spec.code_dim > 0).then(|| CodeBatch::shared(&vec![T::ZERO; self.spec.code_dim]));
        self.prepare(x.nrows(), x.ncols(), codes.as_ref(), Pass::Value, &mut tape)?;
        let mut z = Buf::default();
        let run = if layer < self.layout.len() {
            Run::Prefix(x, layer)
        } else {
            Run::Full(x)
        };
        self.run_chunks(run, &mut tape, par, &mut z);
        Ok(PointCache {
            layer,
            z,
            fingerprint: self.fingerprint(),
        })
    }

    /// The value pass over the cached points with `codes` (bit-identical to
    /// [`Mlp::forward`] with `Pass::Value` on the same points); read the outputs with
    /// [`Tape::output`].
    pub fn forward_cached(
        &self,
        cache: &PointCache<T>,
        codes: Option<&CodeBatch<T>>,
        tape: &mut Tape<T>,
        par: Par,
    ) -> Result<(), NnError> {
        if cache.fingerprint != self.fingerprint() {
            return Err(NnError::StaleCache);
        }
        self.prepare(cache.len(), self.spec.input_dim, codes, Pass::Value, tape)?;
        let mut y = std::mem::take(&mut tape.layers[self.layout.len() - 1].h);
        self.run_chunks(Run::Cached(cache), tape, par, &mut y);
        tape.layers[self.layout.len() - 1].h = y;
        tape.pass = Some(Pass::Value);
        Ok(())
    }

    /// FNV-1a over the parameter bits (detects a cache used with changed parameters).
    fn fingerprint(&self) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for p in &self.params {
            h ^= p.to_f64().to_bits();
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        h
    }

    /// The chunk runner: per chunk, the layers `run` asks for; results gathered into `dst`
    /// (N × the last computed width).
    fn run_chunks(&self, run: Run<'_, T>, tape: &mut Tape<T>, par: Par, dst: &mut Buf<T>) {
        let n = tape.n;
        let n_layers = self.layout.len();
        let (first, last) = match run {
            Run::Full(_) => (0, n_layers),
            Run::Prefix(_, stop) => (0, stop + 1),
            Run::Cached(c) => (c.layer, n_layers),
        };
        let width = if last == 0 {
            self.spec.input_dim
        } else {
            self.layout[last - 1].out_dim
        };
        let n_chunks = n.div_ceil(VALUE_CHUNK);
        let tasks = n_tasks(par).min(n_chunks).max(1);
        let Tape {
            ranges,
            layers,
            scratch,
            ..
        } = tape;
        scratch.resize_with(tasks, ChunkScratch::default);
        let (layers, ranges) = (&*layers, &*ranges);
        let chunk = |t: usize, s: &mut ChunkScratch<T>| {
            s.out.clear();
            for c in (t..n_chunks).step_by(tasks) {
                let r0 = c * VALUE_CHUNK;
                let m = VALUE_CHUNK.min(n - r0);
                if first == n_layers {
                    // Everything is cached: the cache holds the outputs.
                    if let Run::Cached(cache) = run {
                        s.cur.reshape(m, width);
                        for j in 0..width {
                            s.cur
                                .col_mut(j)
                                .copy_from_slice(&cache.z.col(j)[r0..r0 + m]);
                        }
                    }
                }
                for (l, lt) in layers.iter().enumerate().take(last).skip(first) {
                    let lay = self.layout[l];
                    let out = lay.out_dim;
                    s.next.reshape(m, out);
                    match run {
                        Run::Cached(cache) if l == first => {
                            for j in 0..out {
                                s.next
                                    .col_mut(j)
                                    .copy_from_slice(&cache.z.col(j)[r0..r0 + m]);
                            }
                        }
                        Run::Full(x) | Run::Prefix(x, _) if l == 0 => {
                            let w_h = self.weight(l, lt).subcols(0, lay.in_dim);
                            let input = x.subrows(r0, m);
                            matmul_into(s.next.view_mut(), false, input, w_h.transpose(), Par::Seq);
                        }
                        _ => {
                            let w_h = self.weight(l, lt).subcols(0, lay.in_dim);
                            let input = s.cur.view();
                            matmul_into(s.next.view_mut(), false, input, w_h.transpose(), Par::Seq);
                        }
                    }
                    let stop_here = matches!(run, Run::Prefix(_, stop) if stop == l);
                    if !stop_here {
                        let act = self.spec.layers[l].activation;
                        for j in 0..out {
                            let col = s.next.col_mut(j);
                            for (g, r) in ranges.iter().enumerate() {
                                let (lo, hi) = (r.start.max(r0), r.end.min(r0 + m));
                                if lo < hi {
                                    let b = lt.bias[g * out + j];
                                    act.apply(&mut col[lo - r0..hi - r0], b, None, None);
                                }
                            }
                        }
                    }
                    std::mem::swap(&mut s.cur, &mut s.next);
                }
                // Row-major chunk results (m × width) appended in chunk order.
                for i in 0..m {
                    for j in 0..width {
                        s.out.push(s.cur.col(j)[i]);
                    }
                }
            }
        };
        if tasks > 1 {
            scratch
                .par_iter_mut()
                .enumerate()
                .for_each(|(t, s)| chunk(t, s));
        } else {
            chunk(0, &mut scratch[0]);
        }
        dst.reshape(n, width);
        let mut cursor = vec![0usize; tasks];
        for c in 0..n_chunks {
            let t = c % tasks;
            let r0 = c * VALUE_CHUNK;
            let m = VALUE_CHUNK.min(n - r0);
            let src = &scratch[t].out[cursor[t]..cursor[t] + m * width];
            for j in 0..width {
                let col = &mut dst.col_mut(j)[r0..r0 + m];
                for (i, v) in col.iter_mut().enumerate() {
                    *v = src[i * width + j];
                }
            }
            cursor[t] += m * width;
        }
    }
}

#[cfg(test)]
mod tests {
    use faer::Mat;

    use crate::nn::bench::actuation_like_spec;
    use crate::nn::{CodeBatch, Mlp, MlpSpec, NnError, Pass, Tape};
    use faer::Par;

    fn points(n: usize) -> Mat<f64> {
        Mat::from_fn(n, 3, |i, j| ((i * 31 + j * 17) % 97) as f64 / 48.5 - 1.0)
    }

    #[test]
    fn cached_pass_equals_the_full_value_pass_bit_for_bit() {
        let net = Mlp::<f64>::new(actuation_like_spec(24, 2, 5), 4).unwrap();
        let n = 700; // 3 chunks, the last partial
        let x = points(n);
        let cache = net.cache_points(x.as_ref(), Par::rayon(2)).unwrap();
        assert_eq!(cache.len(), n);
        let shared = CodeBatch::shared(&[0.1, -0.2, 0.3, 0.0, 0.5]);
        let segs =
            CodeBatch::segments(5, (0..10).map(|i| i as f64 * 0.1).collect(), vec![300, 400])
                .unwrap();
        for codes in [&shared, &segs] {
            for par in [Par::Seq, Par::rayon(2)] {
                let mut t1 = Tape::new();
                net.forward(x.as_ref(), Some(codes), Pass::Value, &mut t1, par)
                    .unwrap();
                let mut t2 = Tape::new();
                net.forward_cached(&cache, Some(codes), &mut t2, par)
                    .unwrap();
                assert!(t1.output().unwrap() == t2.output().unwrap());
                assert_eq!(t2.len(), n);
            }
        }
        // Wrong code runs for the cached point count.
        let bad = CodeBatch::segments(5, vec![0.0; 10], vec![1, 2]).unwrap();
        assert!(
            net.forward_cached(&cache, Some(&bad), &mut Tape::new(), Par::Seq)
                .is_err()
        );
        // Changed parameters invalidate the cache.
        let mut changed = net.clone();
        changed.params_mut()[0] += 1e-3;
        assert!(matches!(
            changed.forward_cached(&cache, Some(&shared), &mut Tape::new(), Par::Seq),
            Err(NnError::StaleCache)
        ));
    }

    #[test]
    fn cache_of_a_network_without_code_holds_its_outputs() {
        let net = Mlp::<f64>::new(MlpSpec::siren(3, 8, 2, 5.0, 3), 2).unwrap();
        let x = points(300);
        let cache = net.cache_points(x.as_ref(), Par::Seq).unwrap();
        let mut t = Tape::new();
        net.forward_cached(&cache, None, &mut t, Par::Seq).unwrap();
        assert!(t.output().unwrap() == net.eval(x.as_ref(), None).unwrap());
    }
}
