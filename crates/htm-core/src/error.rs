//! One error type for the whole core; the Python layer maps each variant to an `HtmError` subclass.
use std::fmt;

#[derive(Debug, Clone, PartialEq)]
pub enum Error {
    /// A parameter is outside its physical range.
    Parameter { field: String, value: f64, allowed: String },
    /// An input signal or argument is unusable (NaN command, wrong length, ...).
    Input(String),
    /// The integrator could not meet its tolerance (step size underflow, non-finite state).
    Solver(String),
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Error::Parameter { field, value, allowed } => {
                write!(f, "parameter `{field}` = {value} is out of range: allowed {allowed}")
            }
            Error::Input(msg) => write!(f, "bad input: {msg}"),
            Error::Solver(msg) => write!(f, "solver failure: {msg}"),
        }
    }
}

impl std::error::Error for Error {}

pub type Result<T> = std::result::Result<T, Error>;
