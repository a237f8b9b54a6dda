//! The text of a delimited export as tracker software writes it, made plain for
//! polars' reader: the encoding decoded (UTF-8 with or without a byte-order
//! mark, UTF-16 with one; other bytes that are not UTF-8 read as Latin-1),
//! CRLF, LF or CR line ends, the preamble (`skip_rows`) and blank lines left
//! out, a units row under the header recognised and checked against the unit
//! settings, header names trimmed and checked for duplicates, and every record
//! written again with its cells trimmed. Each data row keeps the 1-based file
//! line it started on, for messages.
//!
//! The units row: with a header, the first non-blank line after it is a units
//! row (and not data) when no mapped numeric column holds a number there and at
//! least one holds a unit egcal knows (`mm`, `[mm]`, `(deg)`, `°`, `rad`, `m`,
//! `N`, `N·m`, …). A known unit there, or in brackets at the end of a mapped
//! header name (`X [mm]`), that contradicts the column's unit setting is refused.

use std::borrow::Cow;
use std::path::Path;

use super::{CsvLayout, JointUnit, Kind, LengthUnit, Mapped, MomentUnit, StageError};

/// The export as polars reads it, and where each data row came from.
pub struct Plain {
    /// Header (when the layout has one) and data records, `\n`-terminated.
    pub text: String,
    /// The 1-based file line each data row starts on.
    pub lines: Vec<usize>,
    /// What the log should say about the file (a units row skipped; and, as
    /// `warning: …`, an encoding guessed or an unused duplicate column name).
    pub notes: Vec<String>,
}

/// `bytes` as text: the encoding decided, or refused with the reason.
pub fn decode<'b>(
    file: &Path,
    bytes: &'b [u8],
) -> Result<(Cow<'b, str>, Option<String>), StageError> {
    let refuse = |why: String| StageError::Invalid(format!("{}: {why}", file.display()));
    if let Some(rest) = bytes.strip_prefix(b"\xEF\xBB\xBF") {
        return match std::str::from_utf8(rest) {
            Ok(text) => Ok((Cow::Borrowed(text), None)),
            Err(e) => Err(refuse(format!(
                "starts with a UTF-8 byte-order mark but is not UTF-8 (byte {} is not): save it as UTF-8",
                e.valid_up_to() + 3
            ))),
        };
    }
    for (bom, name, big_endian) in [
        (&b"\xFF\xFE"[..], "UTF-16 LE", false),
        (&b"\xFE\xFF"[..], "UTF-16 BE", true),
    ] {
        if let Some(rest) = bytes.strip_prefix(bom) {
            if rest.len() % 2 != 0 {
                return Err(refuse(format!(
                    "starts with a {name} byte-order mark but has an odd number of bytes: not whole {name} text; save it as UTF-8"
                )));
            }
            let units = rest.chunks_exact(2).map(|pair| {
                if big_endian {
                    u16::from_be_bytes([pair[0], pair[1]])
                } else {
                    u16::from_le_bytes([pair[0], pair[1]])
                }
            });
            let text: Result<String, _> = char::decode_utf16(units).collect();
            return match text {
                Ok(text) => Ok((
                    Cow::Owned(text),
                    Some(format!("read as {name} (its byte-order mark)")),
                )),
                Err(_) => Err(refuse(format!(
                    "starts with a {name} byte-order mark but is not valid {name}: save it as UTF-8"
                ))),
            };
        }
    }
    if bytes.starts_with(b"PAR1") {
        return Err(refuse(
            "is a Parquet file, not delimited text: set `format = \"parquet\"` (or name it .parquet)".into(),
        ));
    }
    if bytes.starts_with(b"PK\x03\x04") {
        return Err(refuse(
            "is a zip archive (an Excel workbook?), not delimited text: export the sheet as CSV"
                .into(),
        ));
    }
    if let Some(at) = bytes.iter().take(4096).position(|b| *b == 0) {
        return Err(refuse(format!(
            "has a NUL byte at byte {at}: UTF-16 text without a byte-order mark, or not text at all; save it as UTF-8 (egcal reads UTF-8, UTF-16 with a byte-order mark, and Latin-1)"
        )));
    }
    match std::str::from_utf8(bytes) {
        Ok(text) => Ok((Cow::Borrowed(text), None)),
        Err(e) => {
            let at = e.valid_up_to();
            Ok((
                Cow::Owned(bytes.iter().map(|b| char::from(*b)).collect()),
                Some(format!(
                    "warning: not UTF-8 (byte {at} is not): read as Latin-1 (ISO 8859-1); save it as UTF-8 if its names or texts look wrong"
                )),
            ))
        }
    }
}

/// One record of the file: where it starts and its text (no line end).
struct Record<'t> {
    line: usize,
    text: &'t str,
}

/// The records of `text` (quote-aware: a quoted cell may hold line breaks),
/// the first on line `first_line`. CRLF, LF and a lone CR end a line.
fn records<'t>(
    file: &Path,
    text: &'t str,
    separator: char,
    first_line: usize,
) -> Result<Vec<Record<'t>>, StageError> {
    #[derive(PartialEq)]
    enum State {
        FieldStart,
        Unquoted,
        Quoted,
        QuoteInQuoted,
    }
    let mut out = Vec::new();
    let mut state = State::FieldStart;
    let mut line = first_line;
    let mut start = 0;
    let mut record_line = first_line;
    let mut quote_line = first_line;
    let mut chars = text.char_indices().peekable();
    while let Some((i, c)) = chars.next() {
        let line_end = c == '\n' || c == '\r';
        if line_end {
            // CRLF is one line end.
            if c == '\r' && chars.peek().is_some_and(|(_, n)| *n == '\n') {
                chars.next();
            }
            line += 1;
        }
        match state {
            State::Quoted => {
                if c == '"' {
                    state = State::QuoteInQuoted;
                }
                continue;
            }
            State::QuoteInQuoted if c == '"' => {
                state = State::Quoted;
                continue;
            }
            _ => {}
        }
        if line_end {
            out.push(Record {
                line: record_line,
                text: &text[start..i],
            });
            start = chars.peek().map_or(text.len(), |(j, _)| *j);
            record_line = line;
            state = State::FieldStart;
        } else if c == separator {
            state = State::FieldStart;
        } else if c == '"' && state == State::FieldStart {
            state = State::Quoted;
            quote_line = line;
        } else if !(state == State::FieldStart && c.is_whitespace()) {
            // Spaces before a cell's opening quote keep it a quoted cell.
            state = State::Unquoted;
        }
    }
    if state == State::Quoted {
        return Err(StageError::Invalid(format!(
            "{}: line {quote_line}: a quoted cell opens here and is never closed (a `\"` missing?)",
            file.display()
        )));
    }
    if start < text.len() {
        out.push(Record {
            line: record_line,
            text: &text[start..],
        });
    }
    Ok(out)
}

/// The cells of one record, unquoted (`""` in a quoted cell is one `"`) and trimmed.
fn cells(record: &str, separator: char) -> Vec<String> {
    let mut out = Vec::new();
    let mut cell = String::new();
    let mut quoted = false;
    let mut chars = record.chars().peekable();
    // Whether this cell's quoted part was opened (and closed) already.
    let mut opened = false;
    while let Some(c) = chars.next() {
        if quoted {
            if c == '"' {
                if chars.peek() == Some(&'"') {
                    chars.next();
                    cell.push('"');
                } else {
                    quoted = false;
                }
            } else {
                cell.push(c);
            }
        } else if c == separator {
            out.push(std::mem::take(&mut cell).trim().to_string());
            opened = false;
        } else if c == '"' && !opened && cell.trim().is_empty() {
            // Spaces before the opening quote are not part of the cell.
            cell.clear();
            quoted = true;
            opened = true;
        } else {
            cell.push(c);
        }
    }
    out.push(cell.trim().to_string());
    out
}

/// A cell written back for polars: quoted when it holds the separator, a quote or a line break.
fn write_cell(out: &mut String, cell: &str, separator: char) {
    if cell.contains([separator, '"', '\n', '\r']) {
        out.push('"');
        out.push_str(&cell.replace('"', "\"\""));
        out.push('"');
    } else {
        out.push_str(cell);
    }
}

fn is_blank(record: &str) -> bool {
    record.trim().is_empty()
}

/// A unit as egcal names it, from a cell or a bracketed header suffix
/// (`mm`, `[mm]`, `(deg)`, `°`), or `None` for text that is no unit it knows.
fn unit_of(token: &str) -> Option<&'static str> {
    let t = token.trim();
    let t = t
        .strip_prefix(['[', '(', '{', '<'])
        .and_then(|s| s.strip_suffix([']', ')', '}', '>']))
        .unwrap_or(t)
        .trim();
    let lower = t.to_lowercase().replace(['·', '*', '.', ' '], "");
    Some(match lower.as_str() {
        "°" | "deg" | "degree" | "degrees" => "deg",
        "rad" | "radian" | "radians" => "rad",
        "mm" | "millimeter" | "millimeters" | "millimetre" | "millimetres" => "mm",
        "m" | "meter" | "meters" | "metre" | "metres" => "m",
        "cm" => "cm",
        "µm" | "μm" | "um" => "µm",
        "in" | "inch" | "inches" | "\"" => "in",
        "ft" => "ft",
        "n" => "N",
        "kn" => "kN",
        "lbf" => "lbf",
        "nm" => "N·m",
        "nmm" => "N·mm",
        "knm" => "kN·m",
        _ => return None,
    })
}

/// The unit a mapped numeric column's source values are in, and the setting
/// that says so; `None` for columns without a unit.
fn expected_unit(
    kind: Kind,
    layout: &CsvLayout,
) -> Option<(&'static str, &'static str, &'static [&'static str])> {
    let angle = |unit: JointUnit| match unit {
        JointUnit::Deg => "deg",
        JointUnit::Rad => "rad",
    };
    const ANGLES: &[&str] = &["deg", "rad"];
    const LENGTHS: &[&str] = &["mm", "m"];
    Some(match kind {
        Kind::Joint => (angle(layout.units.joint), "joint_unit", ANGLES),
        Kind::Angle | Kind::AngleSigma => (angle(layout.units.angle), "angle_unit", ANGLES),
        Kind::Position | Kind::Sigma => (
            match layout.units.length {
                LengthUnit::Mm => "mm",
                LengthUnit::M => "m",
            },
            "length_unit",
            LENGTHS,
        ),
        Kind::Force => ("N", "force_unit", &["N"]),
        Kind::Moment => (
            match layout.units.moment {
                MomentUnit::NewtonMetre => "N·m",
                MomentUnit::NewtonMillimetre => "N·mm",
            },
            "moment_unit",
            &["N·m", "N·mm"],
        ),
        Kind::Integer | Kind::Text | Kind::Time => return None,
    })
}

/// Why `unit` (read off the file `where`) does not fit mapped column `m`, if it does not.
fn unit_conflict(
    unit: &str,
    m: &Mapped,
    layout: &CsvLayout,
    file: &Path,
    place: &str,
) -> Option<StageError> {
    let (expected, setting, allowed) = expected_unit(m.kind, layout)?;
    if unit == expected {
        return None;
    }
    let fix = if allowed.contains(&unit) {
        format!("set `{setting} = \"{unit}\"`")
    } else {
        format!(
            "the column is mapped to `columns.{}`, which egcal reads in {} only: check the column map, or convert the column",
            m.contract,
            allowed.join(" or ")
        )
    };
    Some(StageError::Invalid(format!(
        "{}: {place} gives `{unit}` for column `{}` (setting `columns.{}`), but setting `{setting}` = \"{expected}\": {fix}",
        file.display(),
        m.source,
        m.contract
    )))
}

fn is_number(cell: &str, decimal_comma: bool) -> bool {
    let cell = cell.trim();
    if decimal_comma {
        cell.replace(',', ".").parse::<f64>().is_ok()
    } else {
        cell.parse::<f64>().is_ok()
    }
}

/// The export's text made plain for polars (see the module doc).
pub fn plain(
    file: &Path,
    text: &str,
    layout: &CsvLayout,
    mapped: &[Mapped],
) -> Result<Plain, StageError> {
    let separator = char::from(layout.separator);
    let mut notes = Vec::new();
    // The preamble: `skip_rows` physical lines, whatever they hold.
    let mut rest = text;
    let mut line = 1;
    for _ in 0..layout.skip_rows {
        match rest.find(['\n', '\r']) {
            None => {
                rest = "";
                break;
            }
            Some(i) => {
                let skip = if rest[i..].starts_with("\r\n") { 2 } else { 1 };
                rest = &rest[i + skip..];
                line += 1;
            }
        }
    }
    let all = records(file, rest, separator, line)?;
    let mut iter = all.into_iter().filter(|r| !is_blank(r.text)).peekable();
    let mut out = String::with_capacity(text.len());
    let mut header: Option<Vec<String>> = None;
    if layout.has_header {
        let Some(record) = iter.next() else {
            return Err(StageError::Invalid(format!(
                "{}: has no header line{}",
                file.display(),
                if layout.skip_rows > 0 {
                    format!(" after the {} lines `skip_rows` skips", layout.skip_rows)
                } else {
                    String::new()
                }
            )));
        };
        let mut names = cells(record.text, separator);
        if let [only] = names.as_slice()
            && !mapped.iter().any(|m| m.source == *only)
            && let Some(other) = [';', ',', '\t', '|']
                .into_iter()
                .find(|c| *c != separator && only.contains(*c))
        {
            return Err(StageError::Invalid(format!(
                "{}: line {}: the header reads as one column `{only}` with separator {separator:?}, and holds {other:?}: set `separator = {:?}`{}",
                file.display(),
                record.line,
                other.to_string(),
                if other != ',' && text.contains(',') {
                    " (and `decimal_comma = true` if its numbers are written like `1,5`)"
                } else {
                    ""
                }
            )));
        }
        for (i, name) in names.iter_mut().enumerate() {
            if name.is_empty() {
                *name = format!("column_{}", i + 1);
            }
        }
        // Duplicate names: refused when a setting reads the name, else noted.
        let mut seen: Vec<(String, usize)> = Vec::new();
        for (i, slot) in names.iter_mut().enumerate() {
            let name = slot.clone();
            if let Some((_, first)) = seen.iter().find(|(n, _)| *n == name) {
                if let Some(m) = mapped.iter().find(|m| m.source == name) {
                    return Err(StageError::Invalid(format!(
                        "{}: line {}: the header names columns {} and {} both `{name}`, and setting `columns.{}` reads that name: rename one of them in the file",
                        file.display(),
                        record.line,
                        first + 1,
                        i + 1,
                        m.contract
                    )));
                }
                notes.push(format!(
                    "warning: {}: line {}: columns {} and {} are both named `{name}`; no setting reads it, so both are left out",
                    file.display(),
                    record.line,
                    first + 1,
                    i + 1
                ));
                *slot = format!("{name} (column {})", i + 1);
            } else {
                seen.push((name, i));
            }
        }
        // A unit in brackets at the end of a mapped header name.
        for m in mapped {
            if let Some(name) = names.iter().find(|n| **n == m.source)
                && let Some(open) = name.rfind(['[', '('])
                && let Some(unit) = unit_of(&name[open..])
                && let Some(e) = unit_conflict(
                    unit,
                    m,
                    layout,
                    file,
                    &format!("line {}: the header name", record.line),
                )
            {
                return Err(e);
            }
        }
        // The units row.
        if let Some(next) = iter.peek() {
            let row = cells(next.text, separator);
            let numeric: Vec<(&Mapped, &str)> = mapped
                .iter()
                .filter(|m| expected_unit(m.kind, layout).is_some())
                .filter_map(|m| {
                    let i = names.iter().position(|n| *n == m.source)?;
                    Some((m, row.get(i).map_or("", String::as_str)))
                })
                .collect();
            let has_unit = numeric.iter().any(|(_, c)| unit_of(c).is_some());
            let has_number = numeric
                .iter()
                .any(|(_, c)| is_number(c, layout.decimal_comma));
            if has_unit && !has_number {
                let units_line = next.line;
                for (m, cell) in &numeric {
                    if let Some(unit) = unit_of(cell)
                        && let Some(e) = unit_conflict(
                            unit,
                            m,
                            layout,
                            file,
                            &format!("line {units_line} (the units row under the header)"),
                        )
                    {
                        return Err(e);
                    }
                }
                notes.push(format!(
                    "{}: line {units_line} is a units row, not data: skipped",
                    file.display()
                ));
                iter.next();
            }
        }
        for (i, name) in names.iter().enumerate() {
            if i > 0 {
                out.push(separator);
            }
            write_cell(&mut out, name, separator);
        }
        out.push('\n');
        header = Some(names);
    }
    let mut data: Vec<Record> = iter.collect();
    // Rows of nothing but separators at the end (a spreadsheet's formatted, empty rows).
    while data
        .last()
        .is_some_and(|r| r.text.chars().all(|c| c == separator || c.is_whitespace()))
    {
        data.pop();
    }
    let width = header.as_ref().map(Vec::len);
    let mut lines = Vec::with_capacity(data.len());
    for record in data {
        let mut row = cells(record.text, separator);
        if let Some(width) = width {
            if row.len() > width {
                if row[width..].iter().all(String::is_empty) {
                    row.truncate(width);
                } else {
                    return Err(StageError::Invalid(format!(
                        "{}: line {}: {} cells, but the header names {width} columns (is `separator` {:?} right, or a quote missing?)",
                        file.display(),
                        record.line,
                        row.len(),
                        separator
                    )));
                }
            }
            row.resize(width, String::new());
        }
        for (i, cell) in row.iter().enumerate() {
            if i > 0 {
                out.push(separator);
            }
            write_cell(&mut out, cell, separator);
        }
        out.push('\n');
        lines.push(record.line);
    }
    Ok(Plain {
        text: out,
        lines,
        notes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::import_source::SourceUnits;

    fn layout(separator: u8) -> CsvLayout {
        CsvLayout {
            separator,
            decimal_comma: false,
            skip_rows: 0,
            has_header: true,
            units: SourceUnits::default(),
        }
    }

    fn mapped(pairs: &[(&'static str, Kind, &str)]) -> Vec<Mapped> {
        pairs
            .iter()
            .map(|(contract, kind, source)| Mapped {
                contract,
                kind: *kind,
                source: source.to_string(),
            })
            .collect()
    }

    #[test]
    fn utf16_with_a_byte_order_mark_is_decoded_and_latin1_is_read() {
        let file = Path::new("e.csv");
        let text = "x,y\r\n1,2\r\n";
        let mut le = vec![0xFF, 0xFE];
        let mut be = vec![0xFE, 0xFF];
        for unit in text.encode_utf16() {
            le.extend(unit.to_le_bytes());
            be.extend(unit.to_be_bytes());
        }
        for bytes in [le, be] {
            let (decoded, note) = decode(file, &bytes).unwrap();
            assert_eq!(decoded, text);
            assert!(note.unwrap().contains("UTF-16"));
        }
        // Latin-1 `°` (0xB0) in a header name.
        let (decoded, note) = decode(file, b"T [\xB0C],x\n1,2\n").unwrap();
        assert_eq!(decoded, "T [°C],x\n1,2\n");
        assert!(note.unwrap().starts_with("warning: not UTF-8"));
        // UTF-16 without a byte-order mark: refused, naming the encoding.
        let message = decode(file, b"x\0,\0y\0").unwrap_err().to_string();
        assert!(
            message.contains("UTF-16") && message.contains("e.csv"),
            "{message}"
        );
        let message = decode(file, b"PAR1\0\0").unwrap_err().to_string();
        assert!(message.contains("format = \"parquet\""), "{message}");
    }

    #[test]
    fn blank_lines_units_rows_and_quotes_keep_the_file_lines() {
        let file = Path::new("e.csv");
        let m = mapped(&[
            ("x_mm", Kind::Position, "X [mm]"),
            ("q1_deg", Kind::Joint, "a1"),
        ]);
        let text = "\"X [mm]\" , a1\r\n[mm],(°)\r\n\r\n 1.5 ,\"2\"\r\n  \"3\" ,\"4\nstill 4\"\r\n5,6\r\n\r\n,\r\n\r\n";
        let plain = plain(file, text, &layout(b','), &m).unwrap();
        assert_eq!(plain.text, "X [mm],a1\n1.5,2\n3,\"4\nstill 4\"\n5,6\n");
        assert_eq!(plain.lines, [4, 5, 7]);
        assert!(
            plain.notes[0].contains("line 2 is a units row"),
            "{:?}",
            plain.notes
        );
        // A row of numbers is data, never a units row.
        let plain = plain_of(file, "X [mm],a1\n1,2\n", &m);
        assert_eq!(plain.lines, [2]);
    }

    fn plain_of(file: &Path, text: &str, m: &[Mapped]) -> Plain {
        plain(file, text, &layout(b','), m).unwrap()
    }

    #[test]
    fn units_that_contradict_the_settings_and_duplicate_names_are_refused() {
        let file = Path::new("e.csv");
        let m = mapped(&[("x_mm", Kind::Position, "X"), ("q1_deg", Kind::Joint, "A1")]);
        let refused = |text: &str| {
            plain(file, text, &layout(b','), &m)
                .err()
                .unwrap()
                .to_string()
        };
        let message = refused("X,A1\nm,deg\n1,2\n");
        assert!(
            message.contains("line 2") && message.contains("length_unit = \"m\""),
            "{message}"
        );
        let message = refused("X,A1\nmm,mm\n1,2\n");
        assert!(
            message.contains("columns.q1_deg") && message.contains("deg or rad"),
            "{message}"
        );
        let m2 = mapped(&[("x_mm", Kind::Position, "X [m]")]);
        let message = plain(file, "X [m]\n1\n", &layout(b','), &m2)
            .err()
            .unwrap()
            .to_string();
        assert!(
            message.contains("header name") && message.contains("length_unit"),
            "{message}"
        );
        let message = refused("X,A1,X\n1,2,3\n");
        assert!(
            message.contains("columns 1 and 3")
                && message.contains("`X`")
                && message.contains("columns.x_mm"),
            "{message}"
        );
        // A duplicate no setting reads is a warning only.
        let plain = plain_of(file, "X,A1,t,t\n1,2,3,4\n", &m);
        assert!(
            plain.notes[0].starts_with("warning:") && plain.notes[0].contains("columns 3 and 4")
        );
        let message = refused("X;A1\n1,5;2\n");
        assert!(
            message.contains("separator = \";\"") && message.contains("decimal_comma"),
            "{message}"
        );
        let message = refused("X,A1\n1,\"2\n");
        assert!(
            message.contains("line 2") && message.contains("never closed"),
            "{message}"
        );
    }
}
