//! `--pairs FILE`: hloc's retrieval pairs, `QUERY DATABASE` a line: every
//! non-database frame with each database frame it overlaps above mu (IoU of
//! the voxel sets the solver saw), best first; ties in frame order.
//!
//! A frame is named by the image the user already has, so that hloc's
//! `image_dir` is the sequence directory: its colour file's path relative
//! to the sequence's root ([`names`]). A sequence without colour files (a
//! ROS 2 bag, a depth-only layout) keeps the frame-index names of the
//! COLMAP export ([`super::image_name`]), which the caller says on stderr.

use super::{image_name, Selection};
use crate::error::OutputError;
use crate::sequence::Sequence;
use std::fmt::Write as _;
use std::path::{Component, Path};

/// Whether `path` holds an earlier pairs file, which `--pairs` may replace:
/// UTF-8 text whose every line is two names (hloc's pairs format). Any
/// other file is the user's, and is refused.
pub fn is_pairs(path: &Path) -> bool {
    std::fs::read_to_string(path)
        .is_ok_and(|text| text.lines().all(|l| l.split_whitespace().count() == 2))
}

/// What the pairs call the frames' images.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Names {
    /// Every frame's colour file, relative to the sequence's root with `/`
    /// separators, by frame index.
    Colour(Vec<String>),
    /// [`image_name`]s (`NNNNNN.jpg`): the number of the first frame
    /// without a colour file when others have one, `None` when none has (a
    /// ROS 2 bag, a depth-only layout, the built-in renderer).
    Index(Option<usize>),
}

/// The names of `seq`'s frames in pairs file `file` (named in a refusal):
/// colour files only when every frame has one, as the dataset's `color/`
/// (a pair naming a missing image would fail in hloc all the same). A
/// name hloc's parser cannot read back is refused.
pub fn names(seq: &Sequence, file: &Path) -> Result<Names, OutputError> {
    let Some(root) = &seq.root else {
        return Ok(Names::Index(None));
    };
    let mut names = Vec::with_capacity(seq.frames.len());
    for frame in &seq.frames {
        let Some(colour) = &frame.color_path else {
            let some = seq.frames.iter().any(|f| f.color_path.is_some());
            return Ok(Names::Index(some.then_some(frame.index)));
        };
        names.push(colour_name(root, colour).map_err(|why| {
            OutputError::Mismatch(format!(
                "--pairs {}: frame {}'s colour image {} {why}; hloc's pairs name an image \
                 relative to its image_dir (here {}) and split each line at whitespace into \
                 exactly two names. Rename the colour files, or leave out --pairs",
                file.display(),
                frame.index,
                colour.display(),
                root.display()
            ))
        })?);
    }
    if names.is_empty() {
        return Ok(Names::Index(None));
    }
    Ok(Names::Colour(names))
}

/// `colour`'s path relative to `root` with `/` separators; why not, when
/// it has none hloc can read.
fn colour_name(root: &Path, colour: &Path) -> Result<String, &'static str> {
    // The readers join the root with the path as the layout wrote it, so
    // stripping the root lexically (no canonicalising) gives that path
    // back: `../x.png` of a TUM rgb.txt stays `../x.png`, which hloc's
    // `image_dir / name` opens as the reader did.
    let rel = colour
        .strip_prefix(root)
        .map_err(|_| "is not under the sequence directory (an absolute path in its list)")?;
    let mut parts = Vec::new();
    for c in rel.components() {
        match c {
            Component::Normal(s) => parts.push(s.to_str().ok_or("is not UTF-8 text")?),
            Component::ParentDir => parts.push(".."),
            Component::CurDir => {}
            Component::RootDir | Component::Prefix(_) => {
                return Err("is not under the sequence directory (an absolute path in its list)")
            }
        }
    }
    let name = parts.join("/");
    if name.is_empty() {
        return Err("is the sequence directory itself");
    }
    // Python's str.split() also splits at the information separators
    // U+001C to U+001F, which Rust does not count as whitespace.
    if name
        .chars()
        .any(|c| c.is_whitespace() || ('\u{1c}'..='\u{1f}').contains(&c))
    {
        return Err("has whitespace or a line break in its name");
    }
    Ok(name)
}

/// The text of the pairs file, its frames named by `names`.
pub fn text(sel: &Selection, names: &Names) -> Result<String, OutputError> {
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
    let name = |i: usize| match names {
        Names::Colour(n) => n[i].clone(),
        Names::Index(_) => image_name(sel.seq.frames[i].index),
    };
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
            let _ = writeln!(s, "{} {}", name(q), name(d));
        }
    }
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::colour_name;
    use std::path::Path;

    #[test]
    fn colour_names_are_relative_to_the_root_as_the_layout_wrote_them() {
        let root = Path::new("data/seq");
        let name = |p: &str| colour_name(root, &root.join(p));
        assert_eq!(name("rgb/1.png").unwrap(), "rgb/1.png");
        assert_eq!(name("./rgb/1.png").unwrap(), "rgb/1.png");
        assert_eq!(name("../other/1.png").unwrap(), "../other/1.png");
        assert_eq!(
            colour_name(Path::new("."), Path::new("./frame-000001.color.jpg")).unwrap(),
            "frame-000001.color.jpg"
        );
        assert!(name("/elsewhere/1.png").is_err());
        for bad in [
            "color/a b.png",
            "color/a\tb.png",
            "a\nb.png",
            "a\u{1f}b.png",
            "a\u{a0}b",
        ] {
            assert!(name(bad).is_err(), "{bad:?}");
        }
    }
}
