//! `--pairs FILE`: hloc's retrieval pairs, `QUERY DATABASE` a line (the
//! names of the COLMAP export's images, [`super::image_name`]): every
//! non-database frame with each database frame it overlaps above mu (IoU of
//! the voxel sets the solver saw), best first; ties in frame order.

use super::{image_name, Selection};
use crate::error::OutputError;
use std::fmt::Write as _;
use std::path::Path;

/// Whether `path` holds an earlier pairs file, which `--pairs` may replace:
/// UTF-8 text whose every line is two names (hloc's pairs format). Any
/// other file is the user's, and is refused.
pub fn is_pairs(path: &Path) -> bool {
    std::fs::read_to_string(path)
        .is_ok_and(|text| text.lines().all(|l| l.split_whitespace().count() == 2))
}

/// The text of the pairs file.
pub fn text(sel: &Selection) -> Result<String, OutputError> {
    let co = sel.overlaps.ok_or_else(|| {
        OutputError::Mismatch("--pairs needs the frames' overlaps, which were not computed".into())
    })?;
    if co.len() < sel.labels.len() {
        return Err(OutputError::Mismatch(format!(
            "overlaps of {} frames for {} labelled frames",
            co.len(),
            sel.labels.len()
        )));
    }
    let database: Vec<usize> = sel.database_rows().iter().map(|r| r.0).collect();
    let mut s = String::new();
    for q in sel.non_database() {
        let mut best: Vec<(f32, usize)> = database
            .iter()
            .map(|&d| (co.iou(q, d), d))
            .filter(|&(iou, _)| iou > sel.mu)
            .collect();
        best.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        for (_, d) in best {
            let _ = writeln!(s, "{} {}", image_name(q), image_name(d));
        }
    }
    Ok(s)
}
