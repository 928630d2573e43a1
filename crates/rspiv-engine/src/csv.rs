//! Minimal CSV reading and writing for point tables: a header row naming the columns, comma
//! separated numbers, blank lines and lines starting with `#` ignored. Errors name the file,
//! the line and the problem.

use std::io::Write;
use std::path::Path;

/// Read the named columns of a numeric CSV file into rows of `cols.len()` values.
pub fn read_columns(path: &Path, cols: &[&str]) -> Result<Vec<Vec<f64>>, String> {
    let name = path.display();
    let bytes = std::fs::read(path).map_err(|e| format!("{name}: cannot read ({e})"))?;
    let text = String::from_utf8(bytes).map_err(|_| format!("{name}: not a UTF-8 text file"))?;
    parse_columns(&text, cols).map_err(|e| format!("{name}: {e}"))
}

/// Parse CSV text (see [`read_columns`]); errors without the file name.
pub fn parse_columns(text: &str, cols: &[&str]) -> Result<Vec<Vec<f64>>, String> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let (_, header) = lines.next().ok_or("empty file (expected a header row)")?;
    let names: Vec<&str> = header
        .split(',')
        .map(|s| s.trim().trim_matches('"'))
        .collect();
    let idx = cols
        .iter()
        .map(|c| {
            names.iter().position(|n| n == c).ok_or_else(|| {
                format!(
                    "missing column {c:?} (header has {}; expected {})",
                    names.join(","),
                    cols.join(",")
                )
            })
        })
        .collect::<Result<Vec<usize>, String>>()?;
    let mut rows = Vec::new();
    for (lineno, line) in lines {
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != names.len() {
            return Err(format!(
                "line {lineno}: {} fields, the header has {}",
                fields.len(),
                names.len()
            ));
        }
        let mut row = Vec::with_capacity(idx.len());
        for (&k, c) in idx.iter().zip(cols) {
            let v: f64 = fields[k].parse().map_err(|_| {
                format!(
                    "line {lineno}: column {c}: cannot parse {:?} as a number",
                    fields[k]
                )
            })?;
            row.push(v);
        }
        rows.push(row);
    }
    if rows.is_empty() {
        return Err("no data rows".into());
    }
    Ok(rows)
}

/// Write rows under a header to `out`, numbers in shortest round-trip form.
pub fn write_rows(out: &mut dyn Write, header: &[&str], rows: &[[f64; 2]]) -> std::io::Result<()> {
    writeln!(out, "{}", header.join(","))?;
    for r in rows {
        writeln!(out, "{},{}", r[0], r[1])?;
    }
    Ok(())
}

/// Write `bytes` to `path` atomically (temporary file in the same directory, then rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), String> {
    let name = path.display();
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => std::path::PathBuf::from("."),
    };
    let file = path
        .file_name()
        .ok_or_else(|| format!("{name}: not a file path"))?;
    let tmp = dir.join(format!(
        ".{}.{}.tmp",
        file.to_string_lossy(),
        std::process::id()
    ));
    std::fs::write(&tmp, bytes).map_err(|e| format!("{name}: cannot write ({e})"))?;
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        format!("{name}: cannot write ({e})")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_named_columns_in_any_order() {
        let t = "# comment\ny,x\n1, 2\n\n3,4.5e1\n";
        let r = parse_columns(t, &["x", "y"]).unwrap();
        assert_eq!(r, vec![vec![2.0, 1.0], vec![45.0, 3.0]]);
    }

    #[test]
    fn errors_name_the_problem() {
        let e = parse_columns("x,z\n1,2\n", &["x", "y"]).unwrap_err();
        assert!(e.contains("missing column \"y\""), "{e}");
        let e = parse_columns("x,y\n1,abc\n", &["x", "y"]).unwrap_err();
        assert!(e.contains("line 2: column y"), "{e}");
        let e = parse_columns("x,y\n1\n", &["x", "y"]).unwrap_err();
        assert!(e.contains("line 2: 1 fields"), "{e}");
        assert!(parse_columns("x,y\n", &["x", "y"])
            .unwrap_err()
            .contains("no data"));
        assert!(parse_columns("", &["x"]).unwrap_err().contains("empty"));
    }
}
