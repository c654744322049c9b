//! The four networks of the multi-identity model and their file.
//!
//! - Expression encoder E_x: 19 → GeLU → e, style encoder E_s: 4 → GeLU → s (the "tiny MLPs,
//!   akin to learned positional encoding"); z = [e; s].
//! - N_A: canonical position X̂ (normalized by the canonical frame) → SIREN first layer (the
//!   learnable positional encoding) → GeLU layers with Lipschitz weight normalization, each
//!   modulated by tanh(z) → the 6 entries of log A (`[xx, yy, zz, xy, xz, yz]`).
//! - N_B: tanh(z) → GeLU → GeLU → jaw `[θ; t]` (rad, cm) about the face's pivot.
//!
//! **Why log A.** `A = exp(log A)` is symmetric positive definite for any finite output, and
//! the log-Euclidean space is the one the actuation basis blends in (so stage-1 targets,
//! the baseline and the networks share one metric; zero output is exactly the rest `A = I`).
//! Because N_A sees the code only through tanh and its positions are fixed per face, its
//! output is bounded for any code, also far beyond the sliders' ranges. N_B also takes
//! tanh(z) so the jaw stays bounded too.

use faer::Mat;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::GenerativeError;
use crate::drive::Codes;
use crate::model::FaceModel;
use crate::nn::{Checkpoint, LayerSpec, Mlp, MlpSpec};
use crate::rig::{ExpressionCode, StyleCode};

/// Layer sizes (defaults: the nn kit's benchmark measured width 64 for the 5 ms target).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Architecture {
    pub expression_hidden: usize,
    /// Width of e.
    pub expression_dim: usize,
    pub style_hidden: usize,
    /// Width of s.
    pub style_dim: usize,
    /// Width of N_A's layers.
    pub actuation_width: usize,
    /// GeLU layers of N_A after the SIREN layer.
    pub actuation_gelu_layers: usize,
    /// ω₀ of N_A's SIREN layer (inputs in about [−1, 1]³).
    pub omega0: f64,
    /// Width of N_B's two GeLU layers.
    pub jaw_width: usize,
}

impl Default for Architecture {
    fn default() -> Self {
        Architecture {
            expression_hidden: 64,
            expression_dim: 32,
            style_hidden: 32,
            style_dim: 16,
            actuation_width: 64,
            actuation_gelu_layers: 3,
            omega0: 10.0,
            jaw_width: 64,
        }
    }
}

impl Architecture {
    /// Dimension of z.
    pub fn code_dim(&self) -> usize {
        self.expression_dim + self.style_dim
    }

    pub fn expression_spec(&self) -> MlpSpec {
        MlpSpec::new(ExpressionCode::LEN)
            .layer(LayerSpec::gelu(self.expression_hidden))
            .layer(LayerSpec::linear(self.expression_dim))
    }

    pub fn style_spec(&self) -> MlpSpec {
        MlpSpec::new(StyleCode::LEN)
            .layer(LayerSpec::gelu(self.style_hidden))
            .layer(LayerSpec::linear(self.style_dim))
    }

    pub fn actuation_spec(&self) -> MlpSpec {
        self.field_spec(6)
    }

    /// The displacement baseline's network ([`super::displacement`]): N_A's shape with 3
    /// outputs, a displacement (cm).
    pub fn displacement_spec(&self) -> MlpSpec {
        self.field_spec(3)
    }

    /// A network over canonical positions X̂ modulated by the code: SIREN first layer, then
    /// Lipschitz GeLU layers that take the code, then `outputs` linear outputs.
    fn field_spec(&self, outputs: usize) -> MlpSpec {
        let mut spec = MlpSpec::new(3)
            .with_code_dim(self.code_dim())
            .layer(LayerSpec::siren_first(self.actuation_width, self.omega0));
        for _ in 0..self.actuation_gelu_layers {
            spec = spec.layer(
                LayerSpec::gelu(self.actuation_width)
                    .lipschitz()
                    .with_code(),
            );
        }
        spec.layer(LayerSpec::linear(outputs))
    }

    pub fn jaw_spec(&self) -> MlpSpec {
        MlpSpec::new(self.code_dim())
            .layer(LayerSpec::gelu(self.jaw_width))
            .layer(LayerSpec::gelu(self.jaw_width))
            .layer(LayerSpec::linear(6))
    }
}

/// The normalization of canonical positions: X̂ = (X − center)/scale (the template face's
/// tissue bounding-box centre and half its largest extent, as φ's frame uses).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CanonicalFrame {
    pub center: [f64; 3],
    pub scale: f64,
}

impl CanonicalFrame {
    /// The frame of the canonical (template) face.
    pub fn of(canonical: &FaceModel) -> Self {
        let f = crate::mapping::Normalization::between(canonical, canonical);
        CanonicalFrame {
            center: f.canonical_center,
            scale: f.scale,
        }
    }

    pub fn normalize(&self, p: &Point3<f64>) -> [f64; 3] {
        [0, 1, 2].map(|k| (p[k] - self.center[k]) / self.scale)
    }
}

/// The networks (module docs), in f64 (training; inference casts N_A to f32).
#[derive(Clone, Debug, PartialEq)]
pub struct GenerativeNets {
    pub architecture: Architecture,
    pub frame: CanonicalFrame,
    pub expression: Mlp<f64>,
    pub style: Mlp<f64>,
    pub actuation: Mlp<f64>,
    pub jaw: Mlp<f64>,
}

/// Names of the networks in a [`Checkpoint`].
pub const NET_NAMES: [&str; 4] = ["expression", "style", "actuation", "jaw"];
const GENERATIVE_FILE: NetFile = NetFile {
    kind: "facesim-generative",
    what: "generative-model",
    version_key: "generative_version",
    version: GENERATIVE_VERSION,
    names: NET_NAMES,
};
/// Bump when the meaning of the stored networks changes.
pub const GENERATIVE_VERSION: u32 = 1;

impl GenerativeNets {
    /// Fresh networks, initialized deterministically from `seed` (one stream per network).
    pub fn new(
        architecture: Architecture,
        frame: CanonicalFrame,
        seed: u64,
    ) -> Result<Self, GenerativeError> {
        if !(frame.scale > 0.0) || frame.center.iter().any(|c| !c.is_finite()) {
            return Err(GenerativeError::Config(format!(
                "canonical frame {frame:?}"
            )));
        }
        let s = |k: u64| seed.wrapping_mul(0x9e37_79b9_7f4a_7c15).wrapping_add(k);
        Ok(GenerativeNets {
            expression: Mlp::new(architecture.expression_spec(), s(1))?,
            style: Mlp::new(architecture.style_spec(), s(2))?,
            actuation: Mlp::new(architecture.actuation_spec(), s(3))?,
            jaw: Mlp::new(architecture.jaw_spec(), s(4))?,
            architecture,
            frame,
        })
    }

    /// The networks as a list (fixed order: [`NET_NAMES`]).
    pub fn nets(&self) -> [&Mlp<f64>; 4] {
        [&self.expression, &self.style, &self.actuation, &self.jaw]
    }

    pub fn nets_mut(&mut self) -> [&mut Mlp<f64>; 4] {
        [
            &mut self.expression,
            &mut self.style,
            &mut self.actuation,
            &mut self.jaw,
        ]
    }

    /// Rows of expression codes (B × 19) and style codes (B × 4).
    pub fn inputs(codes: &[Codes]) -> (Mat<f64>, Mat<f64>) {
        (
            Mat::from_fn(codes.len(), ExpressionCode::LEN, |b, k| {
                codes[b].expression.0[k]
            }),
            Mat::from_fn(codes.len(), StyleCode::LEN, |b, k| codes[b].style.0[k]),
        )
    }

    /// The modulation tanh(z) of each code (B × code_dim).
    pub fn modulation(&self, codes: &[Codes]) -> Result<Mat<f64>, GenerativeError> {
        modulation(&self.expression, &self.style, &self.architecture, codes)
    }

    /// The jaw `[θ; t]` for a modulation row.
    pub fn jaw_params(&self, u: &[f64]) -> Result<[f64; 6], GenerativeError> {
        jaw_params(&self.jaw, u)
    }

    /// The networks, their architecture and frame in a checkpoint.
    pub fn to_checkpoint(&self) -> Checkpoint {
        GENERATIVE_FILE.write(self.nets(), &self.architecture, &self.frame)
    }

    /// The networks of a checkpoint written by [`GenerativeNets::to_checkpoint`]; checks the
    /// kind, version and that the networks have the architecture's shapes.
    pub fn from_checkpoint(ck: &Checkpoint) -> Result<Self, GenerativeError> {
        let ([expression, style, actuation, jaw], architecture, frame) =
            GENERATIVE_FILE.read(ck, Architecture::actuation_spec)?;
        Ok(GenerativeNets {
            expression,
            style,
            actuation,
            jaw,
            architecture,
            frame,
        })
    }
}

/// A value as hex of its postcard encoding: bit-exact for floats (JSON numbers may not
/// round-trip an f64 exactly, and the canonical frame and optimizer state must, for resumed
/// runs to be bitwise the uninterrupted ones).
pub(crate) fn to_hex<T: Serialize>(value: &T) -> String {
    postcard::to_allocvec(value)
        .expect("serializable")
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// The inverse of [`to_hex`].
pub(crate) fn from_hex<T: serde::de::DeserializeOwned>(hex: &str) -> Result<T, String> {
    if !hex.len().is_multiple_of(2) || !hex.is_ascii() {
        return Err("odd or non-ASCII hex".into());
    }
    let bytes = (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).map_err(|e| e.to_string()))
        .collect::<Result<Vec<u8>, String>>()?;
    postcard::from_bytes(&bytes).map_err(|e| e.to_string())
}

/// The modulation tanh(z) of each code (B × code_dim): the two encoders' outputs side by side
/// (shared by the physics networks and the displacement baseline).
pub(crate) fn modulation(
    expression: &Mlp<f64>,
    style: &Mlp<f64>,
    architecture: &Architecture,
    codes: &[Codes],
) -> Result<Mat<f64>, GenerativeError> {
    let (x, s) = GenerativeNets::inputs(codes);
    let e = expression.eval(x.as_ref(), None)?;
    let s = style.eval(s.as_ref(), None)?;
    let de = architecture.expression_dim;
    Ok(Mat::from_fn(
        codes.len(),
        architecture.code_dim(),
        |b, k| (if k < de { e[(b, k)] } else { s[(b, k - de)] }).tanh(),
    ))
}

/// N_B's jaw `[θ; t]` for a modulation row.
pub(crate) fn jaw_params(jaw: &Mlp<f64>, u: &[f64]) -> Result<[f64; 6], GenerativeError> {
    let m = Mat::from_fn(1, u.len(), |_, k| u[k]);
    let y = jaw.eval(m.as_ref(), None)?;
    Ok([0, 1, 2, 3, 4, 5].map(|k| y[(0, k)]))
}

/// The file form of a code-driven model (two encoders, a field network over canonical
/// positions, N_B): its kind and version under their keys, the architecture and frame as
/// metadata, the four networks by name. The physics networks and the displacement baseline
/// differ only in these constants and the field network's shape.
pub(crate) struct NetFile {
    pub(crate) kind: &'static str,
    /// How errors name the file.
    pub(crate) what: &'static str,
    pub(crate) version_key: &'static str,
    pub(crate) version: u32,
    /// Expression encoder, style encoder, field network, jaw.
    pub(crate) names: [&'static str; 4],
}

const KIND_KEY: &str = "kind";

impl NetFile {
    pub(crate) fn write(
        &self,
        nets: [&Mlp<f64>; 4],
        architecture: &Architecture,
        frame: &CanonicalFrame,
    ) -> Checkpoint {
        let mut ck = Checkpoint::new();
        for (name, net) in self.names.iter().zip(nets) {
            ck.insert_network(name, net);
        }
        let meta = ck.metadata_mut();
        meta.insert(KIND_KEY.into(), self.kind.into());
        meta.insert(self.version_key.into(), self.version.to_string());
        meta.insert(
            "architecture".into(),
            serde_json::to_string(architecture).expect("serializable"),
        );
        meta.insert("frame".into(), to_hex(frame));
        ck
    }

    /// The four networks, architecture and frame of a checkpoint [`NetFile::write`] wrote;
    /// checks the kind, the version and that every network has the architecture's shape
    /// (`field_spec`: the field network's).
    pub(crate) fn read(
        &self,
        ck: &Checkpoint,
        field_spec: fn(&Architecture) -> MlpSpec,
    ) -> Result<([Mlp<f64>; 4], Architecture, CanonicalFrame), GenerativeError> {
        let meta = ck.metadata();
        let bad = |m: String| GenerativeError::Checkpoint(m);
        if meta.get(KIND_KEY).map(String::as_str) != Some(self.kind) {
            return Err(bad(format!(
                "not a {} file (kind {:?})",
                self.what,
                meta.get(KIND_KEY)
            )));
        }
        let version = meta.get(self.version_key).cloned().unwrap_or_default();
        if version != self.version.to_string() {
            return Err(bad(format!(
                "{} version {version}, this build reads {}",
                self.what, self.version
            )));
        }
        let parse = |key: &str| {
            meta.get(key)
                .ok_or_else(|| bad(format!("missing {key}")))
                .map(String::as_str)
        };
        let architecture: Architecture = serde_json::from_str(parse("architecture")?)
            .map_err(|e| bad(format!("architecture: {e}")))?;
        let frame: CanonicalFrame =
            from_hex(parse("frame")?).map_err(|e| bad(format!("frame: {e}")))?;
        let specs = [
            architecture.expression_spec(),
            architecture.style_spec(),
            field_spec(&architecture),
            architecture.jaw_spec(),
        ];
        let mut nets = Vec::with_capacity(4);
        for (name, spec) in self.names.iter().zip(specs) {
            let net: Mlp<f64> = ck.network(name)?;
            if *net.spec() != spec {
                return Err(bad(format!(
                    "network {name} does not match the stored architecture"
                )));
            }
            nets.push(net);
        }
        let nets: [Mlp<f64>; 4] = nets.try_into().expect("four names");
        Ok((nets, architecture, frame))
    }
}
