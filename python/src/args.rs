//! The Python functions' options as `placedb select`'s command line: the
//! Python API turns keyword arguments into the command's flags, and they
//! are parsed here by the command's own parser, so every option exists
//! and is refused with the same words as on the command line.

use crate::errors::Failure;
use clap::{Args, FromArgMatches};
use placedb_host::cli::select::SelectArgs;
use pyo3::prelude::*;

/// The output directory the parser requires; Python writes with
/// `Database.write`, so it is never used.
const NO_OUTPUT: &str = "<not written>";

/// Parses `argv` (a sequence, then flags) as `placedb select`'s arguments.
pub fn select_args(argv: &[String]) -> Result<SelectArgs, Failure> {
    let cmd = SelectArgs::augment_args(
        clap::Command::new("placedb select")
            .no_binary_name(true)
            .disable_help_flag(true),
    );
    let mut all: Vec<String> = argv.to_vec();
    all.extend(["-o".to_string(), NO_OUTPUT.to_string()]);
    let matches = cmd.try_get_matches_from(all).map_err(clap_words)?;
    SelectArgs::from_arg_matches(&matches).map_err(clap_words)
}

/// A clap error as one line: "invalid value '1.5' for '--mu <MU>': mu must
/// be from 0 to below 1 ...", without clap's "error: " and usage.
fn clap_words(e: clap::Error) -> Failure {
    let text = e.render().to_string();
    let first = text
        .lines()
        .next()
        .unwrap_or_default()
        .trim_start_matches("error: ")
        .to_string();
    Failure::value(first)
}

/// Checks `argv` as `placedb select` would, raising `ValueError` on a
/// refused option (`Selector` checks its options so).
#[pyfunction]
pub fn check_select(argv: Vec<String>) -> PyResult<()> {
    select_args(&argv)?.check().map_err(Failure::from)?;
    Ok(())
}
