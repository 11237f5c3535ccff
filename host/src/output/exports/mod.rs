//! Exports for the next tools in a pipeline (docs/exports.md): a COLMAP
//! model of the database frames ([`colmap`]), the layout of
//! VPR-methods-evaluation ([`vpr_eval`]) and hloc's retrieval pairs
//! ([`pairs`]). `placedb select` writes them from its selection and
//! `placedb export --sequence SEQ` from a device's labels, both through
//! [`write_all`]. Each export is all or nothing, with the run's other
//! outputs ([`crate::output::replace`]).

pub mod colmap;
pub mod image;
pub mod pairs;
pub mod vpr_eval;

use crate::error::OutputError;
use crate::output::replace::{self, Outputs};
use crate::output::topview::Projection;
use crate::output::DbRow;
use crate::sequence::Sequence;
use crate::yardstick::graph::CoObservation;
use std::path::{Path, PathBuf};

/// Where the exports go (`select` and `export`'s `--colmap`, `--vpr-eval`
/// and `--pairs`): each `None` is not written.
#[derive(Debug, Clone, Default)]
pub struct ExportTargets {
    /// The database frames as a COLMAP text model:
    /// sparse/0/{cameras,images,points3D}.txt and images/ (docs/exports.md).
    pub colmap: Option<PathBuf>,
    /// VPR-methods-evaluation's layout: database/ and queries/ named
    /// @east@north@index@.jpg (docs/exports.md).
    pub vpr_eval: Option<PathBuf>,
    /// hloc's retrieval pairs: each non-database frame with the database
    /// frames it overlaps above mu, best first.
    pub pairs: Option<PathBuf>,
}

impl ExportTargets {
    /// Whether any export was asked for.
    pub fn any(&self) -> bool {
        self.colmap.is_some() || self.vpr_eval.is_some() || self.pairs.is_some()
    }

    /// The paths asked for.
    pub fn targets(&self) -> Vec<&Path> {
        [&self.colmap, &self.vpr_eval, &self.pairs]
            .into_iter()
            .flatten()
            .map(PathBuf::as_path)
            .collect()
    }

    /// Refuses, before any work, a target [`write_all`] would refuse.
    pub fn check_targets(&self) -> Result<(), OutputError> {
        if let Some(dir) = &self.colmap {
            replace::check_dir(dir, COLMAP, colmap::is_export)?;
        }
        if let Some(dir) = &self.vpr_eval {
            replace::check_dir(dir, VPR_EVAL, vpr_eval::is_export)?;
        }
        if let Some(file) = &self.pairs {
            replace::check_file_of(file, PAIRS, pairs::is_pairs)?;
        }
        Ok(())
    }
}

/// The exports' names in a refusal.
const COLMAP: &str = "a COLMAP export";
const VPR_EVAL: &str = "a VPR-evaluation export";
const PAIRS: &str = "a pairs file (lines of two image names)";

/// A selection as the exports see it.
pub struct Selection<'a> {
    /// The sequence selected from.
    pub seq: &'a Sequence,
    /// The rows of `database.csv`: the poses the exports write.
    pub rows: &'a [DbRow],
    /// The class of every labelled frame from 0 (a device may have
    /// labelled fewer frames than the sequence holds).
    pub labels: &'a [usize],
    /// The frames' overlaps (for `--pairs`).
    pub overlaps: Option<&'a CoObservation>,
    /// The IoU threshold (for `--pairs`).
    pub mu: f32,
    /// The test sequence, whose frames are the VPR-evaluation queries.
    pub test: Option<&'a Sequence>,
}

impl Selection<'_> {
    /// The database rows in frame order.
    pub fn database_rows(&self) -> Vec<DbRow> {
        let mut rows = self.rows.to_vec();
        rows.sort_by_key(|r| r.0);
        rows
    }

    /// The labelled frames that are no database frame, ascending.
    pub fn non_database(&self) -> Vec<usize> {
        (0..self.labels.len())
            .filter(|&i| self.labels[i] != i)
            .collect()
    }

    /// The top view's projection of the sequence.
    pub fn projection(&self) -> Projection {
        crate::output::topview::horizontal(&self.seq.frames)
    }

    /// Database rows, labels and sequence agree.
    fn check(&self) -> Result<(), OutputError> {
        let n = self.seq.frames.len();
        if self.labels.len() > n {
            return Err(OutputError::Mismatch(format!(
                "{} labels for a sequence of {n} frames",
                self.labels.len()
            )));
        }
        for &(i, _, _) in self.rows {
            if i >= self.labels.len() || self.labels[i] != i {
                return Err(OutputError::Mismatch(format!(
                    "database frame {i} is not labelled as its own class in the {} labelled frames",
                    self.labels.len()
                )));
            }
            if self.overlaps.is_some_and(|co| i >= co.len()) {
                return Err(OutputError::Mismatch(format!(
                    "database frame {i} has no overlaps computed"
                )));
            }
        }
        Ok(())
    }
}

/// The name of the image of the frame numbered `n` in its sequence (its
/// [`FrameInfo::index`](crate::sequence::FrameInfo::index), which is its
/// position unless the sequence was cut to the frames a device received)
/// in the COLMAP export, and in the pairs of a sequence without colour
/// files ([`pairs::names`]).
pub fn image_name(n: usize) -> String {
    format!("{n:06}.jpg")
}

/// The name of [`SOURCES`]: which sequence file each exported image is.
pub const SOURCES: &str = "sources.csv";

/// `sources.csv` of an export whose images have names of its own
/// (`images/000042.jpg`, `database/@e@n@42@.jpg`): a row per image
/// (`image`, its path in the export; `i`, the frame's position in `seq`),
/// with the frame's index in its sequence ([`crate::sequence::FrameInfo::index`]) and
/// timestamp and its `source`: the colour image file it came from, relative
/// to the sequence's directory as its layout names it; else (a bag's colour
/// topic, or a rendering of the depth) the frame's depth image name, as
/// `depth:` and the layout's name (a bag's `topic@stamp`). Fields holding a
/// comma or a quote are quoted.
pub fn sources_csv<'a>(images: impl IntoIterator<Item = (String, &'a Sequence, usize)>) -> String {
    let quoted = |s: &str| {
        if s.contains([',', '"', '\n', '\r']) {
            format!("\"{}\"", s.replace('"', "\"\""))
        } else {
            s.to_string()
        }
    };
    let mut csv = String::from("image,frame,timestamp,source\n");
    for (image, seq, i) in images {
        let Some(f) = seq.frames.get(i) else { continue };
        let source = match (&f.color_path, &seq.root) {
            (Some(colour), Some(root)) => colour
                .strip_prefix(root)
                .map(|rel| rel.to_string_lossy().replace('\\', "/"))
                .unwrap_or_else(|_| colour.display().to_string()),
            (Some(colour), None) => colour.display().to_string(),
            (None, _) => format!("depth:{}", f.depth_name),
        };
        csv.push_str(&format!(
            "{},{},{:.6},{}\n",
            quoted(&image),
            f.index,
            f.timestamp,
            quoted(&source)
        ));
    }
    csv
}

/// `[east, north]` of world point `p`: the top view's right and up.
pub fn east_north_of(proj: &Projection, p: [f64; 3]) -> [f64; 2] {
    let ((e, es), (n, ns)) = crate::output::annotate::east_north(proj);
    [es * p[e], ns * p[n]]
}

/// Writes every export `flags` asks for into `outputs` (renamed into place
/// with the run's other outputs); returns a line about each.
pub fn write_all(
    flags: &ExportTargets,
    sel: &Selection,
    outputs: &mut Outputs,
) -> Result<Vec<String>, OutputError> {
    let mut said = Vec::new();
    if !flags.any() {
        return Ok(said);
    }
    sel.check()?;
    // Names the pairs cannot hold refuse the run before any export is made.
    let names = match &flags.pairs {
        Some(file) => Some(pairs::names(sel.seq, file)?),
        None => None,
    };
    if let Some(dir) = &flags.colmap {
        let d = outputs.dir(dir, COLMAP, colmap::is_export)?;
        let n = colmap::write(&d, sel)?;
        said.push(format!(
            "  colmap: {n} images with their poses in {}/{{sparse/0,images}}",
            dir.display()
        ));
    }
    if let Some(dir) = &flags.vpr_eval {
        let d = outputs.dir(dir, VPR_EVAL, vpr_eval::is_export)?;
        let (db, q) = vpr_eval::write(&d, sel)?;
        said.push(format!(
            "  vpr-eval: {db} database and {q} query images in {}/{{database,queries}}",
            dir.display()
        ));
    }
    if let (Some(file), Some(names)) = (&flags.pairs, &names) {
        let text = pairs::text(sel, names)?;
        replace::write_text(&outputs.file(file, PAIRS, pairs::is_pairs)?, &text)?;
        said.push(format!(
            "  pairs: {} query-database pairs above mu {} in {}",
            text.lines().count(),
            sel.mu,
            file.display()
        ));
        if let pairs::Names::Index(first) = names {
            // These names are no file of the user's: say so where a script
            // reading stdout does not trip over it.
            let why = match first {
                Some(n) => format!("frame {n} of the sequence has no colour image file"),
                None => "the sequence has no colour image files".into(),
            };
            crate::warning::warn(format!(
                "--pairs {}: {why}, so the pairs name frames by index, NNNNNN.jpg; \
                 give hloc an image directory holding the frames under those names",
                file.display()
            ));
        }
    }
    Ok(said)
}
