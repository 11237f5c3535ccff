//! All or nothing: an export is written into a temporary directory (or
//! file) beside its target and renamed into place only when complete, so a
//! failed run leaves what was there before.

use crate::output::dataset::DatasetError;
use std::path::{Path, PathBuf};

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Write {
        path: path.to_path_buf(),
        source,
    }
}

/// `target`'s folder and a hidden sibling name `.NAME.WHAT-PID`.
fn sibling(target: &Path, what: &str) -> Result<(PathBuf, PathBuf), DatasetError> {
    let name = target
        .file_name()
        .and_then(|n| n.to_str())
        .filter(|n| !n.is_empty() && *n != "..")
        .ok_or_else(|| {
            DatasetError::Mismatch(format!(
                "{}: not a name for an export (give a file or directory name)",
                target.display()
            ))
        })?;
    let parent = match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let other = parent.join(format!(".{name}.{what}-{}", std::process::id()));
    Ok((parent, other))
}

/// Whether [`replace_dir`] may write `target`: a new name, an empty
/// directory, or one that `is_ours` says holds an earlier export of the
/// same kind. Also called before a command's work, so that a refused
/// target fails the run before anything is written.
pub fn check_dir(
    target: &Path,
    kind: &str,
    is_ours: impl Fn(&Path) -> bool,
) -> Result<(), DatasetError> {
    sibling(target, "partial")?;
    if target.exists() {
        if !target.is_dir() {
            return Err(DatasetError::Mismatch(format!(
                "{} exists and is not a directory: give a directory for {kind}",
                target.display()
            )));
        }
        let empty = std::fs::read_dir(target)
            .map_err(io_err(target))?
            .next()
            .is_none();
        if !empty && !is_ours(target) {
            return Err(DatasetError::Mismatch(format!(
                "{} exists and is not {kind}: give a new or empty directory",
                target.display()
            )));
        }
    }
    Ok(())
}

/// Whether [`replace_file`] may write `target` (not a directory, a name).
pub fn check_file(target: &Path) -> Result<(), DatasetError> {
    if target.is_dir() {
        return Err(DatasetError::Mismatch(format!(
            "{} is a directory: give a file name",
            target.display()
        )));
    }
    sibling(target, "partial").map(|_| ())
}

/// Writes directory `target` whole: `fill` writes into an empty temporary
/// directory beside it, which then replaces `target`. An existing `target`
/// is replaced only when it is empty or `is_ours` says it holds an earlier
/// export of the same kind (a mistyped path never replaces other files);
/// `kind` names the export in that refusal.
pub fn replace_dir<T>(
    target: &Path,
    kind: &str,
    is_ours: impl Fn(&Path) -> bool,
    fill: impl FnOnce(&Path) -> Result<T, DatasetError>,
) -> Result<T, DatasetError> {
    check_dir(target, kind, &is_ours)?;
    let (parent, partial) = sibling(target, "partial")?;
    std::fs::create_dir_all(&parent).map_err(io_err(&parent))?;
    let _ = std::fs::remove_dir_all(&partial);
    std::fs::create_dir(&partial).map_err(io_err(&partial))?;
    let filled = fill(&partial).and_then(|v| {
        if target.exists() {
            let (_, old) = sibling(target, "old")?;
            let _ = std::fs::remove_dir_all(&old);
            std::fs::rename(target, &old).map_err(io_err(target))?;
            if let Err(e) = std::fs::rename(&partial, target) {
                let _ = std::fs::rename(&old, target);
                return Err(io_err(target)(e));
            }
            let _ = std::fs::remove_dir_all(&old);
        } else {
            std::fs::rename(&partial, target).map_err(io_err(target))?;
        }
        Ok(v)
    });
    if filled.is_err() {
        let _ = std::fs::remove_dir_all(&partial);
    }
    filled
}

/// Writes file `target` whole: `text` into a temporary file beside it,
/// renamed over it.
pub fn replace_file(target: &Path, text: &str) -> Result<(), DatasetError> {
    check_file(target)?;
    let (parent, partial) = sibling(target, "partial")?;
    std::fs::create_dir_all(&parent).map_err(io_err(&parent))?;
    let written = std::fs::write(&partial, text)
        .and_then(|()| std::fs::rename(&partial, target))
        .map_err(io_err(target));
    if written.is_err() {
        let _ = std::fs::remove_file(&partial);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("placedb-replace-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_failed_fill_leaves_what_was_there() {
        let root = temp("fail");
        let target = root.join("out");
        let ours = |d: &Path| d.join("mark").exists();
        replace_dir(&target, "an export", ours, |d| {
            std::fs::write(d.join("mark"), "1").map_err(io_err(d))
        })
        .unwrap();
        let failed = replace_dir(&target, "an export", ours, |d| {
            std::fs::write(d.join("mark"), "2").map_err(io_err(d))?;
            Err::<(), _>(DatasetError::Mismatch("broken".into()))
        });
        assert!(failed.is_err());
        assert_eq!(std::fs::read_to_string(target.join("mark")).unwrap(), "1");
        // Nothing left beside it.
        let names: Vec<_> = std::fs::read_dir(&root).unwrap().collect();
        assert_eq!(names.len(), 1);
        replace_dir(&target, "an export", ours, |d| {
            std::fs::write(d.join("mark"), "3").map_err(io_err(d))
        })
        .unwrap();
        assert_eq!(std::fs::read_to_string(target.join("mark")).unwrap(), "3");
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn a_directory_of_other_files_is_not_replaced() {
        let root = temp("other");
        std::fs::write(root.join("precious.txt"), "keep").unwrap();
        let r = replace_dir(&root, "a COLMAP export", |_| false, |_| Ok(()));
        let msg = r.unwrap_err().to_string();
        assert!(msg.contains("is not a COLMAP export"), "{msg}");
        assert!(root.join("precious.txt").exists());
        let file = root.join("pairs.txt");
        replace_file(&file, "a b\n").unwrap();
        replace_file(&file, "c d\n").unwrap();
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "c d\n");
        assert!(replace_file(&root, "x").is_err());
        std::fs::remove_dir_all(&root).ok();
    }
}
