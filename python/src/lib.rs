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
    m.add_function(wrap_pyfunction!(mdagl::_restore_mdagl, m)?)?;
    m.add_class::<structure::Structure>()?;
    m.add_class::<agents::Agent>()?;
    m.add_function(wrap_pyfunction!(agents::_restore_agent, m)?)?;
    m.add_class::<worlds::GridWorld>()?;
    m.add_class::<worlds::ArenaWorld>()?;
    m.add_function(wrap_pyfunction!(worlds::_restore_grid_world, m)?)?;
    m.add_function(wrap_pyfunction!(worlds::_restore_arena_world, m)?)?;
    m.add(
        "LibraryFileError",
        m.py().get_type::<agents::LibraryFileError>(),
    )?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
