//! `--vpr-eval DIR`: the layout of gmberton's VPR-methods-evaluation,
//! which reads a place's coordinates from its file name:
//!
//! ```text
//! DIR/database/@EAST@NORTH@NNNNNN@.jpg   the database frames
//! DIR/queries/@EAST@NORTH@NNNNNN@.jpg    the --test sequence's frames, or else the non-database frames
//! ```
//!
//! `EAST` and `NORTH` are the two horizontal world axes in metres, the
//! axes the top view draws (right and up, [`crate::output::annotate::east_north`]),
//! standing for UTM easting and northing; `NNNNNN` is the frame's index in
//! its sequence (it keeps names unique). The tool splits a path at `@` and
//! reads fields 1 and 2, so `DIR` itself must hold no `@`.

use super::{east_north_of, Selection};
use crate::error::OutputError;
use crate::sequence::Sequence;
use rayon::prelude::*;
use std::path::Path;

/// Whether `dir` holds a VPR-evaluation export (so that it may be replaced).
pub fn is_export(dir: &Path) -> bool {
    dir.join("database").is_dir() && dir.join("queries").is_dir()
}

/// The file name of the frame numbered `n` in its sequence
/// ([`crate::sequence::FrameInfo::index`]) at plane coordinates `[east,
/// north]`.
pub fn name(n: usize, [east, north]: [f64; 2]) -> String {
    format!("@{east:.4}@{north:.4}@{n:06}@.jpg")
}

/// `(east, north)` and the frame index of a name written by [`name`].
pub fn parse(name: &str) -> Option<([f64; 2], usize)> {
    let mut f = name.split('@');
    f.next()?;
    let east = f.next()?.parse().ok()?;
    let north = f.next()?.parse().ok()?;
    let index = f.next()?.parse().ok()?;
    Some(([east, north], index))
}

/// What was written: database images and query images.
pub fn write(dir: &Path, sel: &Selection) -> Result<(usize, usize), OutputError> {
    if dir.to_string_lossy().contains('@') {
        return Err(OutputError::Mismatch(format!(
            "{}: VPR-methods-evaluation reads coordinates between '@'s, so the directory's path must hold none",
            dir.display()
        )));
    }
    let database = dir.join("database");
    let queries = dir.join("queries");
    for d in [&database, &queries] {
        std::fs::create_dir_all(d).map_err(OutputError::writing(d))?;
    }
    let proj = sel.projection();
    // Database frames at the poses of database.csv.
    let db: Vec<(usize, [f64; 2])> = sel
        .database_rows()
        .iter()
        .map(|&(i, _, p)| (i, east_north_of(&proj, [p[0], p[1], p[2]])))
        .collect();
    let (query_seq, query): (&Sequence, Vec<usize>) = match sel.test {
        Some(t) => (t, (0..t.frames.len()).collect()),
        None => (sel.seq, sel.non_database()),
    };
    let jobs: Vec<(&Sequence, usize, [f64; 2], &Path)> = db
        .iter()
        .map(|&(i, en)| (sel.seq, i, en, database.as_path()))
        .chain(query.iter().map(|&i| {
            let en = east_north_of(&proj, query_seq.frames[i].translation);
            (query_seq, i, en, queries.as_path())
        }))
        .collect();
    jobs.par_iter()
        .try_for_each(|&(seq, i, en, d)| -> Result<(), OutputError> {
            let bytes = super::image::frame_jpeg(seq, i)?;
            let path = d.join(name(seq.frames[i].index, en));
            std::fs::write(&path, bytes).map_err(OutputError::writing(&path))
        })?;
    let sources = super::sources_csv(jobs.iter().map(|&(seq, i, en, d)| {
        let folder = if d == database.as_path() {
            "database"
        } else {
            "queries"
        };
        (
            format!("{folder}/{}", name(seq.frames[i].index, en)),
            seq,
            i,
        )
    }));
    let path = dir.join(super::SOURCES);
    std::fs::write(&path, sources).map_err(OutputError::writing(&path))?;
    Ok((db.len(), query.len()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_back() {
        let n = name(42, [-1.23456, 7.0]);
        assert_eq!(n, "@-1.2346@7.0000@000042@.jpg");
        let (en, i) = parse(&n).unwrap();
        assert_eq!(i, 42);
        assert!((en[0] + 1.2346).abs() < 1e-12 && (en[1] - 7.0).abs() < 1e-12);
        assert!(parse("db1.jpg").is_none());
    }
}
