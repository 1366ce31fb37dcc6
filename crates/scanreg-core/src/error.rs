//! One error type for the whole core; the binding maps it to `ValueError`.

/// What went wrong, always naming the offending argument.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// An argument is malformed: wrong length, non-finite values, too few points.
    #[error("{arg}: {msg}")]
    InvalidInput { arg: &'static str, msg: String },
}

impl Error {
    pub fn invalid(arg: &'static str, msg: impl Into<String>) -> Self {
        Error::InvalidInput {
            arg,
            msg: msg.into(),
        }
    }
}

pub type Result<T> = std::result::Result<T, Error>;
