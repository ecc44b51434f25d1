//! Two-column CSV files of names (`from,to`, one row per name): the C3D label maps of
//! `--label-map` and the rig name maps of `--name-map`. A header names the two columns;
//! blank lines and `#` comments are skipped; a `from` name may appear once.

use std::collections::HashMap;

/// The layout of one kind of name-pair file.
#[derive(Debug, Clone, Copy)]
pub(crate) struct NamePairsFormat<'a> {
    /// The header's two column names.
    pub columns: [&'a str; 2],
    /// What a `from` name is, for the duplicate error ("label", "shape").
    pub what: &'a str,
    /// Whether rows (and the header) may have columns after the two.
    pub extra_columns: bool,
}

/// Parses `text`: the (from, to) rows in file order, or the 1-based line and message of the
/// first problem (an empty file, a wrong header, a row without two names, a name twice).
pub(crate) fn parse_name_pairs(
    text: &str,
    format: &NamePairsFormat,
) -> Result<Vec<(String, String)>, (usize, String)> {
    let [from, to] = format.columns;
    let columns_ok = |n: usize| n == 2 || (format.extra_columns && n > 2);
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let (hline, header) = lines
        .next()
        .ok_or_else(|| (1, format!("empty file: expected header {from},{to}")))?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    if !columns_ok(cols.len()) || cols[..2] != [from, to] {
        return Err((hline, format!("header {header:?} should be {from},{to}")));
    }
    let mut rows = Vec::new();
    let mut seen: HashMap<String, usize> = HashMap::new();
    for (line, row) in lines {
        let f: Vec<&str> = row.split(',').map(str::trim).collect();
        if !columns_ok(f.len()) || f[0].is_empty() || f[1].is_empty() {
            return Err((line, format!("{row:?}: expected {from},{to}")));
        }
        if let Some(first) = seen.insert(f[0].to_string(), line) {
            return Err((
                line,
                format!(
                    "{} {} is mapped twice (first on line {first})",
                    format.what, f[0]
                ),
            ));
        }
        rows.push((f[0].to_string(), f[1].to_string()));
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    const FORMAT: NamePairsFormat = NamePairsFormat {
        columns: ["shape", "target"],
        what: "shape",
        extra_columns: false,
    };

    #[test]
    fn rows_comments_and_every_error_with_its_line() {
        let rows = parse_name_pairs("# map\nshape, target\n\na,b\nc , d\n", &FORMAT).unwrap();
        assert_eq!(rows, [("a".into(), "b".into()), ("c".into(), "d".into())]);
        let line = |text: &str| parse_name_pairs(text, &FORMAT).unwrap_err().0;
        assert_eq!(line(""), 1);
        assert_eq!(line("\nname,target\n"), 2);
        assert_eq!(line("shape,target\na,b\na,c\n"), 3);
        assert_eq!(line("shape,target\na,b,c\n"), 2);
        assert_eq!(line("shape,target\n,b\n"), 2);
        let extra = NamePairsFormat {
            extra_columns: true,
            ..FORMAT
        };
        assert_eq!(
            parse_name_pairs("shape,target,note\na,b,x\n", &extra).unwrap(),
            [("a".into(), "b".into())]
        );
    }
}
