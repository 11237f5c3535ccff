//! All or nothing, the one rule for every directory and file a command
//! writes (`select -o` and `--dataset`, `export`, `stream -o`, `synth`, the
//! exports): each output is written into a hidden temporary sibling,
//! `.NAME.partial-PID-K`, and the outputs of one run are renamed into place
//! together at its end ([`Outputs::commit`]), so a failed run leaves what was
//! there before and a re-run leaves no stale file.
//!
//! The rule on an existing target: a directory is replaced whole when it is
//! empty or holds an earlier output of the same kind (each kind says how it
//! knows its own); any other directory is refused, so a mistyped path never
//! replaces other files. A file target is replaced unless it is a directory.
//! [`check_dir`] and [`check_file`] apply the rule before a command's work,
//! so that a refused or unwritable target fails the run before anything is
//! computed. A run stopped by SIGINT or SIGTERM removes its partial
//! siblings before it exits ([`interrupt`]); one that a run killed outright
//! left behind is removed by the next run writing that target ([`stale`]).

use crate::interrupt::{self, remove};
pub use crate::interrupt::{
    defer_stop, end_defer, remove_partials_on_signal, stop_now, stop_requested,
};
mod stale;

use crate::error::OutputError;
use crate::error::ReadError;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

fn refused(text: String) -> OutputError {
    OutputError::Mismatch(text)
}

/// Numbers the temporary siblings of one process apart.
static NEXT_SIBLING: AtomicUsize = AtomicUsize::new(0);

/// `target`'s folder and its file name.
fn split(target: &Path) -> Result<(PathBuf, String), OutputError> {
    let name = target
        .file_name()
        .and_then(|n| n.to_str())
        .filter(|n| !n.is_empty() && *n != "..")
        .ok_or_else(|| {
            refused(format!(
                "{}: not a name for an output (give a file or directory name)",
                target.display()
            ))
        })?;
    let parent = match target.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    Ok((parent, name.to_string()))
}

/// A fresh hidden sibling name of `target`, `.NAME.WHAT-PID-K`.
fn sibling(target: &Path, what: &str) -> Result<PathBuf, OutputError> {
    let (parent, name) = split(target)?;
    let k = NEXT_SIBLING.fetch_add(1, Ordering::Relaxed);
    Ok(parent.join(format!(".{name}.{what}-{}-{k}", std::process::id())))
}

/// The folder `target` will be written in can be: its nearest existing
/// ancestor is a directory in which a directory can be made (tried, and
/// removed at once), so that a path under a regular file or in a read-only
/// place fails before the work, naming it.
fn check_parent(target: &Path) -> Result<(), OutputError> {
    let (parent, _) = split(target)?;
    let mut at = parent.as_path();
    while !at.exists() {
        match at.parent() {
            Some(p) if !p.as_os_str().is_empty() => at = p,
            _ => {
                at = Path::new(".");
                break;
            }
        }
    }
    if !at.is_dir() {
        return Err(refused(format!(
            "{} is not a directory: {} cannot be written under it",
            at.display(),
            target.display()
        )));
    }
    let probe = sibling(&at.join("probe"), "probe")?;
    std::fs::create_dir(&probe).map_err(|e| {
        refused(format!(
            "{}: cannot write there ({e}), so not {} either",
            at.display(),
            target.display()
        ))
    })?;
    let _ = std::fs::remove_dir(&probe);
    Ok(())
}

/// Whether directory `target` may be written as output `kind` (in words,
/// e.g. "a database directory"): a new name, an empty directory, or one that
/// `is_ours` says holds an earlier output of that kind; and its folder can be
/// written. Called before a command's work and again when it writes.
pub fn check_dir(
    target: &Path,
    kind: &str,
    is_ours: impl Fn(&Path) -> bool,
) -> Result<(), OutputError> {
    split(target)?;
    if target.exists() {
        if !target.is_dir() {
            return Err(refused(format!(
                "{} exists and is not a directory: give a new or empty directory",
                target.display()
            )));
        }
        let empty = std::fs::read_dir(target)
            .map_err(OutputError::writing(target))?
            .next()
            .is_none();
        if !empty && !is_ours(target) {
            return Err(refused(format!(
                "{} exists and is not {kind}: give a new or empty directory",
                target.display()
            )));
        }
    }
    check_parent(target)
}

/// Whether file `target` may be written: not a directory, a name, in a
/// folder that can be written.
pub fn check_file(target: &Path) -> Result<(), OutputError> {
    if target.is_dir() {
        return Err(refused(format!(
            "{} is a directory: give a file name",
            target.display()
        )));
    }
    check_parent(target)
}

/// Whether file `target` may be written as output `kind` (in words, e.g.
/// "a pairs file"): [`check_file`], and an existing file is replaced only
/// when it is empty or `is_ours` says it holds an earlier output of that
/// kind, as a directory is ([`check_dir`]): a mistyped path never replaces
/// a user's file.
pub fn check_file_of(
    target: &Path,
    kind: &str,
    is_ours: impl Fn(&Path) -> bool,
) -> Result<(), OutputError> {
    check_file(target)?;
    if let Ok(m) = std::fs::metadata(target) {
        if m.len() > 0 && !is_ours(target) {
            return Err(refused(format!(
                "{} exists and is not {kind}: give a new file name (or remove that file)",
                target.display()
            )));
        }
    }
    Ok(())
}

/// `path` made absolute and free of `.` and `..` (lexically), to compare
/// targets.
fn normal(path: &Path) -> PathBuf {
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut out = PathBuf::new();
    for c in abs.components() {
        match c {
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// The outputs of one run lie apart: none is another, or inside another
/// (each is replaced whole, so one would replace the other).
pub fn check_apart(targets: &[&Path]) -> Result<(), OutputError> {
    let normal: Vec<PathBuf> = targets.iter().map(|t| normal(t)).collect();
    for (i, a) in normal.iter().enumerate() {
        for (j, b) in normal.iter().enumerate() {
            if i != j && a.starts_with(b) {
                return Err(refused(format!(
                    "{} is {} {}: give every output its own place",
                    targets[i].display(),
                    if a == b { "given twice, as" } else { "inside" },
                    targets[j].display()
                )));
            }
        }
    }
    Ok(())
}

/// One output written into `partial`, to become `target`.
struct Staged {
    target: PathBuf,
    partial: PathBuf,
}

/// The outputs of one run, each written into its temporary sibling
/// ([`Outputs::dir`], [`Outputs::file`]) and renamed into place together by
/// [`Outputs::commit`]. Dropped without a commit (a failed run), it removes
/// the temporary siblings and leaves every target as it was.
#[derive(Default)]
pub struct Outputs {
    staged: Vec<Staged>,
}

impl Outputs {
    /// No output yet.
    pub fn new() -> Self {
        Self::default()
    }

    fn stage(&mut self, target: &Path, partial: PathBuf) -> Result<(), OutputError> {
        let mut all: Vec<&Path> = self.staged.iter().map(|s| s.target.as_path()).collect();
        all.push(target);
        check_apart(&all)?;
        let (parent, name) = split(target)?;
        std::fs::create_dir_all(&parent).map_err(OutputError::writing(&parent))?;
        stale::remove_stale(&parent, &name);
        interrupt::register(&partial);
        self.staged.push(Staged {
            target: target.to_path_buf(),
            partial,
        });
        Ok(())
    }

    /// Directory output `target` of `kind` (see [`check_dir`]): returns an
    /// empty temporary directory beside it to write the output into.
    pub fn dir(
        &mut self,
        target: &Path,
        kind: &str,
        is_ours: impl Fn(&Path) -> bool,
    ) -> Result<PathBuf, OutputError> {
        check_dir(target, kind, is_ours)?;
        let partial = sibling(target, "partial")?;
        self.stage(target, partial.clone())?;
        std::fs::create_dir(&partial).map_err(OutputError::writing(&partial))?;
        Ok(partial)
    }

    /// File output `target` of `kind` (see [`check_file_of`]): returns the
    /// temporary file name beside it to write the output to.
    pub fn file(
        &mut self,
        target: &Path,
        kind: &str,
        is_ours: impl Fn(&Path) -> bool,
    ) -> Result<PathBuf, OutputError> {
        check_file_of(target, kind, is_ours)?;
        let partial = sibling(target, "partial")?;
        self.stage(target, partial.clone())?;
        Ok(partial)
    }

    /// `e` with a temporary sibling's path in it shown as its target's (a
    /// disk full while writing `OUT/metrics.json` names that file).
    pub fn named(&self, e: OutputError) -> OutputError {
        let rename = |path: PathBuf| {
            for s in &self.staged {
                if let Ok(rest) = path.strip_prefix(&s.partial) {
                    return if rest.as_os_str().is_empty() {
                        s.target.clone()
                    } else {
                        s.target.join(rest)
                    };
                }
            }
            path
        };
        match e {
            OutputError::Write { path, source } => OutputError::Write {
                path: rename(path),
                source,
            },
            OutputError::Read(ReadError::Io { path, source }) => OutputError::Read(ReadError::Io {
                path: rename(path),
                source,
            }),
            OutputError::Read(ReadError::Png { path, reason }) => {
                OutputError::Read(ReadError::Png {
                    path: rename(path),
                    reason,
                })
            }
            // Words that name a path in their text (a refusal, a frame
            // that does not fit) name the target too, never the sibling.
            OutputError::Mismatch(text) => OutputError::Mismatch(self.named_text(text)),
            OutputError::Read(ReadError::Layout { path, reason }) => {
                OutputError::Read(ReadError::Layout {
                    path: rename(path),
                    reason: self.named_text(reason),
                })
            }
            other => other,
        }
    }

    /// `text` with every temporary sibling's path in it shown as its
    /// target's.
    fn named_text(&self, mut text: String) -> String {
        for s in &self.staged {
            let partial = s.partial.display().to_string();
            if text.contains(&partial) {
                text = text.replace(&partial, &s.target.display().to_string());
            }
        }
        text
    }

    /// Renames every output into place, each replacing its target whole. If
    /// one rename fails, those already made are undone, so that every target
    /// is as before.
    pub fn commit(mut self) -> Result<(), OutputError> {
        // A SIGINT or SIGTERM now waits for the renames to end (all made or
        // all undone) before it removes what is still partial.
        let mut live = interrupt::live();
        let staged = std::mem::take(&mut self.staged);
        // (target, its previous content moved aside if any)
        let mut done: Vec<(&Staged, Option<PathBuf>)> = Vec::new();
        let mut failed = None;
        for s in &staged {
            match Self::swap(s) {
                Ok(old) => done.push((s, old)),
                Err(e) => {
                    failed = Some(e);
                    break;
                }
            }
        }
        if let Some(e) = failed {
            for (s, old) in done.into_iter().rev() {
                let _ = std::fs::rename(&s.target, &s.partial);
                if let Some(old) = old {
                    let _ = std::fs::rename(&old, &s.target);
                }
            }
            self.staged = staged;
            return Err(e);
        }
        for s in &staged {
            interrupt::forget(&mut live, &s.partial);
        }
        drop(live);
        for (_, old) in done {
            if let Some(old) = old {
                if let Err(e) = remove(&old) {
                    crate::warning::warn(format!(
                        "the previous output moved to {} could not be removed: {e}",
                        old.display()
                    ));
                }
            }
        }
        Ok(())
    }

    /// Moves `s.target` aside (if it exists) and `s.partial` into its place;
    /// returns where the previous content went.
    fn swap(s: &Staged) -> Result<Option<PathBuf>, OutputError> {
        let old = if std::fs::symlink_metadata(&s.target).is_ok() {
            let old = sibling(&s.target, "old")?;
            std::fs::rename(&s.target, &old).map_err(OutputError::writing(&s.target))?;
            Some(old)
        } else {
            None
        };
        if let Err(e) = std::fs::rename(&s.partial, &s.target) {
            if let Some(old) = &old {
                let _ = std::fs::rename(old, &s.target);
            }
            return Err(OutputError::writing(&s.target)(e));
        }
        Ok(old)
    }
}

impl Drop for Outputs {
    fn drop(&mut self) {
        for s in &self.staged {
            let _ = remove(&s.partial);
        }
        let mut live = interrupt::live();
        for s in &self.staged {
            interrupt::forget(&mut live, &s.partial);
        }
    }
}

/// Runs `fill`, which writes a run's outputs into the [`Outputs`] it is
/// given, and renames them into place together when it succeeds; when it
/// fails, or a rename does, every target is left as it was. An error names
/// the target's path, not the temporary one.
pub fn together<T>(
    fill: impl FnOnce(&mut Outputs) -> Result<T, OutputError>,
) -> Result<T, OutputError> {
    let mut outputs = Outputs::new();
    match fill(&mut outputs) {
        // A failed rename names its target already.
        Ok(v) => outputs.commit().map(|()| v),
        Err(e) => Err(outputs.named(e)),
    }
}

/// Writes `text` to the file `path` (a staged output's temporary file, or a
/// file inside a staged directory), naming it in an error.
pub fn write_text(path: &Path, text: &str) -> Result<(), OutputError> {
    std::fs::write(path, text).map_err(OutputError::writing(path))
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

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    /// Writes `mark` = `text` (and `extra` when given) as output `target`.
    fn run(target: &Path, text: &str, extra: bool, fail: bool) -> Result<(), OutputError> {
        let mut outputs = Outputs::new();
        let d = outputs.dir(target, "an export", |d| d.join("mark").exists())?;
        write_text(&d.join("mark"), text)?;
        if extra {
            write_text(&d.join("extra"), text)?;
        }
        if fail {
            return Err(OutputError::Mismatch("broken".into()));
        }
        outputs.commit()
    }

    /// An error about a file in a staged output names the user's target,
    /// never the hidden sibling, whatever its form.
    #[test]
    fn errors_name_the_target_not_the_hidden_sibling() {
        let root = temp("named");
        let target = root.join("v@x");
        let mut outputs = Outputs::new();
        let d = outputs.dir(&target, "an export", |_| false).unwrap();
        let inside = d.join("database").join("a.jpg");
        let want = target.join("database").join("a.jpg").display().to_string();
        let errors = [
            OutputError::Write {
                path: inside.clone(),
                source: std::io::ErrorKind::StorageFull.into(),
            },
            OutputError::Mismatch(format!("{}: not a readable JPEG file", inside.display())),
        ];
        for e in errors {
            let said = outputs.named(e).to_string();
            assert!(said.contains(&want), "{said}");
            assert!(!said.contains(".partial-"), "{said}");
        }
        drop(outputs);
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn a_failed_run_leaves_what_was_there_and_a_rerun_leaves_no_stale_file() {
        let root = temp("fail");
        let target = root.join("out");
        run(&target, "1", true, false).unwrap();
        assert!(run(&target, "2", false, true).is_err());
        assert_eq!(std::fs::read_to_string(target.join("mark")).unwrap(), "1");
        assert_eq!(names(&root), ["out"], "nothing left beside it");
        run(&target, "3", false, false).unwrap();
        assert_eq!(std::fs::read_to_string(target.join("mark")).unwrap(), "3");
        assert_eq!(names(&target), ["mark"], "the earlier extra is gone");
        assert_eq!(names(&root), ["out"]);
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn the_outputs_of_one_run_appear_together_or_not_at_all() {
        let root = temp("together");
        let (a, b) = (root.join("a"), root.join("b.txt"));
        let mut outputs = Outputs::new();
        let d = outputs.dir(&a, "an export", |_| false).unwrap();
        write_text(&d.join("mark"), "a").unwrap();
        let f = outputs.file(&b, "a test file", |_| true).unwrap();
        write_text(&f, "b").unwrap();
        assert!(!a.exists() && !b.exists(), "nothing before the commit");
        outputs.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&b).unwrap(), "b");
        // A second run whose second rename fails (its target became a
        // directory meanwhile) puts the first back.
        let mut outputs = Outputs::new();
        let d = outputs
            .dir(&a, "an export", |d| d.join("mark").exists())
            .unwrap();
        write_text(&d.join("mark"), "a2").unwrap();
        let f = outputs.file(&b, "a test file", |_| true).unwrap();
        write_text(&f, "b2").unwrap();
        std::fs::remove_file(&f).unwrap();
        let msg = outputs.commit().unwrap_err().to_string();
        assert!(msg.contains("b.txt"), "{msg}");
        assert_eq!(std::fs::read_to_string(a.join("mark")).unwrap(), "a");
        assert_eq!(std::fs::read_to_string(&b).unwrap(), "b");
        assert_eq!(names(&root), ["a", "b.txt"]);
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn a_directory_of_other_files_or_a_bad_place_is_refused_before_the_work() {
        let root = temp("other");
        std::fs::write(root.join("precious.txt"), "keep").unwrap();
        let msg = check_dir(&root, "a COLMAP export", |_| false)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("is not a COLMAP export"), "{msg}");
        assert!(root.join("precious.txt").exists());
        let file = root.join("precious.txt");
        let msg = check_dir(&file, "a dataset", |_| true)
            .unwrap_err()
            .to_string();
        assert!(
            msg.contains("precious.txt exists and is not a directory"),
            "{msg}"
        );
        let msg = check_dir(&file.join("sub/out"), "a dataset", |_| true)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("precious.txt is not a directory"), "{msg}");
        assert!(check_file(&root).is_err());
        let msg = check_apart(&[&root.join("x"), &root.join("x/y")])
            .unwrap_err()
            .to_string();
        assert!(msg.contains("is inside"), "{msg}");
        assert!(check_apart(&[&root.join("x"), &root.join("./x")]).is_err());
        assert!(check_apart(&[&root.join("x"), &root.join("xy")]).is_ok());
        assert_eq!(names(&root), ["precious.txt"], "no probe left");
        std::fs::remove_dir_all(&root).ok();
    }
}
