//! The shared secret a remote client must present before the session answers it.
//!
//! A generated token is 128 random bits from the operating system's generator, written as 32
//! hex digits. A presented token is compared in constant time, so the time a refusal takes
//! says nothing about how much of a guess was right.

use rand::RngCore;
use subtle::ConstantTimeEq;

/// Shortest token accepted from the user: 16 characters (a typed password shorter than this
/// is guessable over a network).
pub const MIN_TOKEN_LEN: usize = 16;

/// The environment variable a token may be given in instead of `--token` (keeps it out of the
/// process list and the shell history).
pub const TOKEN_ENV: &str = "FACESIM_TOKEN";

#[derive(Clone, PartialEq, Eq)]
pub struct Token(String);

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum TokenError {
    #[error("a token needs at least {MIN_TOKEN_LEN} characters, this one has {0}")]
    TooShort(usize),
    #[error("a token is printable ASCII without spaces (it travels in JSON and on command lines)")]
    BadCharacter,
}

impl Token {
    /// A fresh random token.
    pub fn generate() -> Self {
        let mut bytes = [0u8; 16];
        rand::rng().fill_bytes(&mut bytes);
        Token(bytes.iter().map(|b| format!("{b:02x}")).collect())
    }

    /// A token the user chose.
    pub fn new(text: &str) -> Result<Self, TokenError> {
        if !text.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(TokenError::BadCharacter);
        }
        if text.len() < MIN_TOKEN_LEN {
            return Err(TokenError::TooShort(text.len()));
        }
        Ok(Token(text.to_string()))
    }

    /// Whether `presented` is this token, in time independent of where they differ.
    pub fn accepts(&self, presented: &str) -> bool {
        // `ct_eq` on slices of different lengths is false at once; the length of a token is
        // not the secret.
        bool::from(self.0.as_bytes().ct_eq(presented.as_bytes()))
    }

    /// The token's text, to print for the user or send to a server.
    pub fn reveal(&self) -> &str {
        &self.0
    }
}

/// Never printed by accident (logs, panics).
impl std::fmt::Debug for Token {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Token(…)")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generated_tokens_are_long_distinct_and_accept_only_themselves() {
        let (a, b) = (Token::generate(), Token::generate());
        assert_eq!(a.reveal().len(), 32);
        assert_ne!(a, b);
        assert!(a.accepts(a.reveal()));
        assert!(!a.accepts(b.reveal()));
        assert!(!a.accepts(""));
        assert!(!a.accepts(&a.reveal()[..31]));
        assert!(!a.accepts(&format!("{}0", a.reveal())));
        assert_eq!(format!("{a:?}"), "Token(…)");
    }

    #[test]
    fn chosen_tokens_must_be_long_and_printable() {
        assert_eq!(Token::new("short"), Err(TokenError::TooShort(5)));
        assert_eq!(
            Token::new("with a space in it!"),
            Err(TokenError::BadCharacter)
        );
        assert!(
            Token::new("correct-horse-battery")
                .unwrap()
                .accepts("correct-horse-battery")
        );
    }
}
