//! The native half of the `tes` Python package (`tes._tes`). Every class here wraps a type of
//! the workspace's crates; the Python side (`python/tes/`) adds NumPy and SciPy conversions
//! and scikit-learn's names. Errors cross the boundary as Python exceptions carrying the Rust
//! message; nothing here panics on input.

mod agents;
mod mdagl;
mod structure;
mod worlds;

use pyo3::prelude::*;

/// The `tes._tes` extension module.
#[pymodule]
fn _tes(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<mdagl::Mdagl>()?;
    m.add_class::<structure::Structure>()?;
    m.add_class::<agents::Agent>()?;
    m.add_class::<worlds::GridWorld>()?;
    m.add_class::<worlds::ArenaWorld>()?;
    m.add(
        "LibraryFileError",
        m.py().get_type::<agents::LibraryFileError>(),
    )?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
