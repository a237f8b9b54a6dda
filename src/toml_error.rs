//! Turns TOML parser and deserializer errors into one-line messages with a line
//! number, so job-file and robot-file errors read the same way everywhere.

/// 1-based line and column of a byte offset in `text`.
pub fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.len() - before.rfind('\n').map_or(0, |i| i + 1) + 1;
    (line, column)
}

/// "line L, column C" for an error that carries a span, "location unknown" otherwise.
pub fn location(err: &toml::de::Error, text: &str) -> String {
    match err.span() {
        Some(span) => {
            let (line, column) = line_column(text, span.start);
            format!("line {line}, column {column}")
        }
        None => "location unknown".to_string(),
    }
}

/// The error's message followed by its location.
pub fn describe(err: &toml::de::Error, text: &str) -> String {
    format!("{} at {}", err.message().trim(), location(err, text))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_and_column_are_one_based() {
        let text = "a = 1\nbb = 2\n";
        assert_eq!(line_column(text, 0), (1, 1));
        assert_eq!(line_column(text, 6), (2, 1));
        assert_eq!(line_column(text, 9), (2, 4));
    }
}
