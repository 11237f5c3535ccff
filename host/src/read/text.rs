//! Shared helpers for the readers' text files: reading with the path in the
//! error, numbered data lines, number columns, pose validation with the line.

use crate::error::ReadError;
use std::path::Path;

/// Reads a whole text file; a missing or unreadable file is an `Io` error
/// naming it.
pub(crate) fn read_text(path: &Path) -> Result<String, ReadError> {
    std::fs::read_to_string(path).map_err(|source| ReadError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The data lines of a text file with their 1-based line numbers: blank lines
/// and `#` comment lines are skipped, surrounding white space is trimmed.
pub(crate) fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// A `Parse` error at `path:line`.
pub(crate) fn parse_error(path: &Path, line: usize, reason: impl Into<String>) -> ReadError {
    ReadError::Parse {
        path: path.to_path_buf(),
        line,
        reason: reason.into(),
    }
}

/// Parses a white-space separated line of numbers whose column count is one
/// of `allowed`. `what` names the line's meaning for the message, e.g.
/// "`tx ty tz qx qy qz qw`".
pub(crate) fn numbers(
    path: &Path,
    line: usize,
    text: &str,
    allowed: &[usize],
    what: &str,
) -> Result<Vec<f64>, ReadError> {
    let mut out = Vec::with_capacity(allowed.iter().copied().max().unwrap_or(0));
    for (col, field) in text.split_whitespace().enumerate() {
        let v: f64 = field.parse().map_err(|_| {
            parse_error(
                path,
                line,
                format!("column {}: {field:?} is not a number", col + 1),
            )
        })?;
        out.push(v);
    }
    if !allowed.contains(&out.len()) {
        let expected = allowed
            .iter()
            .map(|n| n.to_string())
            .collect::<Vec<_>>()
            .join(" or ");
        return Err(parse_error(
            path,
            line,
            format!("expected {expected} numbers ({what}), found {}", out.len()),
        ));
    }
    Ok(out)
}

/// The rows of an `n` x `n` matrix written a row a line in `content` (the
/// text of `path`), each with its 1-based line; `what` names the matrix in
/// errors ("pose", "intrinsics"): a row of another length, a row too many
/// or too few is an error naming the line.
pub(crate) fn square_rows(
    path: &Path,
    content: &str,
    n: usize,
    what: &str,
) -> Result<Vec<(usize, Vec<f64>)>, ReadError> {
    let mut rows: Vec<(usize, Vec<f64>)> = Vec::with_capacity(n);
    let mut last_line = 1;
    for (line, l) in data_lines(content) {
        if rows.len() == n {
            return Err(parse_error(
                path,
                line,
                format!("more than {n} rows in a {n}x{n} {what} matrix"),
            ));
        }
        let row_of = format!("a row of the {n}x{n} {what} matrix");
        rows.push((line, numbers(path, line, l, &[n], &row_of)?));
        last_line = line;
    }
    if rows.len() < n {
        return Err(parse_error(
            path,
            last_line,
            format!("a {n}x{n} {what} matrix has {n} rows, found {}", rows.len()),
        ));
    }
    Ok(rows)
}

/// Checks a translation and quaternion `[qx, qy, qz, qw]` with the core's
/// rules and returns the quaternion normalised in `f64`.
pub(crate) fn checked_quaternion(
    path: &Path,
    line: usize,
    t: [f64; 3],
    q: [f64; 4],
) -> Result<[f64; 4], ReadError> {
    placedb::Pose::from_quaternion(t.map(|c| c as f32), q.map(|c| c as f32)).map_err(|reason| {
        ReadError::Pose {
            path: path.to_path_buf(),
            line,
            reason,
        }
    })?;
    let n = q.iter().map(|c| c * c).sum::<f64>().sqrt();
    Ok(q.map(|c| c / n))
}

/// The directory's name for messages and `Sequence::name`.
pub(crate) fn dir_name(dir: &Path) -> String {
    dir.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .or_else(|| {
            dir.canonicalize()
                .ok()
                .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        })
        .unwrap_or_else(|| dir.display().to_string())
}

/// Lists a directory's entries (file names), naming it on failure.
pub(crate) fn list_dir(dir: &Path) -> Result<Vec<String>, ReadError> {
    let io = |source| ReadError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let entry = entry.map_err(io)?;
        if let Some(name) = entry.file_name().to_str() {
            names.push(name.to_owned());
        }
    }
    Ok(names)
}

/// A `Layout` error about `path`.
pub(crate) fn layout(path: &Path, reason: impl Into<String>) -> ReadError {
    ReadError::Layout {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_lines_skip_comments_and_blanks_keeping_numbers() {
        let text = "# header\n\n 1 2 \n#x\n3\n";
        let got: Vec<_> = data_lines(text).collect();
        assert_eq!(got, vec![(3, "1 2"), (5, "3")]);
    }

    #[test]
    fn numbers_reports_column_and_count() {
        let p = Path::new("f.txt");
        assert_eq!(
            numbers(p, 1, "1 2.5 -3e1", &[3], "x").unwrap(),
            vec![1.0, 2.5, -30.0]
        );
        let e = numbers(p, 4, "1 x 3", &[3], "x").unwrap_err().to_string();
        assert!(e.contains("f.txt:4") && e.contains("column 2"), "{e}");
        let e = numbers(p, 2, "1 2", &[7, 8], "pose")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("f.txt:2") && e.contains("7 or 8") && e.contains("found 2"),
            "{e}"
        );
    }

    #[test]
    fn quaternion_is_checked_and_normalised() {
        let p = Path::new("g.txt");
        let q = checked_quaternion(p, 1, [0.0; 3], [0.0, 0.0, 0.0, 1.0002]).unwrap();
        assert!((q[3] - 1.0).abs() < 1e-15);
        let e = checked_quaternion(p, 9, [f64::NAN, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]);
        assert!(matches!(
            e,
            Err(ReadError::Pose {
                line: 9,
                reason: placedb::CameraError::NonFinitePose,
                ..
            })
        ));
        let e = checked_quaternion(p, 2, [0.0; 3], [0.0, 0.0, 0.0, 2.0]);
        assert!(matches!(
            e,
            Err(ReadError::Pose {
                reason: placedb::CameraError::NotARotation,
                ..
            })
        ));
    }
}
