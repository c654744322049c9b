//! Session tests on the neutral coarse face built from the rig, driven by a small
//! test-only actuation model (the app never ships it).

use std::sync::{Arc, OnceLock};
use std::time::Duration;

use nalgebra::{Matrix3, Point3, Vector3};

use super::*;
use crate::drive::{Actuation, ActuationModel, Codes, DriveError};
use crate::model::{FaceModel, Lod, build_face};
use crate::rig::ExpressionCode;
use crate::rig::style::StyleCode;
use crate::rig::test_support::rig;
use crate::sim::{Quality, RigidMotion, SymTensor};

const WAIT: Duration = Duration::from_secs(60);

pub(crate) fn neutral_coarse() -> Arc<FaceModel> {
    static MODEL: OnceLock<Arc<FaceModel>> = OnceLock::new();
    MODEL
        .get_or_init(|| Arc::new(build_face(rig(), None, &Lod::Coarse.settings()).unwrap()))
        .clone()
}

/// Test double: jawOpen rotates the jaw and stretches the tissue near the mouth along y (no
/// tissue rides on the jaw: the rig's chin slides over it), mouthSmile_L contracts it along x,
/// and mouthPucker ≥ 0.9 is refused (to exercise error frames).
pub(crate) struct TestActuation {
    weights: Vec<f64>,
}

impl TestActuation {
    pub(crate) fn new(model: &FaceModel) -> Self {
        let centroids: Vec<Point3<f64>> = model
            .mesh
            .tets
            .iter()
            .map(|t| {
                let s: Vector3<f64> = t
                    .iter()
                    .map(|&v| model.mesh.vertices[v as usize].coords)
                    .sum();
                Point3::from(s / 4.0)
            })
            .collect();
        let (lo, hi) = model.mesh.bounds();
        // The mouth is low and in front: weight elements by closeness to that corner.
        let mouth = Point3::new(0.5 * (lo.x + hi.x), lo.y + 0.35 * (hi.y - lo.y), hi.z);
        let r = 0.25 * (hi - lo).norm();
        let weights = centroids
            .iter()
            .map(|c| (-(c - mouth).norm_squared() / (r * r)).exp())
            .collect();
        TestActuation { weights }
    }
}

impl ActuationModel for TestActuation {
    fn element_count(&self) -> usize {
        self.weights.len()
    }
    fn actuate(&self, codes: &Codes) -> Result<Actuation, DriveError> {
        codes.validate()?;
        let e = &codes.expression;
        if e.get("mouthPucker").unwrap() >= 0.9 {
            return Err(DriveError::BadTensor {
                element: 0,
                reason: "test model refuses mouthPucker ≥ 0.9".into(),
            });
        }
        let smile = e.get("mouthSmile_L").unwrap() * (1.0 + 0.35 * codes.style.0[0]);
        let open = e.get("jawOpen").unwrap();
        let tensors = self
            .weights
            .iter()
            .map(|w| {
                let mut m = Matrix3::identity();
                m[(0, 0)] = 1.0 - 0.3 * smile * w;
                m[(1, 1)] = 1.0 + 0.2 * open * w;
                SymTensor::from_matrix(&m)
            })
            .collect();
        let jaw = RigidMotion {
            rotation: Vector3::new(0.25 * e.get("jawOpen").unwrap(), 0.0, 0.0),
            translation: Vector3::zeros(),
        };
        Ok(Actuation { tensors, jaw })
    }
}

pub(crate) fn test_face(name: &str) -> SessionFace {
    let model = neutral_coarse();
    SessionFace {
        name: name.into(),
        identity: None,
        default_style: StyleCode::NEUTRAL,
        actuation: Arc::new(TestActuation::new(&model)),
        model,
    }
}

/// A session on the test double's faces, contact off: these tests are about the session's
/// frames, requests and protocol (the contact tests below turn it on).
fn session(quality: Quality, refine: bool) -> Session {
    let s = Session::new(vec![test_face("neutral"), test_face("other")], quality).unwrap();
    // Its frames from here on are of these inputs (a session opens with contact on, and its
    // first frame may come before they arrive).
    let g = s
        .submit_all(&[Request::Refine(refine), Request::Contact(false)])
        .unwrap();
    s.wait_generation(g, WAIT).unwrap();
    s
}

fn expression(name: &str, w: f64) -> Request {
    Request::Expression(ExpressionCode::single(name, w).unwrap())
}

fn max_distance(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f32>().sqrt())
        .fold(0.0, f32::max)
}

#[test]
fn a_slider_change_gives_a_new_finite_frame_that_moves_the_face() {
    let s = session(Quality::Interactive, false);
    let first = s.wait_newer(None, WAIT).unwrap();
    assert!(first.error.is_none(), "{:?}", first.error);
    let model = neutral_coarse();
    assert_eq!(first.positions.len(), model.render.rest.len());
    assert_eq!(first.normals.len(), first.positions.len());
    let g = s.submit(expression("jawOpen", 0.8)).unwrap();
    let f = s.wait_generation(g, WAIT).unwrap();
    assert!(f.error.is_none(), "{:?}", f.error);
    assert_eq!(f.codes.expression.get("jawOpen"), Some(0.8));
    assert!(
        max_distance(&f.positions, &first.positions) > 0.3,
        "the jaw must move the face"
    );
    assert!(f.positions.iter().flatten().all(|c| c.is_finite()));
    assert_eq!(
        f.heatmaps.len(),
        2,
        "displacement and volume ratio by default"
    );
    assert!(
        f.heatmaps
            .iter()
            .all(|h| h.values.len() == f.positions.len())
    );
    assert!(f.stats.iterations > 0 && f.stats.total_ms > 0.0);
}

#[test]
fn a_flood_of_requests_is_coalesced_into_few_solves() {
    let s = session(Quality::Interactive, false);
    s.wait_newer(None, WAIT).unwrap();
    let solves = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let counter = solves.clone();
    s.on_frame(move |_| {
        counter.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
    });
    let mut last = 0;
    for i in 1..=500 {
        last = s
            .submit(expression("mouthSmile_L", i as f64 / 500.0))
            .unwrap();
    }
    let f = s.wait_generation(last, WAIT).unwrap();
    assert_eq!(f.generation, last);
    assert_eq!(
        f.codes.expression.get("mouthSmile_L"),
        Some(1.0),
        "the latest request wins"
    );
    let n = solves.load(std::sync::atomic::Ordering::SeqCst);
    assert!(n < 50, "{n} solves for 500 requests");
}

#[test]
fn solves_warm_start_from_the_last_frame() {
    let s = session(Quality::Final, false);
    s.wait_newer(None, WAIT).unwrap();
    let g = s.submit(expression("mouthSmile_L", 0.6)).unwrap();
    let cold = s.wait_generation(g, WAIT).unwrap();
    // Same inputs again via another generation (display change): starts at the solution.
    let g = s
        .submit(Request::Display(Display {
            crosses: true,
            heatmaps: true,
        }))
        .unwrap();
    let warm = s.wait_generation(g, WAIT).unwrap();
    assert!(cold.stats.iterations > 5, "{:?}", cold.stats);
    assert!(
        warm.stats.iterations <= 1,
        "warm start must be at the solution: {:?}",
        warm.stats
    );
    // Only the display changed: the frame reuses the solve (no solve ran), with the same
    // geometry, and the new overlays computed.
    assert!(warm.stats.reused && !cold.stats.reused, "{:?}", warm.stats);
    assert_eq!(warm.positions, cold.positions);
    assert_eq!(warm.stats.residual, cold.stats.residual);
    // A new code solves again.
    let g = s.submit(expression("mouthSmile_L", 0.5)).unwrap();
    let moved = s.wait_generation(g, WAIT).unwrap();
    assert!(!moved.stats.reused && moved.stats.iterations > 0);
    assert!(!warm.crosses.is_empty(), "the smile contracts elements");
    assert!(warm.crosses.iter().all(|a| a.contraction > 0.0));
}

#[test]
fn resting_inputs_are_refined_to_final_quality() {
    let s = session(Quality::Interactive, true);
    let g = s.submit(expression("mouthSmile_L", 0.7)).unwrap();
    let first = s.wait_generation(g, WAIT).unwrap();
    assert_eq!(first.quality, Quality::Interactive);
    let fin = s
        .wait_until_test(|f| f.generation == g && f.quality == Quality::Final)
        .expect("refined to final");
    assert!(
        fin.stats.residual <= Quality::Final.settings().tolerance
            || fin.stats.termination != crate::sim::Termination::Converged
    );
    assert!(fin.stats.residual <= first.stats.residual);
}

#[test]
fn failures_become_error_frames_with_the_last_good_geometry_and_the_session_recovers() {
    let s = session(Quality::Interactive, false);
    let g = s.submit(expression("jawOpen", 0.5)).unwrap();
    let good = s.wait_generation(g, WAIT).unwrap();
    let g = s.submit(expression("mouthPucker", 0.95)).unwrap();
    let bad = s.wait_generation(g, WAIT).unwrap();
    let message = bad.error.as_deref().expect("an error frame");
    assert!(message.contains("mouthPucker"), "{message}");
    assert_eq!(
        bad.positions, good.positions,
        "the last good geometry stays"
    );
    assert!(bad.index > good.index);
    let g = s.submit(expression("jawOpen", 0.5)).unwrap();
    let again = s.wait_generation(g, WAIT).unwrap();
    assert!(again.error.is_none());
    assert!(max_distance(&again.positions, &good.positions) < 1e-3);
}

#[test]
fn bad_requests_are_rejected_and_change_nothing() {
    let s = session(Quality::Interactive, false);
    let before = s.inputs();
    let mut e = ExpressionCode::NEUTRAL;
    e.0[3] = f64::NAN;
    let err = s.submit(Request::Expression(e)).unwrap_err();
    assert!(err.to_string().contains("jawForward"), "{err}");
    assert!(matches!(
        s.submit(Request::Face(7)),
        Err(SessionError::FaceOutOfRange { index: 7, count: 2 })
    ));
    assert_eq!(s.inputs(), before);
}

#[test]
fn the_same_requests_give_bitwise_the_same_frames() {
    let run = || {
        let s = session(Quality::Preview, false);
        let mut frames = Vec::new();
        for r in [
            expression("jawOpen", 0.4),
            expression("mouthSmile_L", 0.8),
            Request::Face(1),
            Request::Style(StyleCode([0.5, 0.0, 0.0, 0.0])),
        ] {
            let g = s.submit(r).unwrap();
            frames.push(s.wait_generation(g, WAIT).unwrap());
        }
        frames
    };
    let (a, b) = (run(), run());
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.positions, y.positions);
        assert_eq!(x.heatmaps, y.heatmaps);
        assert_eq!(x.stats.iterations, y.stats.iterations);
    }
    assert_eq!(a[2].face, 1);
}

impl Session {
    fn wait_until_test(&self, done: impl Fn(&frame::Frame) -> bool) -> Option<Arc<frame::Frame>> {
        let deadline = std::time::Instant::now() + WAIT;
        let mut after = None;
        while std::time::Instant::now() < deadline {
            let f = self.wait_newer(after, Duration::from_secs(5))?;
            if done(&f) {
                return Some(f);
            }
            after = Some(f.index);
        }
        None
    }
}

mod protocol_tests {
    use std::io::{BufRead, BufReader, Read, Write};
    use std::net::{TcpListener, TcpStream};
    use std::time::Duration;

    use super::*;
    use crate::session::client::Connection;
    use crate::session::protocol::{Entries, Message, Reply};
    use crate::session::server::{AccessError, MAX_PENDING, ServerSettings};
    use crate::session::token::{Token, TokenError};

    const TOKEN: &str = "a-test-token-0123456789";

    fn settings() -> ServerSettings {
        ServerSettings::new(Token::new(TOKEN).unwrap())
    }

    fn server() -> (Arc<Session>, String) {
        server_with(settings())
    }

    fn server_with(settings: ServerSettings) -> (Arc<Session>, String) {
        let s = Arc::new(session(Quality::Interactive, false));
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        let served = s.clone();
        std::thread::spawn(move || crate::session::server::serve(listener, served, settings));
        (s, addr)
    }

    fn hello() -> Message {
        Message::Hello {
            token: Some(TOKEN.into()),
        }
    }

    /// A connection that has not said hello.
    fn unauthenticated(addr: &str) -> (TcpStream, BufReader<TcpStream>) {
        let s = TcpStream::connect(addr).unwrap();
        let r = BufReader::new(s.try_clone().unwrap());
        (s, r)
    }

    /// A connection past its hello.
    fn raw(addr: &str) -> (TcpStream, BufReader<TcpStream>) {
        let (mut out, mut input) = unauthenticated(addr);
        let line = serde_json::to_string(&hello()).unwrap();
        assert_eq!(ask(&mut out, &mut input, &line)["reply"], "hello");
        (out, input)
    }

    /// Whether the server has closed `input` (EOF or reset), reading past any replies; false
    /// if it is still open after 5 s.
    fn closed_by_server(input: &mut BufReader<TcpStream>) -> bool {
        input
            .get_ref()
            .set_read_timeout(Some(Duration::from_secs(5)))
            .unwrap();
        let mut rest = Vec::new();
        match input.read_to_end(&mut rest) {
            Ok(_) => true,
            Err(e) => !matches!(
                e.kind(),
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
            ),
        }
    }

    fn ask(out: &mut TcpStream, input: &mut BufReader<TcpStream>, line: &str) -> serde_json::Value {
        out.write_all(line.as_bytes()).unwrap();
        out.write_all(b"\n").unwrap();
        let mut reply = String::new();
        input.read_line(&mut reply).unwrap();
        serde_json::from_str(&reply).unwrap()
    }

    #[test]
    fn good_messages_set_inputs_and_return_frames() {
        let (s, addr) = server();
        let mut c = Connection::open(&addr, None).unwrap();
        let Reply::Hello {
            faces,
            expression_names,
            ..
        } = c.request(&hello()).unwrap()
        else {
            panic!("hello")
        };
        assert_eq!(faces.len(), 2);
        assert_eq!(expression_names.len(), 19);
        let reply = c
            .request(&Message::SetCodes {
                expression: Some(Entries::Named([("jawOpen".to_string(), 0.6)].into())),
                style: None,
            })
            .unwrap();
        let Reply::Ok { generation } = reply else {
            panic!("{reply:?}")
        };
        assert_eq!(s.inputs().codes.expression.get("jawOpen"), Some(0.6));
        let f = s.wait_generation(generation, WAIT).unwrap();
        let Reply::Frame { frame } = c
            .request(&Message::GetFrame {
                after: Some(f.index - 1),
                timeout_ms: Some(5000),
                geometry: Some(true),
                encoding: None,
                base: None,
            })
            .unwrap()
        else {
            panic!("frame")
        };
        assert_eq!(frame.codes.expression.get("jawOpen"), Some(0.6));
        assert_eq!(frame.positions.len(), neutral_coarse().render.rest.len());
        let Reply::Topology { topology, .. } =
            c.request(&Message::GetTopology { face: 1 }).unwrap()
        else {
            panic!("topology")
        };
        assert_eq!(topology.rest.len(), frame.positions.len());
    }

    #[test]
    fn bad_messages_get_clear_errors_and_change_nothing() {
        let (s, addr) = server();
        let (mut out, mut input) = raw(&addr);
        let before = s.inputs();
        for (line, needle) in [
            ("not json", "malformed"),
            (r#"{"op":"fly"}"#, "unknown variant"),
            (
                r#"{"op":"set_codes","expression":{"jawOpen":1.5}}"#,
                "outside [0, 1]",
            ),
            (
                r#"{"op":"set_codes","expression":{"smirk":0.5}}"#,
                "unknown expression entry 'smirk'",
            ),
            (
                r#"{"op":"set_codes","expression":[0.1,0.2]}"#,
                "needs 19 values",
            ),
            (
                r#"{"op":"set_codes","style":{"jaw":-3}}"#,
                "outside [-1, 1]",
            ),
            (r#"{"op":"set_codes"}"#, "needs `expression`"),
            (r#"{"op":"set_face","face":9}"#, "out of range"),
            (r#"{"op":"set_face","face":"nobody"}"#, "no face"),
            (
                r#"{"op":"set_quality","quality":"ultra"}"#,
                "unknown variant",
            ),
            (r#"{"op":"get_topology","face":5}"#, "out of range"),
            (
                r#"{"op":"get_frame","timeout_ms":999999}"#,
                "over the limit",
            ),
            (r#"{"op":"set_display","crosess":true}"#, "unknown field"),
            (
                r#"{"op":"set_quality","quality":"final","contact":"yes"}"#,
                "invalid type",
            ),
        ] {
            let reply = ask(&mut out, &mut input, line);
            assert_eq!(reply["reply"], "error", "{line} → {reply}");
            let message = reply["message"].as_str().unwrap();
            assert!(message.contains(needle), "{line} → {message}");
        }
        assert_eq!(s.inputs(), before, "rejected messages change nothing");
        // The connection still works after errors.
        assert_eq!(
            ask(
                &mut out,
                &mut input,
                r#"{"op":"set_quality","quality":"preview","contact":true}"#
            )["reply"],
            "ok"
        );
        assert_eq!(s.inputs().quality, Quality::Preview);
        assert!(s.inputs().contact);
        // An over-long line is refused and the connection closed.
        let long = format!("{{\"op\":\"hello\",\"pad\":\"{}\"}}", "x".repeat(70_000));
        let reply = ask(&mut out, &mut input, &long);
        assert!(reply["message"].as_str().unwrap().contains("longer than"));
    }

    #[test]
    fn floods_coalesce_and_disconnects_leave_other_clients_working() {
        let (s, addr) = server();
        s.wait_newer(None, WAIT).unwrap();
        let frames = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let counter = frames.clone();
        s.on_frame(move |_| {
            counter.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        });
        // A client that connects, sends half a line and vanishes.
        {
            let mut gone = TcpStream::connect(&addr).unwrap();
            gone.write_all(br#"{"op":"set_co"#).unwrap();
        }
        // Another that asks for a frame and disconnects without reading the reply.
        {
            let mut gone = TcpStream::connect(&addr).unwrap();
            gone.write_all(b"{\"op\":\"get_frame\",\"timeout_ms\":100}\n")
                .unwrap();
        }
        // Two clients flood the same slider: all lines at once, replies read afterwards.
        let flood = |addr: String, offset: f64| {
            std::thread::spawn(move || {
                let (mut out, mut input) = raw(&addr);
                let lines: String = (0..300)
                    .map(|i| {
                        let w = offset + 0.5 * i as f64 / 299.0;
                        format!(
                            "{{\"op\":\"set_codes\",\"expression\":{{\"mouthSmile_L\":{w}}}}}\n"
                        )
                    })
                    .collect();
                out.write_all(lines.as_bytes()).unwrap();
                for _ in 0..300 {
                    let mut reply = String::new();
                    input.read_line(&mut reply).unwrap();
                    assert!(reply.contains("\"ok\""), "{reply}");
                }
            })
        };
        let (a, b) = (flood(addr.clone(), 0.0), flood(addr.clone(), 0.5));
        a.join().unwrap();
        b.join().unwrap();
        let g = s.submit(Request::Refine(false)).unwrap();
        let last = s.wait_generation(g, WAIT).unwrap();
        let w = last.codes.expression.get("mouthSmile_L").unwrap();
        assert!(
            w == 0.5 || w == 1.0,
            "one of the floods' last values wins, got {w}"
        );
        let n = frames.load(std::sync::atomic::Ordering::SeqCst);
        assert!(n < 150, "600 slider messages must coalesce, got {n} frames");
        // The server still answers new clients.
        let mut c = Connection::open(&addr, None).unwrap();
        assert!(matches!(c.request(&hello()).unwrap(), Reply::Hello { .. }));
    }

    /// Binary frames: the geometry of a JSON frame within the quantum (normals and heatmaps
    /// rebuilt), at a fraction of its size, and a delta on the frame the client holds.
    #[test]
    fn binary_frames_carry_the_same_geometry_in_few_bytes() {
        use crate::session::client::FrameAssembler;
        use crate::session::protocol::Encoding;
        use crate::session::wire::QUANTUM;
        let (s, addr) = server();
        let mut c = Connection::open(&addr, None).unwrap();
        c.request(&hello()).unwrap();
        let Reply::Topology { topology, .. } =
            c.request(&Message::GetTopology { face: 0 }).unwrap()
        else {
            panic!("topology")
        };
        let mut drawn: Vec<usize> = topology
            .triangles
            .iter()
            .flatten()
            .map(|&v| v as usize)
            .collect();
        drawn.sort_unstable();
        drawn.dedup();
        let mut assembler = FrameAssembler::default();
        let fetch = |c: &mut Connection, index: u64, encoding, base| {
            c.request(&Message::GetFrame {
                after: Some(index - 1),
                timeout_ms: Some(5000),
                geometry: None,
                encoding: Some(encoding),
                base,
            })
            .unwrap()
        };
        // Deltas carry on across the plain and the deflated binary encodings.
        let steps = [
            (0.3, Encoding::Binary),
            (0.35, Encoding::BinaryDeflate),
            (0.4, Encoding::Binary),
        ];
        for (step, (jaw, encoding)) in steps.into_iter().enumerate() {
            let g = s.submit(expression("jawOpen", jaw)).unwrap();
            let f = s.wait_generation(g, WAIT).unwrap();
            let Reply::Frame { frame: json } = fetch(&mut c, f.index, Encoding::Json, None) else {
                panic!("json frame")
            };
            let base = assembler.base();
            assert_eq!(base.is_some(), step > 0);
            let Reply::FrameData {
                frame,
                payload,
                deflated,
                bytes,
            } = fetch(&mut c, f.index, encoding, base)
            else {
                panic!("binary frame")
            };
            assert_eq!(deflated, encoding == Encoding::BinaryDeflate);
            assert_eq!(deflated, bytes < payload.len());
            let binary = assembler.assemble(*frame, &payload, &topology).unwrap();
            assert_eq!(binary.index, json.index);
            assert_eq!(binary.stats, json.stats);
            let json_bytes = serde_json::to_vec(&Reply::Frame {
                frame: json.clone(),
            })
            .unwrap()
            .len();
            assert!(
                payload.len() * 10 < json_bytes,
                "{} payload bytes against {json_bytes} of JSON",
                payload.len()
            );
            let worst = |a: &[[f32; 3]], b: &[[f32; 3]]| {
                assert_eq!(a.len(), b.len());
                a.iter()
                    .zip(b)
                    .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs()))
                    .fold(0.0f32, f32::max)
            };
            let quantum = (0.5 * QUANTUM) as f32 + 1e-5;
            assert!(worst(&binary.positions, &json.positions) <= quantum);
            assert!(worst(&binary.mesh_positions, &json.mesh_positions) <= quantum);
            // The client recomputes normals over the triangles the viewers draw; the eyes'
            // see-through layers, which they leave out, have none there.
            let (drawn_binary, drawn_json): (Vec<[f32; 3]>, Vec<[f32; 3]>) = drawn
                .iter()
                .map(|&v| (binary.normals[v], json.normals[v]))
                .unzip();
            assert!(worst(&drawn_binary, &drawn_json) < 0.05);
            assert_eq!(binary.heatmaps.len(), json.heatmaps.len());
            assert!(!json.heatmaps.is_empty());
            for (b, j) in binary.heatmaps.iter().zip(&json.heatmaps) {
                assert_eq!((&b.name, b.legend.max), (&j.name, j.legend.max));
                for (x, y) in b.values.iter().zip(&j.values) {
                    assert!(
                        (x - y).abs() <= y.abs() / 2048.0 + 1e-7,
                        "{}: {x} {y}",
                        b.name
                    );
                }
            }
        }
    }

    /// Inside TLS (`serve --tls-cert`): the protocol and binary frames work for a client
    /// that trusts the certificate, the token is still required, and a plain client gets no
    /// reply it can read.
    #[test]
    fn tls_carries_the_protocol_and_keeps_the_token() {
        use crate::session::client::ClientError;
        use crate::session::protocol::Encoding;
        use crate::session::tls::{ClientTls, ServerTls, test_identity};
        let dir = std::env::temp_dir().join(format!("facesim-tls-proto-{}", std::process::id()));
        let (cert, key) = test_identity(&dir);
        let tls = ServerTls::from_pem_files(&cert, &key).unwrap();
        let (s, addr) = server_with(settings().with_tls(Some(tls)));
        let trust = ClientTls::trusting(&cert).unwrap();
        let mut c = Connection::open(&addr, Some(&trust)).unwrap();
        let (faces, _) = c.hello(TOKEN).unwrap();
        assert_eq!(faces.len(), 2);
        let g = s.submit(expression("jawOpen", 0.4)).unwrap();
        let f = s.wait_generation(g, WAIT).unwrap();
        let reply = c
            .request(&Message::GetFrame {
                after: Some(f.index - 1),
                timeout_ms: Some(5000),
                geometry: None,
                encoding: Some(Encoding::Binary),
                base: None,
            })
            .unwrap();
        let Reply::FrameData { bytes, payload, .. } = reply else {
            panic!("{reply:?}")
        };
        assert!(bytes > 1000 && payload.len() == bytes);

        let mut guess = Connection::open(&addr, Some(&trust)).unwrap();
        let refused = guess.hello("guess-guess-guess-guess");
        assert!(
            matches!(&refused, Err(ClientError::Refused(m)) if m.contains("wrong token")),
            "{refused:?}"
        );
        let mut plain = Connection::open(&addr, None).unwrap();
        assert!(plain.hello(TOKEN).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn connections_without_the_token_are_refused_and_closed() {
        let (s, addr) = server();
        let before = s.inputs();
        for (first, needle) in [
            (
                r#"{"op":"set_codes","expression":{"jawOpen":1}}"#,
                "authenticate first",
            ),
            (r#"{"op":"hello"}"#, "authenticate first"),
            (
                r#"{"op":"hello","token":"a-test-token-0123456780"}"#,
                "wrong token",
            ),
            (r#"{"op":"hello","token":""}"#, "wrong token"),
            ("not json", "authenticate first"),
        ] {
            let (mut out, mut input) = unauthenticated(&addr);
            let reply = ask(&mut out, &mut input, first);
            assert_eq!(reply["reply"], "error", "{first} → {reply}");
            let message = reply["message"].as_str().unwrap();
            assert!(message.contains(needle), "{first} → {message}");
            assert!(closed_by_server(&mut input), "{first}: still open");
        }
        assert_eq!(s.inputs(), before, "refused clients change nothing");
        // A later hello on an authenticated connection needs no token.
        let (mut out, mut input) = raw(&addr);
        assert_eq!(
            ask(&mut out, &mut input, r#"{"op":"hello"}"#)["reply"],
            "hello"
        );
    }

    #[test]
    fn silent_connections_never_lock_out_a_client_with_the_token() {
        let (s, addr) = server();
        let (mut editor, mut editor_in) = raw(&addr);
        let silent: Vec<_> = (0..64).map(|_| unauthenticated(&addr)).collect();
        // The authenticated client still edits, and a new one still gets in, long before
        // the silent ones' 5 s handshake timeout.
        let started = std::time::Instant::now();
        let reply = ask(
            &mut editor,
            &mut editor_in,
            r#"{"op":"set_codes","expression":{"jawOpen":0.4}}"#,
        );
        assert_eq!(reply["reply"], "ok", "{reply}");
        let (mut late, mut late_in) = raw(&addr);
        let reply = ask(
            &mut late,
            &mut late_in,
            r#"{"op":"get_frame","geometry":false}"#,
        );
        assert_eq!(reply["reply"], "frame", "{reply}");
        assert!(started.elapsed() < Duration::from_secs(4));
        assert_eq!(s.inputs().codes.expression.get("jawOpen"), Some(0.4));
        // Each connection past MAX_PENDING pushed out the oldest silent one, the late
        // client's too.
        let pushed_out = 64 - MAX_PENDING + 1;
        let mut closed = 0;
        for (_, mut input) in silent.into_iter().take(pushed_out) {
            input
                .get_ref()
                .set_read_timeout(Some(Duration::from_secs(2)))
                .unwrap();
            let mut rest = Vec::new();
            closed += usize::from(input.read_to_end(&mut rest).is_ok());
        }
        assert_eq!(closed, pushed_out);
    }

    #[test]
    fn silent_and_stalled_clients_time_out() {
        let (s, addr) = server_with(ServerSettings {
            handshake_timeout: Duration::from_millis(200),
            idle_timeout: Duration::from_millis(400),
            write_timeout: Duration::from_millis(300),
            ..settings()
        });
        // Never says hello.
        let (_out, mut input) = unauthenticated(&addr);
        let mut line = String::new();
        input.read_line(&mut line).unwrap();
        assert!(line.contains("no hello within"), "{line}");
        assert!(closed_by_server(&mut input));
        // Says hello, then nothing: what a half-open client looks like from the server.
        let (_out, mut input) = raw(&addr);
        line.clear();
        input.read_line(&mut line).unwrap();
        assert!(line.contains("no request for"), "{line}");
        assert!(closed_by_server(&mut input));
        // Asks for frame after frame and never reads them: the server's writes stall and it
        // closes the client instead of buffering its replies.
        let (out, mut input) = raw(&addr);
        let mut flood = out.try_clone().unwrap();
        let writer = std::thread::spawn(move || {
            let line = b"{\"op\":\"get_frame\"}\n";
            for _ in 0..100_000 {
                if flood.write_all(line).is_err() {
                    return;
                }
            }
        });
        std::thread::sleep(Duration::from_secs(2));
        assert!(closed_by_server(&mut input), "a stalled client is closed");
        writer.join().unwrap();
        // The server still serves others.
        let (mut out, mut input) = raw(&addr);
        assert_eq!(
            ask(
                &mut out,
                &mut input,
                r#"{"op":"set_quality","quality":"preview"}"#
            )["reply"],
            "ok"
        );
        assert_eq!(s.inputs().quality, Quality::Preview);
    }

    #[test]
    fn serving_beyond_loopback_needs_a_chosen_token() {
        let local = "127.0.0.1:7878".parse().unwrap();
        let public = "0.0.0.0:7878".parse().unwrap();
        let (generated, shown) = ServerSettings::for_listen(&[local], None).unwrap();
        assert!(shown && generated.token.reveal().len() == 32);
        assert_eq!(
            ServerSettings::for_listen(&[local, public], None).unwrap_err(),
            AccessError::PublicWithoutToken(public)
        );
        let (chosen, shown) = ServerSettings::for_listen(&[public], Some(TOKEN)).unwrap();
        assert!(!shown && chosen.token.accepts(TOKEN));
        assert_eq!(
            ServerSettings::for_listen(&[local], Some("hunter2")).unwrap_err(),
            AccessError::Token(TokenError::TooShort(7))
        );
    }
}

/// Contact in the session: a session opens with contact on, and on the sample's template
/// with its basis the lower lip rolled in at full weight solves to a valid frame with contact
/// pairs reported and no crossing of the contact surface (checked here: the interactive solve
/// does not audit); switching contact off reports none.
#[test]
fn contact_on_keeps_the_rolled_lips_apart_in_the_session() {
    let sample = crate::sample::Sample::load(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(crate::sample::SAMPLE_DIR),
    )
    .unwrap();
    let s = Session::new(sample.session_faces()[..1].to_vec(), Quality::Interactive).unwrap();
    assert!(s.inputs().contact, "a session opens with contact on");
    s.submit(Request::Refine(false)).unwrap();
    let g = s.submit(expression("mouthRollLower", 1.0)).unwrap();
    let on = s.wait_generation(g, WAIT).unwrap();
    assert!(on.error.is_none(), "{:?}", on.error);
    assert!(on.stats.contacts.is_some_and(|c| c > 0), "{:?}", on.stats);
    assert!(on.positions.iter().flatten().all(|v| v.is_finite()));
    let contact = crate::contact::surface::FaceContact::new(
        &sample.faces[0].model,
        &crate::model::contact_region::FaceContactSettings::default(),
    )
    .unwrap();
    let y: Vec<f64> = contact
        .render_vertices()
        .iter()
        .flat_map(|&v| on.positions[v as usize].map(f64::from))
        .collect();
    assert!(contact.new_crossings(&y).is_empty());
    let g = s.submit(Request::Contact(false)).unwrap();
    let off = s.wait_generation(g, WAIT).unwrap();
    assert_eq!(off.stats.contacts, None);
}

/// What the artist sees at the final preset with contact is crossing-free inside the mouth
/// too: the smile's final frame carries the deep lining's pass (it ran, converged and moved
/// the cheeks' inside off the lower teeth), and the independent audit of the frame's render
/// surface finds no crossing. An interactive frame leaves the pass out.
#[test]
fn final_frames_with_contact_keep_the_deep_lining_off_the_teeth() {
    let faces = sample_faces()[..1].to_vec();
    let model = faces[0].model.clone();
    let s = Session::new(faces.clone(), Quality::Final).unwrap();
    s.submit_all(&[Request::Refine(false), Request::Contact(true)])
        .unwrap();
    let g = s.submit(expression("mouthSmile_L", 1.0)).unwrap();
    let f = s.wait_generation(g, WAIT).unwrap();
    assert!(
        f.error.is_none() && f.stats.converged,
        "{:?} {:?}",
        f.error,
        f.stats
    );
    let lining = f
        .stats
        .lining
        .as_ref()
        .expect("final frames with contact run the pass");
    assert!(lining.converged && lining.largest_push > 0.05, "{lining:?}");
    let positions: Vec<nalgebra::Point3<f64>> = f
        .positions
        .iter()
        .map(|p| nalgebra::Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .collect();
    let audit = crate::model::audit::CrossingAudit::new(&model);
    assert_eq!(audit.audit(&model, &positions).pairs, 0);

    let s = Session::new(faces, Quality::Interactive).unwrap();
    s.submit_all(&[Request::Refine(false), Request::Contact(true)])
        .unwrap();
    let g = s.submit(expression("mouthSmile_L", 0.2)).unwrap();
    let f = s.wait_generation(g, WAIT).unwrap();
    assert_eq!(f.stats.lining, None);
}

/// The bundled sample's faces as the editor opens them (the actuation basis).
fn sample_faces() -> Vec<SessionFace> {
    crate::sample::Sample::load(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(crate::sample::SAMPLE_DIR),
    )
    .unwrap()
    .session_faces()
}

/// What the solver could not bring to an equilibrium is never presented as a frame of the
/// preset: mouthClose at twice its full weight presses the lips through each other, and
/// without contact at the final preset its solve ends at the iteration cap with the net
/// force far above the element forces (residual 0.09, 10⁴ times the tolerance is 0.01), also
/// from rest: an error frame with the last good geometry. At the interactive preset
/// mouthClose at full weight (346 iterations to converge at the final preset) stops capped:
/// a frame, marked unconverged (the editor, the protocol and the export read
/// `stats.converged`).
#[test]
fn a_solve_without_equilibrium_is_an_error_frame_and_a_capped_one_is_marked() {
    let s = Session::new(sample_faces(), Quality::Final).unwrap();
    // The frame of these inputs (a session opens with contact on, and its first frame may
    // come before they arrive).
    let g = s
        .submit_all(&[Request::Refine(false), Request::Contact(false)])
        .unwrap();
    let rest = s.wait_generation(g, WAIT).unwrap();
    assert!(
        rest.error.is_none() && rest.stats.converged,
        "{:?}",
        rest.stats
    );
    let g = s.submit(expression("mouthClose", 2.0)).unwrap();
    let f = s.wait_generation(g, WAIT).unwrap();
    let error = f.error.as_deref().unwrap_or_default();
    assert!(error.contains("no equilibrium"), "{error:?}, {:?}", f.stats);
    assert!(!f.stats.converged);
    assert_eq!(f.positions, rest.positions, "the last good geometry");

    let s = Session::new(sample_faces(), Quality::Interactive).unwrap();
    let g = s
        .submit_all(&[Request::Refine(false), Request::Contact(false)])
        .unwrap();
    s.wait_generation(g, WAIT).unwrap();
    let g = s.submit(expression("mouthClose", 1.0)).unwrap();
    let f = s.wait_generation(g, WAIT).unwrap();
    assert!(f.error.is_none(), "{:?}", f.error);
    assert_eq!(f.stats.termination, crate::sim::Termination::IterationCap);
    assert!(!f.stats.converged, "{:?}", f.stats);
}

/// The viewers' topology: the whole head, without the eyes' see-through layers (they would
/// hide the eyes), the eyes coloured by part, and only the mouth's inside under the "teeth"
/// toggle.
#[test]
fn the_topology_shows_the_eyes_and_leaves_out_their_see_through_layers() {
    let model = neutral_coarse();
    let topology = FaceTopology::of("neutral", &model);
    let render = &model.render;
    let overlay: usize = render
        .parts
        .iter()
        .filter(|p| session_face::OVERLAY_PARTS.contains(&p.name.as_str()))
        .map(|p| p.triangles.len())
        .sum();
    assert!(overlay > 0);
    assert_eq!(topology.triangles.len() + overlay, render.triangles.len());
    let iris = render
        .parts
        .iter()
        .find(|p| p.name == "M_IrisLeft")
        .unwrap();
    let v = render.triangles[iris.triangles.start as usize][0] as usize;
    assert_ne!(topology.colors[v], session_face::SKIN_COLOR);
    assert!(
        !topology.rigid[v],
        "the eyes are not under the teeth toggle"
    );
    let teeth = render.parts.iter().find(|p| p.name == "M_Teeth").unwrap();
    let t = render.triangles[teeth.triangles.start as usize][0] as usize;
    assert!(topology.rigid[t]);
    assert_eq!(topology.colors[t], session_face::INNER_COLOR);
}
