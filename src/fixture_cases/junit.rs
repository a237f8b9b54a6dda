//! The JUnit XML report CI systems read (Jenkins, GitLab, GitHub test
//! reporters): one `<testsuite>` per stage kind, one `<testcase>` per case, a
//! `<failure>` for a case whose expectation failed and an `<error>` for a
//! malformed case file, with the stage's output attached.

use std::fmt::Write as _;

use super::run::{CaseResult, Outcome, Summary};

/// The report as XML text.
pub fn to_xml(summary: &Summary, timestamp: &str) -> String {
    let mut suites: std::collections::BTreeMap<&str, Vec<&CaseResult>> = Default::default();
    for result in &summary.results {
        suites
            .entry(result.kind.as_deref().unwrap_or("unknown"))
            .or_default()
            .push(result);
    }
    let mut xml = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    let _ = writeln!(
        xml,
        "<testsuites name=\"egcal test\" tests=\"{}\" failures=\"{}\" errors=\"{}\" time=\"{:.3}\" timestamp=\"{}\">",
        summary.results.len(),
        summary.failed(),
        summary.malformed(),
        summary.seconds,
        text(timestamp)
    );
    for (kind, cases) in &suites {
        let failures = cases
            .iter()
            .filter(|c| matches!(c.outcome, Outcome::Failed(_)))
            .count();
        let errors = cases
            .iter()
            .filter(|c| matches!(c.outcome, Outcome::Malformed(_)))
            .count();
        let seconds: f64 = cases.iter().map(|c| c.seconds).sum();
        let _ = writeln!(
            xml,
            "  <testsuite name=\"{}\" tests=\"{}\" failures=\"{failures}\" errors=\"{errors}\" skipped=\"0\" time=\"{seconds:.3}\" timestamp=\"{}\">",
            text(kind),
            cases.len(),
            text(timestamp)
        );
        for case in cases {
            testcase(&mut xml, kind, case);
        }
        xml.push_str("  </testsuite>\n");
    }
    xml.push_str("</testsuites>\n");
    xml
}

fn testcase(xml: &mut String, kind: &str, case: &CaseResult) {
    let _ = write!(
        xml,
        "    <testcase name=\"{}\" classname=\"{}\" file=\"{}/case.toml\" time=\"{:.3}\"",
        text(&case.name),
        text(kind),
        text(&case.name),
        case.seconds
    );
    let (element, kind_of, detail) = match &case.outcome {
        Outcome::Passed if case.recorded => {
            xml.push_str(">\n      <properties><property name=\"recorded\" value=\"regression case recorded from egcal\"/></properties>\n    </testcase>\n");
            return;
        }
        Outcome::Passed => {
            xml.push_str("/>\n");
            return;
        }
        Outcome::Failed(why) => ("failure", "mismatch", why.clone()),
        Outcome::Malformed(e) => ("error", "malformed case file", e.to_string()),
    };
    let first_line = detail.lines().next().unwrap_or_default();
    let _ = writeln!(
        xml,
        ">\n      <{element} message=\"{}\" type=\"{kind_of}\">{}</{element}>",
        text(first_line),
        text(&detail)
    );
    for (tag, output) in [("system-out", &case.stdout), ("system-err", &case.stderr)] {
        if !output.is_empty() {
            let _ = writeln!(xml, "      <{tag}>{}</{tag}>", text(output));
        }
    }
    xml.push_str("    </testcase>\n");
}

/// Escaped XML text; characters XML 1.0 forbids (terminal control codes in a
/// stage's output) become U+FFFD.
fn text(raw: &str) -> String {
    let allowed: String = raw
        .chars()
        .map(|c| match c {
            '\t' | '\n' | '\r' => c,
            c if (c as u32) < 0x20 || c == '\u{FFFE}' || c == '\u{FFFF}' => '\u{FFFD}',
            c => c,
        })
        .collect();
    crate::export::urdf::escape(&allowed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixture_cases::case::Malformed;

    fn result(name: &str, outcome: Outcome) -> CaseResult {
        CaseResult {
            name: name.into(),
            kind: Some("identify".into()),
            recorded: false,
            outcome,
            seconds: 0.5,
            stdout: "a\u{1b}[1m <b>".into(),
            stderr: String::new(),
        }
    }

    #[test]
    fn failures_and_errors_are_counted_and_escaped() {
        let summary = Summary {
            results: vec![
                result("f/identify/ok", Outcome::Passed),
                result(
                    "f/identify/bad",
                    Outcome::Failed("x < y & \"z\"\nmore".into()),
                ),
                result(
                    "f/identify/typo",
                    Outcome::Malformed(Malformed {
                        file: "f/identify/typo/case.toml".into(),
                        line: Some(3),
                        key: "expect.tolerence".into(),
                        message: "unknown field".into(),
                    }),
                ),
            ],
            seconds: 1.5,
        };
        let xml = to_xml(&summary, "2026-12-02T10:00:00");
        assert!(
            xml.contains("tests=\"3\" failures=\"1\" errors=\"1\""),
            "{xml}"
        );
        assert!(
            xml.contains("<failure message=\"x &lt; y &amp; &quot;z&quot;\" type=\"mismatch\">"),
            "{xml}"
        );
        assert!(xml.contains("line 3, key `expect.tolerence`"), "{xml}");
        assert!(
            xml.contains("<system-out>a\u{FFFD}[1m &lt;b&gt;</system-out>"),
            "{xml}"
        );
        assert!(!xml.contains('\u{1b}'));
    }
}
