//! What the sliders set: an expression code and a style code, the model's inputs.

use serde::{Deserialize, Serialize};

use super::expression::ExpressionCode;
use super::style::StyleCode;

/// The expression and the style of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Codes {
    pub expression: ExpressionCode,
    pub style: StyleCode,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CodeError {
    #[error("code entry {name} is {value}; codes must be finite")]
    NonFinite { name: &'static str, value: f64 },
}

impl Codes {
    /// Rejects non-finite entries, naming the slider.
    pub fn validate(&self) -> Result<(), CodeError> {
        let named = self
            .expression
            .iter()
            .chain(StyleCode::NAMES.iter().copied().zip(self.style.0));
        for (name, value) in named {
            if !value.is_finite() {
                return Err(CodeError::NonFinite { name, value });
            }
        }
        Ok(())
    }
}
