//! The host crate's layer rule (docs/ARCHITECTURE.md), checked from the
//! `use` lines and paths of host/src: each top-level module imports only
//! modules listed below it in [`LAYERS`], and no file imports one that
//! imports it back (directly or round a longer circle). Unit-test modules
//! (`#[cfg(test)] mod tests { ... }`) and comments are left out: test code
//! may use `crate::testing`, which sits above every layer.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The top-level modules of host/src, top first. A module may import only
/// those after it. `testing` (shared by the tests, feature `testing`) is
/// above everything and only test code imports it.
const LAYERS: &[&str] = &[
    "testing",
    "cli",
    "board",
    "sessions",
    "output",
    "pipeline",
    "replay",
    "yardstick",
    "degradation",
    "voxelize",
    "frame_rows",
    "synth",
    "read",
    "sequence",
    "picture",
    "vector_unit",
    "rng",
    "interrupt",
    "error",
    "warning",
];

fn src() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every .rs file under `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// `text` without comments, string literals' contents and
/// `#[cfg(test)]` items (a test module's braces skipped whole).
fn code_of(text: &str) -> String {
    let mut kept = String::with_capacity(text.len());
    let b = text.as_bytes();
    let mut i = 0;
    while i < b.len() {
        if text[i..].starts_with("//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if text[i..].starts_with("/*") {
            i += text[i..].find("*/").map_or(b.len() - i, |k| k + 2);
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            kept.push_str("\"\"");
        } else if text[i..].starts_with("#[cfg(test)]") {
            // Skip the item: up to its `;` or its balanced braces.
            let mut depth = 0usize;
            while i < b.len() {
                match b[i] {
                    b'{' => depth += 1,
                    b'}' => {
                        depth -= 1;
                        if depth == 0 {
                            i += 1;
                            break;
                        }
                    }
                    b';' if depth == 0 => {
                        i += 1;
                        break;
                    }
                    _ => {}
                }
                i += 1;
            }
        } else {
            kept.push(b[i] as char);
            i += 1;
        }
    }
    kept
}

/// The module path of a file: host/src/a/b.rs and host/src/a/b/mod.rs are
/// `["a", "b"]`; lib.rs is `[]`.
fn module_of(file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src()).unwrap();
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().unwrap();
    let stem = last.trim_end_matches(".rs");
    if stem != "mod" && stem != "lib" && stem != "main" {
        parts.push(stem.to_string());
    }
    parts
}

/// Paths used in `code`: each `crate::a::b` or `super::a` (with `use`
/// groups `{x, y::z}` expanded one level), as segments.
fn paths_in(code: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let ident = |c: char| c.is_ascii_alphanumeric() || c == '_';
    for start in ["crate::", "super::"] {
        let mut from = 0;
        while let Some(k) = code[from..].find(start) {
            let at = from + k;
            from = at + start.len();
            if at > 0 && ident(code[..at].chars().last().unwrap()) {
                continue;
            }
            let mut segs = vec![start.trim_end_matches("::").to_string()];
            let mut rest = &code[at + start.len()..];
            loop {
                let n = rest.find(|c: char| !ident(c)).unwrap_or(rest.len());
                if n == 0 {
                    break;
                }
                segs.push(rest[..n].to_string());
                rest = &rest[n..];
                if let Some(r) = rest.strip_prefix("::") {
                    rest = r;
                    if let Some(group) = rest.strip_prefix('{') {
                        let end = group.find('}').unwrap_or(group.len());
                        for item in group[..end].split(',') {
                            let item: Vec<String> = item
                                .split("::")
                                .map(|s| s.trim().split(' ').next().unwrap_or("").to_string())
                                .filter(|s| !s.is_empty() && s.chars().all(ident))
                                .collect();
                            let mut p = segs.clone();
                            p.extend(item);
                            out.push(p);
                        }
                        segs.clear();
                        break;
                    }
                } else {
                    break;
                }
            }
            if !segs.is_empty() {
                out.push(segs);
            }
        }
    }
    out
}

/// The file modules of the crate, by module path.
struct Crate {
    files: BTreeMap<Vec<String>, PathBuf>,
    /// `pub use` re-exports of lib.rs: name -> module.
    reexports: BTreeMap<String, Vec<String>>,
}

impl Crate {
    fn load() -> Crate {
        let mut all = Vec::new();
        rust_files(&src(), &mut all);
        let files: BTreeMap<_, _> = all
            .into_iter()
            .filter(|f| !f.ends_with("main.rs"))
            .map(|f| (module_of(&f), f))
            .collect();
        let lib = std::fs::read_to_string(src().join("lib.rs")).unwrap();
        let mut reexports = BTreeMap::new();
        for p in paths_in(&code_of(&lib.replace("pub use ", "pub use crate::"))) {
            if let [_, module, .., name] = p.as_slice() {
                reexports.insert(name.clone(), vec![module.clone()]);
            }
        }
        Crate { files, reexports }
    }

    /// The file module a path used in module `from` names (the longest
    /// prefix that is a file).
    fn resolve(&self, from: &[String], path: &[String]) -> Option<Vec<String>> {
        let mut base: Vec<String> = Vec::new();
        let mut rest = path;
        match path.first().map(String::as_str) {
            Some("crate") => rest = &path[1..],
            Some("super") => {
                base = from.to_vec();
                while rest.first().is_some_and(|s| s == "super") {
                    base.pop()?;
                    rest = &rest[1..];
                }
            }
            _ => return None,
        }
        if base.is_empty() {
            if let Some(first) = rest.first() {
                if let Some(module) = self.reexports.get(first) {
                    return Some(module.clone());
                }
            }
        }
        let mut best = base.clone();
        let mut cur = base;
        for seg in rest {
            cur.push(seg.clone());
            if self.files.contains_key(&cur) {
                best = cur.clone();
            } else {
                break;
            }
        }
        Some(best)
    }

    /// Which file modules each file module imports.
    fn imports(&self) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
        let mut graph = BTreeMap::new();
        for (module, file) in &self.files {
            let code = code_of(&std::fs::read_to_string(file).unwrap());
            let mut to = BTreeSet::new();
            for p in paths_in(&code) {
                if let Some(target) = self.resolve(module, &p) {
                    // A module naming its own items, or an ancestor naming
                    // the children it declares, is no import.
                    if !target.is_empty() && !target.starts_with(module) && &target != module {
                        to.insert(target);
                    }
                }
            }
            graph.insert(module.clone(), to);
        }
        graph
    }
}

#[test]
fn every_top_level_module_has_a_layer() {
    let krate = Crate::load();
    let tops: BTreeSet<&str> = krate
        .files
        .keys()
        .filter_map(|m| m.first().map(String::as_str))
        .collect();
    for top in tops {
        assert!(
            LAYERS.contains(&top),
            "host/src/{top}: not in the layer list of host/tests/layers.rs (and docs/ARCHITECTURE.md)"
        );
    }
}

#[test]
fn imports_go_down_the_layers() {
    let krate = Crate::load();
    let rank = |m: &[String]| {
        LAYERS
            .iter()
            .position(|l| Some(*l) == m.first().map(String::as_str))
    };
    let mut wrong = Vec::new();
    for (from, tos) in krate.imports() {
        for to in tos {
            let (Some(a), Some(b)) = (rank(&from), rank(&to)) else {
                continue;
            };
            if a > b || (to.first() == Some(&"testing".to_string()) && from.first() != to.first()) {
                wrong.push(format!(
                    "{} imports {} (up a layer)",
                    from.join("::"),
                    to.join("::")
                ));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports that run up the stack:\n{}",
        wrong.join("\n")
    );
}

#[test]
fn no_file_imports_one_that_imports_it_back() {
    let graph = Crate::load().imports();
    // Depth-first search for a back edge; the circle is printed.
    fn visit(
        m: &Vec<String>,
        graph: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>,
        stack: &mut Vec<Vec<String>>,
        done: &mut BTreeSet<Vec<String>>,
    ) -> Option<Vec<Vec<String>>> {
        if let Some(k) = stack.iter().position(|s| s == m) {
            return Some(stack[k..].to_vec());
        }
        if done.contains(m) {
            return None;
        }
        stack.push(m.clone());
        for to in graph.get(m).into_iter().flatten() {
            if let Some(circle) = visit(to, graph, stack, done) {
                return Some(circle);
            }
        }
        stack.pop();
        done.insert(m.clone());
        None
    }
    let mut done = BTreeSet::new();
    for m in graph.keys() {
        if let Some(circle) = visit(m, &graph, &mut Vec::new(), &mut done) {
            let names: Vec<String> = circle.iter().map(|m| m.join("::")).collect();
            panic!("import circle: {} -> back to the first", names.join(" -> "));
        }
    }
}

/// The checker sees what it must: a path into a sibling, a group, a
/// `super` path, a re-export, and nothing in comments or test modules.
#[test]
fn the_checker_reads_paths_as_the_compiler_does() {
    let code = code_of(
        "use crate::a::{b, c::d};\n// use crate::x;\nuse super::e;\n#[cfg(test)]\nmod tests { use crate::y; }\nfn f() { crate::g::h(); }",
    );
    let paths = paths_in(&code);
    let seen: Vec<String> = paths.iter().map(|p| p.join("::")).collect();
    assert_eq!(
        seen,
        vec!["crate::a::b", "crate::a::c::d", "crate::g::h", "super::e"]
    );
}

/// The core is testable alone (docs/CONTRIBUTING.md, "Tests"): its
/// dev-dependencies name no host crate, and no test file of `tests/` uses
/// one, so `cargo test -p placedb` builds no host code and no C++.
#[test]
fn the_core_tests_without_the_host() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).unwrap();
    let dev_deps: Vec<&str> = manifest
        .split("\n[")
        .filter(|table| table.starts_with("dev-dependencies]"))
        .flat_map(|table| table.lines().skip(1))
        .filter(|line| !line.trim_start().starts_with('#'))
        .collect();
    assert!(
        !dev_deps.is_empty(),
        "the root Cargo.toml has no [dev-dependencies]"
    );
    for line in &dev_deps {
        assert!(
            !line.contains("host") && !line.contains("png"),
            "the core's dev-dependencies name a host crate: {line}"
        );
    }
    let mut tests = Vec::new();
    rust_files(&root.join("tests"), &mut tests);
    assert!(!tests.is_empty(), "no test files in tests/");
    for file in tests {
        let code = code_of(&std::fs::read_to_string(&file).unwrap());
        assert!(
            !code.contains("placedb_host"),
            "{} uses the host crate: it belongs in host/tests/",
            file.display()
        );
    }
}
