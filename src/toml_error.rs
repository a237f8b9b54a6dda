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

/// Why a strictly parsed TOML file was rejected.
#[derive(Debug, Clone, PartialEq)]
pub enum StrictError {
    /// Not TOML at all: message with its location.
    Syntax(String),
    /// TOML, but a key is unknown, missing or of the wrong type.
    Invalid { key: String, message: String },
}

/// Deserialises `text` into `T`, naming the key path and line of the first problem.
pub fn from_str_strict<T: serde::de::DeserializeOwned>(text: &str) -> Result<T, StrictError> {
    let de =
        toml::de::Deserializer::parse(text).map_err(|e| StrictError::Syntax(describe(&e, text)))?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let key = e.path().to_string();
        let inner = e.into_inner();
        StrictError::Invalid {
            message: format!("{} ({})", inner.message(), location(&inner, text)),
            key,
        }
    })
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
