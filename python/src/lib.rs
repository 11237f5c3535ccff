//! `placedb._native`: the Rust half of the Python package. It calls the
//! host crate's own code (the command line's parsers, reader, solvers,
//! writers and device client), so Python and `placedb` give the same
//! results in the same words; `python/placedb/` is the Python API over it
//! (keyword arguments, docstrings, types).

use pyo3::prelude::*;

mod args;
mod database;
mod device;
mod errors;
mod sequence;

/// The native module; `placedb` re-exports what users call.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<sequence::Sequence>()?;
    m.add_class::<database::Database>()?;
    m.add_class::<device::Device>()?;
    m.add_function(wrap_pyfunction!(sequence::read_sequence, m)?)?;
    m.add_function(wrap_pyfunction!(sequence::sequence_from_arrays, m)?)?;
    m.add_function(wrap_pyfunction!(database::select, m)?)?;
    m.add_function(wrap_pyfunction!(args::check_select, m)?)?;
    // The online solver's default margin, so `Selector` decides as
    // `select(solver="online")` does.
    m.add(
        "SKETCH_MARGIN",
        placedb_host::pipeline::SolverParams::default().sketch_margin,
    )?;
    Ok(())
}
