//! The docs say what the program prints: docs/DEVICE.md's budget table is
//! `placedb budget`'s table line for line, and README.md's command table
//! names exactly the subcommands `placedb --help` lists, one row each.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository's root (the host crate's parent).
fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("the host crate lies in the repository")
        .to_path_buf()
}

fn read(rel: &str) -> String {
    let path = repo().join(rel);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `placedb ARGS`'s stdout; it must succeed.
fn placedb(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_placedb"))
        .args(args)
        .output()
        .expect("placedb runs");
    assert!(
        out.status.success(),
        "placedb {args:?}: {:?}, stderr: {}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("UTF-8 output")
}

/// The lines of the first fenced block after the line holding `marker`.
fn block_after<'a>(text: &'a str, marker: &str) -> Vec<&'a str> {
    let start = text
        .find(marker)
        .unwrap_or_else(|| panic!("no {marker:?} in the document"));
    let mut lines = text[start..]
        .lines()
        .skip_while(|l| !l.starts_with("```"))
        .skip(1);
    let block: Vec<&str> = lines
        .by_ref()
        .take_while(|l| !l.starts_with("```"))
        .collect();
    assert!(!block.is_empty(), "an empty block after {marker:?}");
    block
}

#[test]
fn device_md_budget_table_is_what_placedb_budget_prints() {
    let printed = placedb(&["budget"]);
    // The table is the lines before the legend (`selector = ...`).
    let table: Vec<&str> = printed
        .lines()
        .take_while(|l| !l.contains(" = "))
        .map(str::trim_end)
        .collect();
    assert!(
        table.len() >= 2,
        "no table in placedb budget's output:\n{printed}"
    );
    let doc = read("docs/DEVICE.md");
    let documented: Vec<&str> = block_after(&doc, "`placedb budget` prints each capacity profile")
        .into_iter()
        .map(str::trim_end)
        .collect();
    assert_eq!(
        documented, table,
        "docs/DEVICE.md's budget table differs from `placedb budget`: paste its table in"
    );
}

/// The subcommands `placedb --help` lists (without `help`).
fn listed_commands() -> Vec<String> {
    let help = placedb(&["--help"]);
    let mut names: Vec<String> = help
        .lines()
        .skip_while(|l| l.trim() != "Commands:")
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        // A command's line is indented two spaces; a wrapped about text more.
        .filter(|l| l.starts_with("  ") && !l.starts_with("   "))
        .filter_map(|l| l.split_whitespace().next())
        .filter(|&n| n != "help")
        .map(String::from)
        .collect();
    assert!(!names.is_empty(), "no commands in placedb --help:\n{help}");
    names.sort();
    names
}

/// The commands README.md's command table names, one per row, in row order
/// sorted (a command named twice shows twice).
fn readme_commands() -> Vec<String> {
    let readme = read("README.md");
    let mut rows = readme
        .lines()
        .skip_while(|l| !l.starts_with("| command |"))
        .skip(2) // the header and its |---| line
        .take_while(|l| l.starts_with('|'));
    let mut names: Vec<String> = rows
        .by_ref()
        .map(|row| {
            let cell = row.split('|').nth(1).unwrap_or("").trim();
            let words: Vec<&str> = cell.trim_matches('`').split_whitespace().collect();
            assert!(
                words.len() >= 2 && words[0] == "placedb",
                "README.md's command table: row {row:?} does not start with `placedb COMMAND`"
            );
            words[1].to_string()
        })
        .collect();
    assert!(!names.is_empty(), "README.md has no `| command |` table");
    names.sort();
    names
}

#[test]
fn readme_command_table_names_every_subcommand_once() {
    assert_eq!(
        readme_commands(),
        listed_commands(),
        "README.md's command table (left) and `placedb --help`'s commands (right) differ"
    );
}
