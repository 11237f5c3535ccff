//! `database.csv` and `labels.csv` of an extended run (`select --extend`):
//! the columns of a one-session run, byte for byte as [`super::database_csv`]
//! and [`super::labels_csv`] write them, with columns appended that say
//! which session each frame (and each class frame) came from.

use super::{DbRow, Numbers};

/// The session of a global frame index and its index within that session.
pub type SessionOf<'a> = &'a dyn Fn(usize) -> (u32, u32);

/// Appends `extra(row)` to each line after the header of `text`, and
/// `header` to the header.
fn append(text: &str, header: &str, mut extra: impl FnMut(usize) -> String) -> String {
    let mut out = String::with_capacity(text.len() + text.len() / 4);
    for (k, line) in text.lines().enumerate() {
        out.push_str(line);
        if k == 0 {
            out.push_str(header);
        } else {
            out.push_str(&extra(k - 1));
        }
        out.push('\n');
    }
    out
}

/// `database.csv` with `session,session_index` appended; its index column
/// numbered by `numbers` (the sessions are the run's own).
pub fn database_csv(rows: &[DbRow], session_of: SessionOf<'_>, numbers: Numbers<'_>) -> String {
    let mut sorted = rows.to_vec();
    sorted.sort_by_key(|r| r.0);
    append(
        &super::database_csv_numbered(&sorted, numbers),
        ",session,session_index",
        |k| {
            let (s, i) = session_of(sorted[k].0);
            format!(",{s},{i}")
        },
    )
}

/// `labels.csv` of every frame of every session with
/// `session,session_index,class_session` appended; its index and class
/// columns numbered by `numbers` (the sessions are the run's own).
pub fn labels_csv(
    timestamps: &[f64],
    labels: &[usize],
    session_of: SessionOf<'_>,
    numbers: Numbers<'_>,
) -> String {
    append(
        &super::labels_csv_numbered(timestamps, labels, numbers),
        ",session,session_index,class_session",
        |k| {
            let (s, i) = session_of(k);
            let (cs, _) = session_of(labels[k]);
            format!(",{s},{i},{cs}")
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_one_session_columns_come_first_unchanged() {
        let split = |g: usize| {
            if g < 2 {
                (0, g as u32)
            } else {
                (1, g as u32 - 2)
            }
        };
        let rows = vec![(2, 3.0, [0.0; 7]), (0, 1.0, [1.0; 7])];
        let db = database_csv(&rows, &split, None);
        let plain = super::super::database_csv(&rows);
        for (a, b) in db.lines().zip(plain.lines()) {
            assert!(a.starts_with(b), "{a} / {b}");
        }
        assert!(db.starts_with("index,timestamp,tx,ty,tz,qx,qy,qz,qw,session,session_index\n0,"));
        assert!(db.ends_with(",1,0\n"), "{db}");
        let labels = labels_csv(&[1.0, 2.0, 3.0], &[0, 0, 0], &split, None);
        assert_eq!(
            labels,
            "index,timestamp,class_index,session,session_index,class_session\n\
             0,1.000000,0,0,0,0\n1,2.000000,0,0,1,0\n2,3.000000,0,1,0,0\n"
        );
    }
}
