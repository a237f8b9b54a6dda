//! "Did you mean" hints for misspelt keys and names (edit distance).

/// Levenshtein distance between two strings, by characters.
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut previous: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut current = vec![i + 1; b.len() + 1];
        for (j, cb) in b.iter().enumerate() {
            let substitution = previous[j] + usize::from(ca != *cb);
            current[j + 1] = substitution.min(previous[j + 1] + 1).min(current[j] + 1);
        }
        previous = current;
    }
    previous[b.len()]
}

/// The closest candidate within a third of the word's length (at least 2 edits).
/// A candidate that is the word plus a suffix after `_` counts as one edit: a
/// forgotten unit (`edge` for `edge_mm`, `timeout` for `timeout_s`).
pub fn closest<'a>(word: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let limit = (word.chars().count() / 3).max(2);
    let unit_dropped = |c: &str| {
        c.strip_prefix(word)
            .is_some_and(|rest| rest.starts_with('_') && !word.is_empty())
    };
    candidates
        .into_iter()
        .map(|c| {
            let d = if unit_dropped(c) {
                1
            } else {
                edit_distance(word, c)
            };
            (d, c)
        })
        .filter(|(d, _)| *d <= limit)
        .min_by_key(|(d, _)| *d)
        .map(|(_, c)| c)
}

/// `" (did you mean `x`?)"` or an empty string.
pub fn did_you_mean<'a>(word: &str, candidates: impl IntoIterator<Item = &'a str>) -> String {
    closest(word, candidates)
        .map(|c| format!(" (did you mean `{c}`?)"))
        .unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_forgotten_unit_suffix_is_suggested() {
        assert_eq!(closest("edge", ["edge_mm", "count"]), Some("edge_mm"));
        assert_eq!(
            closest("timeout", ["timeout_s", "retries"]),
            Some("timeout_s")
        );
    }

    #[test]
    fn distance_and_suggestion() {
        assert_eq!(edit_distance("kitten", "sitting"), 3);
        assert_eq!(
            closest("per_confg", ["per_config", "sigma_f"]),
            Some("per_config")
        );
        assert_eq!(closest("zzz", ["per_config"]), None);
    }
}
