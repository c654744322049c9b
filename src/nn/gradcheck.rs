//! Tests of the batched passes: every derivative against central finite differences in f64 on
//! small random networks, plus determinism, initialization statistics and training.

use faer::{Mat, MatRef, Par};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::lipschitz::softplus_inverse;
use super::*;

const H: f64 = 1e-5;

/// A network using every feature: SIREN first and hidden layers, a Lipschitz GeLU layer and a
/// tanh layer taking a 2-d code, and a linear output.
fn small_net(seed: u64) -> Mlp<f64> {
    let spec = MlpSpec::new(3)
        .with_code_dim(2)
        .layer(LayerSpec::siren_first(5, 5.0))
        .layer(LayerSpec::siren(6, 5.0))
        .layer(LayerSpec::gelu(5).lipschitz().with_code())
        .layer(LayerSpec::tanh(4).lipschitz().with_code())
        .layer(LayerSpec::linear(3));
    let mut net = Mlp::new(spec, seed).unwrap();
    clip_some_rows(&mut net);
    net
}

/// Sets each Lipschitz bound between the layer's row sums so that some rows are clipped and
/// some are not (both branches of the normalization's derivative are exercised).
fn clip_some_rows(net: &mut Mlp<f64>) {
    let layout = net.spec().layout();
    let p = net.params_mut();
    for lay in layout {
        if let Some(c) = lay.c {
            let mut sums: Vec<f64> = (0..lay.out_dim)
                .map(|i| {
                    (0..lay.fan_in())
                        .map(|j| p[lay.w + j * lay.out_dim + i].abs())
                        .sum()
                })
                .collect();
            sums.sort_by(f64::total_cmp);
            let mid = lay.out_dim / 2;
            p[c] = softplus_inverse(0.5 * (sums[mid - 1] + sums[mid]));
        }
    }
}

fn random_mat(rng: &mut ChaCha8Rng, r: usize, c: usize, a: f64) -> Mat<f64> {
    Mat::from_fn(r, c, |_, _| rng.random_range(-a..a))
}

struct Problem {
    net: Mlp<f64>,
    x: Mat<f64>,
    codes: CodeBatch<f64>,
    ry: Mat<f64>,
    rj: Mat<f64>,
}

fn problem(seed: u64) -> Problem {
    let net = small_net(seed);
    let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
    let n = 5;
    let x = random_mat(&mut rng, n, 3, 0.8);
    let codes = CodeBatch::segments(2, vec![0.3, -0.6, -0.2, 0.5], vec![2, 3]).unwrap();
    let ry = random_mat(&mut rng, n, 3, 1.0);
    let rj = random_mat(&mut rng, 3 * n, 3, 1.0);
    Problem {
        net,
        x,
        codes,
        ry,
        rj,
    }
}

fn inner(a: MatRef<'_, f64>, b: MatRef<'_, f64>) -> f64 {
    let mut s = 0.0;
    for j in 0..a.ncols() {
        for i in 0..a.nrows() {
            s += a[(i, j)] * b[(i, j)];
        }
    }
    s
}

/// L = ⟨R_y, y⟩ + ⟨R_J, J⟩ (the Jacobian term only with `with_jacobian`).
fn loss(
    net: &Mlp<f64>,
    x: MatRef<'_, f64>,
    codes: &CodeBatch<f64>,
    p: &Problem,
    with_jacobian: bool,
) -> f64 {
    let mut tape = Tape::new();
    net.forward(x, Some(codes), Pass::Jacobian, &mut tape, Par::Seq)
        .unwrap();
    let mut l = inner(tape.output().unwrap(), p.ry.as_ref());
    if with_jacobian {
        l += inner(tape.jacobian().unwrap(), p.rj.as_ref());
    }
    l
}

fn assert_close(what: &str, analytic: &[f64], fd: &[f64]) {
    let scale = fd.iter().fold(1e-3f64, |m, v| m.max(v.abs()));
    for (i, (a, f)) in analytic.iter().zip(fd).enumerate() {
        assert!(
            (a - f).abs() <= 1e-6 * scale + 1e-7 * f.abs(),
            "{what}[{i}]: analytic {a:e} vs finite difference {f:e} (scale {scale:e})"
        );
    }
}

/// Central differences of `f` with respect to each entry of `v`.
fn fd_vec(v: &[f64], mut f: impl FnMut(&[f64]) -> f64) -> Vec<f64> {
    (0..v.len())
        .map(|k| {
            let (mut a, mut b) = (v.to_vec(), v.to_vec());
            a[k] += H;
            b[k] -= H;
            (f(&a) - f(&b)) / (2.0 * H)
        })
        .collect()
}

fn mat_to_vec(m: MatRef<'_, f64>) -> Vec<f64> {
    (0..m.ncols())
        .flat_map(|j| (0..m.nrows()).map(move |i| m[(i, j)]))
        .collect()
}

fn vec_to_mat(v: &[f64], r: usize, c: usize) -> Mat<f64> {
    Mat::from_fn(r, c, |i, j| v[j * r + i])
}

/// Runs the analytic passes; returns (∂L/∂θ, ∂L/∂x, ∂L/∂z).
fn analytic(p: &Problem, with_jacobian: bool, pass: Pass) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let mut tape = Tape::new();
    p.net
        .forward(p.x.as_ref(), Some(&p.codes), pass, &mut tape, Par::Seq)
        .unwrap();
    let mut grad = vec![0.0; p.net.num_params()];
    let dj = with_jacobian.then(|| p.rj.as_ref());
    p.net
        .backward(&mut tape, Some(p.ry.as_ref()), dj, &mut grad, Par::Seq)
        .unwrap();
    (
        grad,
        mat_to_vec(tape.input_grad().unwrap()),
        tape.code_grad().unwrap().to_vec(),
    )
}

fn check_all_gradients(with_jacobian: bool, pass: Pass) {
    for seed in [1, 2] {
        let p = problem(seed);
        let (g, gx, gz) = analytic(&p, with_jacobian, pass);
        let fd_params = fd_vec(p.net.params(), |q| {
            let net = Mlp::from_params(p.net.spec().clone(), q.to_vec()).unwrap();
            loss(&net, p.x.as_ref(), &p.codes, &p, with_jacobian)
        });
        assert_close("∂L/∂θ", &g, &fd_params);
        let (n, d) = (p.x.nrows(), p.x.ncols());
        let fd_x = fd_vec(&mat_to_vec(p.x.as_ref()), |xv| {
            loss(
                &p.net,
                vec_to_mat(xv, n, d).as_ref(),
                &p.codes,
                &p,
                with_jacobian,
            )
        });
        assert_close("∂L/∂x", &gx, &fd_x);
        let fd_z = fd_vec(p.codes.values(), |zv| {
            let codes = CodeBatch::segments(2, zv.to_vec(), vec![2, 3]).unwrap();
            loss(&p.net, p.x.as_ref(), &codes, &p, with_jacobian)
        });
        assert_close("∂L/∂z", &gz, &fd_z);
    }
}

#[test]
fn gradients_of_an_output_loss_match_finite_differences() {
    check_all_gradients(false, Pass::Gradient);
    // The same loss through a Jacobian-pass tape (no Jacobian adjoint).
    check_all_gradients(false, Pass::Jacobian);
}

#[test]
fn gradients_of_a_jacobian_loss_match_finite_differences() {
    check_all_gradients(true, Pass::Jacobian);
}

#[test]
fn jacobian_from_tangents_matches_finite_differences() {
    let p = problem(3);
    let (n, d) = (p.x.nrows(), p.x.ncols());
    let mut tape = Tape::new();
    p.net
        .forward(
            p.x.as_ref(),
            Some(&p.codes),
            Pass::Jacobian,
            &mut tape,
            Par::Seq,
        )
        .unwrap();
    let out = p.net.output_dim();
    let j = tape.jacobian().unwrap().to_owned();
    for k in 0..d {
        let (mut xp, mut xm) = (p.x.clone(), p.x.clone());
        for i in 0..n {
            xp[(i, k)] += H;
            xm[(i, k)] -= H;
        }
        let yp = p.net.eval(xp.as_ref(), Some(&p.codes)).unwrap();
        let ym = p.net.eval(xm.as_ref(), Some(&p.codes)).unwrap();
        for i in 0..n {
            for o in 0..out {
                let fd = (yp[(i, o)] - ym[(i, o)]) / (2.0 * H);
                let an = j[(k * n + i, o)];
                assert!(
                    (an - fd).abs() < 1e-7 * (1.0 + fd.abs()),
                    "J[{i}][{o},{k}]: {an} vs {fd}"
                );
                assert_eq!(tape.jacobian_at(i).unwrap()[o * d + k], an);
                assert_eq!(tape.jacobian_column(k).unwrap()[(i, o)], an);
            }
        }
    }
    // The Jacobian pass's outputs equal a value pass's, bit for bit.
    let y = p.net.eval(p.x.as_ref(), Some(&p.codes)).unwrap();
    assert_eq!(y, tape.output().unwrap().to_owned());
}

#[test]
fn lipschitz_loss_gradient_through_the_network() {
    let p = problem(4);
    let mut grad = vec![0.0; p.net.num_params()];
    let l = p.net.lipschitz_loss(0.3, Some(&mut grad)).unwrap();
    let bounds = p.net.lipschitz_bounds();
    assert_eq!(bounds.len(), 2);
    assert!((l - 0.3 * bounds[0] * bounds[1]).abs() < 1e-15);
    let fd = fd_vec(p.net.params(), |q| {
        let net = Mlp::from_params(p.net.spec().clone(), q.to_vec()).unwrap();
        net.lipschitz_loss(0.3, None).unwrap()
    });
    assert_close("∂L_lip/∂θ", &grad, &fd);
    assert_eq!(grad.iter().filter(|g| **g != 0.0).count(), 2);
}

#[test]
fn shared_code_equals_one_segment_and_network_without_code_works() {
    let p = problem(5);
    let n = p.x.nrows();
    let shared = CodeBatch::shared(&[0.3, -0.6]);
    let seg = CodeBatch::segments(2, vec![0.3, -0.6], vec![n]).unwrap();
    let a = p.net.eval(p.x.as_ref(), Some(&shared)).unwrap();
    let b = p.net.eval(p.x.as_ref(), Some(&seg)).unwrap();
    assert_eq!(a, b);
    // φ-like network: gradients of a Jacobian loss without any code.
    let net = Mlp::<f64>::new(MlpSpec::siren(3, 7, 4, 5.0, 3), 8).unwrap();
    let mut tape = Tape::new();
    net.forward(p.x.as_ref(), None, Pass::Jacobian, &mut tape, Par::Seq)
        .unwrap();
    let mut grad = vec![0.0; net.num_params()];
    net.backward(
        &mut tape,
        Some(p.ry.as_ref()),
        Some(p.rj.as_ref()),
        &mut grad,
        Par::Seq,
    )
    .unwrap();
    assert!(tape.code_grad().is_none());
    let fd = fd_vec(net.params(), |q| {
        let net = Mlp::from_params(net.spec().clone(), q.to_vec()).unwrap();
        let mut t = Tape::new();
        net.forward(p.x.as_ref(), None, Pass::Jacobian, &mut t, Par::Seq)
            .unwrap();
        inner(t.output().unwrap(), p.ry.as_ref()) + inner(t.jacobian().unwrap(), p.rj.as_ref())
    });
    assert_close("φ ∂L/∂θ", &grad, &fd);
}

#[test]
fn misuse_is_reported_as_errors() {
    let p = problem(6);
    let mut tape = Tape::new();
    let mut grad = vec![0.0; p.net.num_params()];
    let x = p.x.as_ref();
    assert!(matches!(
        p.net.forward(x, None, Pass::Value, &mut tape, Par::Seq),
        Err(NnError::MissingCode(2))
    ));
    let wrong = CodeBatch::shared(&[0.0; 3]);
    assert!(matches!(
        p.net
            .forward(x, Some(&wrong), Pass::Value, &mut tape, Par::Seq),
        Err(NnError::CodeDim {
            expected: 2,
            found: 3
        })
    ));
    let runs = CodeBatch::segments(2, vec![0.0; 4], vec![1, 1]).unwrap();
    assert!(matches!(
        p.net
            .forward(x, Some(&runs), Pass::Value, &mut tape, Par::Seq),
        Err(NnError::CodeBatch(_))
    ));
    let x2 = Mat::<f64>::zeros(4, 2);
    assert!(matches!(
        p.net.forward(
            x2.as_ref(),
            Some(&p.codes),
            Pass::Value,
            &mut tape,
            Par::Seq
        ),
        Err(NnError::Shape { .. })
    ));
    p.net
        .forward(x, Some(&p.codes), Pass::Value, &mut tape, Par::Seq)
        .unwrap();
    assert!(matches!(
        p.net
            .backward(&mut tape, Some(p.ry.as_ref()), None, &mut grad, Par::Seq),
        Err(NnError::Pass { .. })
    ));
    p.net
        .forward(x, Some(&p.codes), Pass::Gradient, &mut tape, Par::Seq)
        .unwrap();
    assert!(matches!(
        p.net
            .backward(&mut tape, None, Some(p.rj.as_ref()), &mut grad, Par::Seq),
        Err(NnError::Pass {
            needed: Pass::Jacobian,
            ..
        })
    ));
    assert!(matches!(
        p.net
            .backward(&mut tape, Some(p.rj.as_ref()), None, &mut grad, Par::Seq),
        Err(NnError::Shape { .. })
    ));
    assert!(matches!(
        p.net
            .backward(&mut tape, None, None, &mut grad[1..], Par::Seq),
        Err(NnError::ParamCount { .. })
    ));
    let no_code = Mlp::<f64>::new(MlpSpec::siren(3, 4, 2, 5.0, 3), 1).unwrap();
    assert!(matches!(
        no_code.forward(x, Some(&p.codes), Pass::Value, &mut tape, Par::Seq),
        Err(NnError::UnexpectedCode)
    ));
    let mut bad = p.net.params().to_vec();
    bad[3] = f64::NAN;
    assert!(matches!(
        Mlp::from_params(p.net.spec().clone(), bad),
        Err(NnError::NonFiniteParam(3))
    ));
}

/// Bigger network, many points: sequential and 2-task runs give identical bits, and
/// repeated runs on a reused tape too.
#[test]
fn results_are_bitwise_deterministic_across_thread_counts() {
    let spec = bench::actuation_like_spec(48, 2, 16);
    let net = Mlp::<f64>::new(spec.clone(), 77).unwrap();
    assert_eq!(net, Mlp::<f64>::new(spec, 77).unwrap());
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let n = 1500;
    let x = random_mat(&mut rng, n, 3, 1.0);
    let codes = CodeBatch::segments(
        16,
        (0..32).map(|i| (i as f64 * 0.37).sin()).collect(),
        vec![700, 800],
    )
    .unwrap();
    let dy = random_mat(&mut rng, n, 6, 1.0);
    let dj = random_mat(&mut rng, 3 * n, 6, 1.0);
    let run = |par: Par, tape: &mut Tape<f64>| {
        net.forward(x.as_ref(), Some(&codes), Pass::Jacobian, tape, par)
            .unwrap();
        let mut g = vec![0.0; net.num_params()];
        net.backward(tape, Some(dy.as_ref()), Some(dj.as_ref()), &mut g, par)
            .unwrap();
        let bits = |m: MatRef<'_, f64>| {
            mat_to_vec(m)
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        (
            bits(tape.output().unwrap()),
            bits(tape.jacobian().unwrap()),
            g.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            bits(tape.input_grad().unwrap()),
            tape.code_grad()
                .unwrap()
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>(),
        )
    };
    let mut tape = Tape::new();
    let seq = run(Par::Seq, &mut tape);
    let again = run(Par::Seq, &mut tape);
    let par2 = run(Par::rayon(2), &mut Tape::new());
    assert!(seq == again, "sequential runs differ");
    assert!(seq == par2, "sequential and 2-thread runs differ");
    // The chunked value pass: same bits for any task count, and the same values as the
    // whole-batch recorded pass.
    let value = |par: Par| {
        let mut t = Tape::new();
        net.forward(x.as_ref(), Some(&codes), Pass::Value, &mut t, par)
            .unwrap();
        t.output().unwrap().to_owned()
    };
    let (v1, v2, v3) = (value(Par::Seq), value(Par::rayon(2)), value(Par::rayon(3)));
    assert!(v1 == v2 && v1 == v3, "value pass depends on the task count");
    net.forward(
        x.as_ref(),
        Some(&codes),
        Pass::Gradient,
        &mut tape,
        Par::Seq,
    )
    .unwrap();
    let recorded = tape.output().unwrap();
    let mut worst = 0.0f64;
    for j in 0..6 {
        for i in 0..n {
            worst = worst.max((recorded[(i, j)] - v1[(i, j)]).abs());
        }
    }
    assert!(
        worst < 1e-13,
        "value and recorded passes differ by {worst:e}"
    );
}

#[test]
fn f32_network_agrees_with_f64() {
    let p = problem(9);
    let net32: Mlp<f32> = p.net.cast();
    let x32 = Mat::from_fn(p.x.nrows(), 3, |i, j| p.x[(i, j)] as f32);
    let codes32 = CodeBatch::segments(
        2,
        p.codes.values().iter().map(|&v| v as f32).collect(),
        vec![2, 3],
    )
    .unwrap();
    let y32 = net32.eval(x32.as_ref(), Some(&codes32)).unwrap();
    let y64 = p.net.eval(p.x.as_ref(), Some(&p.codes)).unwrap();
    for i in 0..y64.nrows() {
        for j in 0..y64.ncols() {
            assert!(
                (y32[(i, j)] as f64 - y64[(i, j)]).abs() < 1e-5,
                "({i}, {j})"
            );
        }
    }
}

/// SIREN's initialization keeps the activation distribution stable through depth
/// (Sitzmann et al. 2020, Sec. 3.2): hidden-layer outputs have mean ≈ 0 and a standard
/// deviation that neither grows nor collapses (≈ 0.7).
#[test]
fn siren_activations_are_stable_through_depth() {
    let spec = MlpSpec::siren(2, 256, 5, 30.0, 1);
    let net = Mlp::<f64>::new(spec, 3).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let x = random_mat(&mut rng, 2000, 2, 1.0);
    let mut tape = Tape::new();
    net.forward(x.as_ref(), None, Pass::Gradient, &mut tape, Par::Seq)
        .unwrap();
    let mut stds = Vec::new();
    for l in 1..5 {
        let h = tape.layers[l].h.as_slice();
        let n = h.len() as f64;
        let mean = h.iter().sum::<f64>() / n;
        let std = (h.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n).sqrt();
        eprintln!("layer {l}: mean {mean:.4} std {std:.4}");
        assert!(mean.abs() < 0.1, "layer {l}: mean {mean}");
        assert!((0.68..0.74).contains(&std), "layer {l}: std {std}");
        stds.push(std);
    }
    for w in stds.windows(2) {
        assert!((w[1] / w[0] - 1.0).abs() < 0.05, "{stds:?}");
    }
}

/// Adam + the paper's schedule fit a small regression, and a Jacobian-only loss drives a
/// SIREN's Jacobian to a target (training through the double backward).
#[test]
fn adam_trains_a_regression_and_a_jacobian_target() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    let n = 128;
    let x = random_mat(&mut rng, n, 2, 1.0);
    let target = Mat::from_fn(n, 1, |i, _| (2.0 * x[(i, 0)]).sin() * x[(i, 1)].cos());
    let spec = MlpSpec::new(2)
        .layer(LayerSpec::siren_first(24, 5.0))
        .layer(LayerSpec::gelu(24).lipschitz())
        .layer(LayerSpec::linear(1));
    let mut net = Mlp::<f64>::new(spec, 2).unwrap();
    let iters = 600;
    let schedule = LrSchedule::linear_decay(3e-3, iters, 0.5).unwrap();
    let mut adam = Adam::new(net.num_params(), AdamConfig::default()).unwrap();
    let mut tape = Tape::new();
    let mut grad = vec![0.0; net.num_params()];
    let mse = |net: &Mlp<f64>, tape: &mut Tape<f64>| {
        net.forward(x.as_ref(), None, Pass::Gradient, tape, Par::Seq)
            .unwrap();
        let y = tape.output().unwrap();
        let r = Mat::from_fn(n, 1, |i, _| y[(i, 0)] - target[(i, 0)]);
        (r.squared_norm_l2() / n as f64, r)
    };
    let (first, _) = mse(&net, &mut tape);
    for it in 0..iters {
        let (_, r) = mse(&net, &mut tape);
        let dy = Mat::from_fn(n, 1, |i, _| 2.0 * r[(i, 0)] / n as f64);
        grad.fill(0.0);
        net.backward(&mut tape, Some(dy.as_ref()), None, &mut grad, Par::Seq)
            .unwrap();
        net.lipschitz_loss(1e-6, Some(&mut grad)).unwrap();
        adam.step(net.params_mut(), &grad, schedule.lr_at(it))
            .unwrap();
    }
    let (last, _) = mse(&net, &mut tape);
    assert!(last < 1e-3 && last < first / 100.0, "mse {first} → {last}");

    // Jacobian target: J = diag(2, 1, 0.5) everywhere, loss Σ‖J − T‖²/N.
    let mut phi = Mlp::<f64>::new(MlpSpec::siren(3, 16, 3, 5.0, 3), 5).unwrap();
    let x = random_mat(&mut rng, 64, 3, 1.0);
    let n = x.nrows();
    let t = [2.0, 1.0, 0.5];
    let mut adam = Adam::new(phi.num_params(), AdamConfig::default()).unwrap();
    let mut grad = vec![0.0; phi.num_params()];
    let jac_loss = |phi: &Mlp<f64>, tape: &mut Tape<f64>| {
        phi.forward(x.as_ref(), None, Pass::Jacobian, tape, Par::Seq)
            .unwrap();
        let j = tape.jacobian().unwrap();
        let r = Mat::from_fn(3 * n, 3, |row, o| {
            let k = row / n;
            j[(row, o)] - if o == k { t[k] } else { 0.0 }
        });
        (r.squared_norm_l2() / n as f64, r)
    };
    let (first, _) = jac_loss(&phi, &mut tape);
    for _ in 0..300 {
        let (_, r) = jac_loss(&phi, &mut tape);
        let dj = Mat::from_fn(3 * n, 3, |i, j| 2.0 * r[(i, j)] / n as f64);
        grad.fill(0.0);
        phi.backward(&mut tape, None, Some(dj.as_ref()), &mut grad, Par::Seq)
            .unwrap();
        adam.step(phi.params_mut(), &grad, 5e-3).unwrap();
    }
    let (last, _) = jac_loss(&phi, &mut tape);
    assert!(last < first / 100.0, "Jacobian loss {first} → {last}");
}
