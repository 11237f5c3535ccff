//! What the command-line tests share: running the real `placedb` binary,
//! a temporary directory removed on drop, a copy of the first frames of
//! the 7-Scenes sample to run on (the sample itself is never written), and
//! `placedb device` as a user runs it ([`device`]).

#![allow(dead_code)]

pub mod device;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The 7-Scenes sample of `../shared/data`.
pub const SEVEN_SCENES: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/data/7scenes-1000"
);

/// Runs `placedb args`.
pub fn placedb<S: AsRef<std::ffi::OsStr>>(args: &[S]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(args)
        .output()
        .expect("the placedb binary runs")
}

/// What a run wrote on stderr.
pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A fresh empty directory under the system temp dir, removed on drop.
pub struct TempDir(PathBuf);

impl TempDir {
    pub fn new(name: &str) -> TempDir {
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let p = std::env::temp_dir().join(format!("placedb-cli-{}-{n}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }

    /// `self/name` as a string, for an argument.
    pub fn arg(&self, name: &str) -> String {
        self.0.join(name).to_string_lossy().into_owned()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Copies the first `frames` frames of the 7-Scenes sample (depth, pose and
/// the intrinsics file when `intrinsics`) into `dir`.
pub fn seven_scenes_copy(dir: &Path, frames: usize, intrinsics: bool) {
    seven_scenes_frames(dir, 0..frames, intrinsics);
}

/// Copies the sample's frames `frames` (depth and pose, keeping their
/// numbers, and the intrinsics file when `intrinsics`) into `dir`.
pub fn seven_scenes_frames(dir: &Path, frames: impl IntoIterator<Item = usize>, intrinsics: bool) {
    let src = Path::new(SEVEN_SCENES);
    assert!(
        src.is_dir(),
        "test data {} is missing: the command-line tests need ../shared/data",
        src.display()
    );
    std::fs::create_dir_all(dir).unwrap();
    for i in frames {
        for kind in ["depth.png", "pose.txt"] {
            let name = format!("frame-{i:06}.{kind}");
            std::fs::copy(src.join(&name), dir.join(&name)).unwrap();
        }
    }
    if intrinsics {
        std::fs::copy(
            src.join("camera-intrinsics.txt"),
            dir.join("camera-intrinsics.txt"),
        )
        .unwrap();
    }
}

/// Files by relative path, with their bytes.
pub type Tree = BTreeMap<String, Vec<u8>>;

/// Every file under `dir`, by relative path, with its bytes.
pub fn tree(dir: &Path) -> Tree {
    fn walk(root: &Path, at: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for e in std::fs::read_dir(at).unwrap() {
            let path = e.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                let rel = path.strip_prefix(root).unwrap().to_string_lossy().into();
                out.insert(rel, std::fs::read(&path).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// The names in `dir`, sorted.
pub fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}
