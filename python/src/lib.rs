//! The Python package `stillpoint` (distribution `stillpoint-slam`): its compiled part,
//! `stillpoint._stillpoint`. Frames come in as numpy arrays and leave as [`stillpoint::Pipeline`]
//! frames; results go back as numpy arrays. The pure-Python part (`python/stillpoint/`) adds the
//! evaluation helpers' documentation and the batch runner.
//!
//! Errors: a wrong argument is a `ValueError` naming it; a file that cannot be read an
//! `OSError`-like `stillpoint.Error` naming the file; a failure inside the system a
//! `stillpoint.Error`. A panic inside Rust becomes a Python exception, never a crash.

use pyo3::create_exception;
use pyo3::prelude::*;

mod arrays;
mod slam;
mod source;
mod tools;
mod wait;

create_exception!(
    _stillpoint,
    Error,
    pyo3::exceptions::PyRuntimeError,
    "A failure inside stillpoint: a file that cannot be read, settings that do not parse, a map \
     made with another camera, a run that stopped."
);

/// `stillpoint.Error` with the whole chain of causes of `e` as its message.
pub(crate) fn error(e: &dyn std::error::Error) -> PyErr {
    Error::new_err(stillpoint::run::error_chain(e))
}

/// Log lines of the Rust side go to stderr, at the level `STILLPOINT_LOG` names (`error`, `warn`
/// (the default), `info`, `debug`).
fn init_logging() {
    let level = match std::env::var("STILLPOINT_LOG").as_deref() {
        Ok("error") => tracing::Level::ERROR,
        Ok("info") => tracing::Level::INFO,
        Ok("debug") => tracing::Level::DEBUG,
        Ok("trace") => tracing::Level::TRACE,
        _ => tracing::Level::WARN,
    };
    // A second import in the same process (or another extension's subscriber) keeps the first.
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_target(false)
        .with_max_level(level)
        .try_init();
}

#[pymodule]
fn _stillpoint(m: &Bound<'_, PyModule>) -> PyResult<()> {
    init_logging();
    m.add("Error", m.py().get_type::<Error>())?;
    m.add_class::<slam::Camera>()?;
    m.add_class::<slam::Slam>()?;
    m.add_class::<slam::Frame>()?;
    m.add_class::<slam::Run>()?;
    m.add_class::<source::Source>()?;
    m.add_class::<source::SourceFrame>()?;
    m.add_function(wrap_pyfunction!(source::open, m)?)?;
    m.add_function(wrap_pyfunction!(tools::synth, m)?)?;
    m.add_function(wrap_pyfunction!(tools::ate, m)?)?;
    m.add_function(wrap_pyfunction!(tools::rpe, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
