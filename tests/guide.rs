//! The user guide's walkthroughs run as written. Every ```console block of
//! `README.md` and of the pages `docs/SUMMARY.md` lists is run, page by page in
//! the guide's order, each command (`$ …`) through `sh` in a fresh copy of the
//! repository's `jobs/` and `fixtures/` (a page starts from its own state; its
//! blocks share it in order), with the test build's `egcal` first on `PATH`.
//! Its output (stdout and stderr together) must match the lines shown under it:
//! `...` alone on a line stands for any lines, `[..]` for any text within a line;
//! a command shown without output is only required to exit 0. A command meant
//! to fail shows its exit code itself (`…; echo "exit $?"`).
//!
//! Also: every relative link of the guide, the README and the notes for
//! contributors leads to a file that exists, and every `#anchor` to a heading.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The guide's pages in reading order: the README, then `docs/SUMMARY.md`'s links.
fn pages() -> Vec<PathBuf> {
    let summary = std::fs::read_to_string(root().join("docs/SUMMARY.md")).expect("docs/SUMMARY.md");
    let mut pages = vec![root().join("README.md")];
    for (target, _) in links(&summary) {
        let page = root().join("docs").join(&target);
        if !pages.contains(&page) {
            pages.push(page);
        }
    }
    pages
}

/// `[text](target)` links of a Markdown text outside code blocks and spans,
/// with their line numbers.
fn links(text: &str) -> Vec<(String, usize)> {
    let mut found = Vec::new();
    let mut in_code = false;
    for (number, line) in text.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
            continue;
        }
        if in_code {
            continue;
        }
        // Drop inline code spans: `[a](b)` inside backticks is not a link.
        let prose: String = line.split('`').step_by(2).collect::<Vec<_>>().join(" ");
        let mut rest = prose.as_str();
        while let Some(at) = rest.find("](") {
            rest = &rest[at + 2..];
            if let Some(end) = rest.find(')') {
                found.push((rest[..end].to_string(), number + 1));
                rest = &rest[end..];
            }
        }
    }
    found
}

/// GitHub's anchor of a heading: lower case, punctuation dropped, spaces to `-`.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || *c == '-' || *c == '_' || *c == ' ')
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

fn anchors(text: &str) -> Vec<String> {
    let mut in_code = false;
    let mut found = Vec::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_code = !in_code;
        } else if !in_code && line.starts_with('#') {
            found.push(anchor(line.trim_start_matches('#')));
        }
    }
    found
}

/// One command of a console block and the output lines shown under it.
#[derive(Debug)]
struct Step {
    line: usize,
    command: String,
    expected: Vec<String>,
}

/// The ```console blocks' commands: `$ ` starts one, a trailing `\` continues it.
fn steps(text: &str) -> Vec<Step> {
    let mut steps: Vec<Step> = Vec::new();
    let mut in_console = false;
    let mut in_other = false;
    let mut continuing = false;
    for (number, line) in text.lines().enumerate() {
        let fence = line.trim_start().starts_with("```");
        if fence && !in_console && !in_other {
            in_console = line.trim_start().trim_start_matches('`').trim() == "console";
            in_other = !in_console;
            continue;
        }
        if fence {
            in_console = false;
            in_other = false;
            continuing = false;
            continue;
        }
        if !in_console {
            continue;
        }
        if continuing {
            let step = steps.last_mut().expect("a step");
            step.command.push('\n');
            step.command.push_str(line);
            continuing = line.ends_with('\\');
        } else if let Some(command) = line.strip_prefix("$ ") {
            steps.push(Step {
                line: number + 1,
                command: command.to_string(),
                expected: Vec::new(),
            });
            continuing = line.ends_with('\\');
        } else if let Some(step) = steps.last_mut() {
            step.expected.push(line.trim_end().to_string());
        }
    }
    steps
}

/// `actual` against `expected`: `[..]` matches any text within a line.
fn line_matches(expected: &str, actual: &str) -> bool {
    let mut parts = expected.split("[..]");
    let first = parts.next().unwrap_or_default();
    let Some(mut rest) = actual.strip_prefix(first) else {
        return false;
    };
    let parts: Vec<&str> = parts.collect();
    for (k, part) in parts.iter().enumerate() {
        if k + 1 == parts.len() {
            return rest.ends_with(part);
        }
        match rest.find(part) {
            Some(at) => rest = &rest[at + part.len()..],
            None => return false,
        }
    }
    rest.is_empty()
}

/// Whether `actual` lines match `expected`, where a `...` line matches any
/// number of lines (tried shortest first).
fn output_matches(expected: &[String], actual: &[&str]) -> bool {
    match expected.split_first() {
        None => actual.is_empty(),
        Some((first, rest)) if first == "..." => {
            (0..=actual.len()).any(|skip| output_matches(rest, &actual[skip..]))
        }
        Some((first, rest)) => actual
            .split_first()
            .is_some_and(|(line, more)| line_matches(first, line) && output_matches(rest, more)),
    }
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).expect("create folder");
    for entry in std::fs::read_dir(from).expect("read folder") {
        let entry = entry.expect("entry");
        let name = entry.file_name();
        // A developer's own runs of the jobs are not part of the guide's state.
        if name == "out" || name == ".egcal" {
            continue;
        }
        let path = entry.path();
        if path.is_dir() {
            copy_tree(&path, &to.join(&name));
        } else {
            std::fs::copy(&path, to.join(&name)).expect("copy file");
        }
    }
}

/// Runs one page's commands in its own copy; the problems found.
fn run_page(page: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(page).expect("read page");
    let steps = steps(&text);
    if steps.is_empty() {
        return Vec::new();
    }
    let sandbox = tempfile::tempdir().expect("temp dir");
    let checkout = sandbox.path().join("egcal");
    for folder in ["jobs", "fixtures"] {
        copy_tree(&root().join(folder), &checkout.join(folder));
    }
    // Jobs name the real data as `../../shared/…`, beside the checkout.
    let shared = root().join("../shared");
    if shared.is_dir() {
        std::os::unix::fs::symlink(&shared, sandbox.path().join("shared")).expect("link shared");
    }
    let binary = PathBuf::from(env!("CARGO_BIN_EXE_egcal"));
    let path = format!(
        "{}:{}",
        binary.parent().expect("bin folder").display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let name = page
        .strip_prefix(root())
        .unwrap_or(page)
        .display()
        .to_string();
    let mut problems = Vec::new();
    for step in steps {
        let output = Command::new("sh")
            .arg("-c")
            .arg(format!("{{\n{}\n}} 2>&1", step.command))
            .current_dir(&checkout)
            .env("PATH", &path)
            .output()
            .expect("run sh");
        let stdout = String::from_utf8_lossy(&output.stdout);
        let actual: Vec<&str> = stdout.lines().map(str::trim_end).collect();
        let shown = !step.expected.is_empty();
        if !output.status.success() {
            problems.push(format!(
                "{name}:{}: `{}` exited {:?}:\n{stdout}",
                step.line,
                step.command,
                output.status.code()
            ));
        } else if shown && !output_matches(&step.expected, &actual) {
            problems.push(format!(
                "{name}:{}: `{}` printed\n{stdout}\nwhere the guide shows\n{}",
                step.line,
                step.command,
                step.expected.join("\n")
            ));
        }
    }
    problems
}

#[test]
fn every_console_block_of_the_guide_runs_as_written() {
    // The walkthroughs of real cells read the UR10 data beside the checkout.
    if !root().join("../shared/realdata").is_dir() {
        eprintln!("SKIPPED: ../shared/realdata is missing; the guide's walkthroughs need it");
        return;
    }
    let pages = pages();
    let problems: Vec<String> = std::thread::scope(|scope| {
        let runs: Vec<_> = pages
            .iter()
            .map(|page| scope.spawn(move || run_page(page)))
            .collect();
        runs.into_iter()
            .flat_map(|run| run.join().expect("page thread"))
            .collect()
    });
    assert!(problems.is_empty(), "{}", problems.join("\n\n"));
}

#[test]
fn every_relative_link_leads_to_a_file_and_a_heading() {
    let mut documents = pages();
    documents.extend(["ARCHITECTURE.md", "DESIGN.md", "docs/SUMMARY.md"].map(|f| root().join(f)));
    let mut problems = Vec::new();
    for document in &documents {
        let text = std::fs::read_to_string(document).expect("read page");
        let name = document
            .strip_prefix(root())
            .unwrap_or(document)
            .display()
            .to_string();
        for (target, line) in links(&text) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let (file, fragment) = target.split_once('#').unwrap_or((&target, ""));
            let file_path = if file.is_empty() {
                document.clone()
            } else {
                document.parent().expect("folder").join(file)
            };
            if !file_path.exists() {
                problems.push(format!(
                    "{name}:{line}: `{target}`: no file {}",
                    file_path.display()
                ));
                continue;
            }
            if !fragment.is_empty() {
                let target_text = std::fs::read_to_string(&file_path).unwrap_or_default();
                if !anchors(&target_text).iter().any(|a| a == fragment) {
                    problems.push(format!(
                        "{name}:{line}: `{target}`: no heading with anchor #{fragment}"
                    ));
                }
            }
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn the_matcher_takes_wildcards_and_skipped_lines() {
    assert!(line_matches("mean [..] mm", "mean 0.099 mm"));
    assert!(!line_matches("mean [..] mm", "mean 0.099 m"));
    assert!(line_matches("exit 0", "exit 0"));
    assert!(!line_matches("exit 0", "exit 0 and more"));
    let expected: Vec<String> = ["a", "...", "d"].map(String::from).to_vec();
    assert!(output_matches(&expected, &["a", "b", "c", "d"]));
    assert!(output_matches(&expected, &["a", "d"]));
    assert!(!output_matches(&expected, &["a", "b"]));
    let text = "```console\n$ egcal run \\\n  x.toml\nok\n```\n```sh\n$ not run\n```\n";
    let found = steps(text);
    assert_eq!(found.len(), 1);
    assert_eq!(found[0].command, "egcal run \\\n  x.toml");
    assert_eq!(found[0].expected, ["ok"]);
    assert_eq!(
        anchor("The report: \"is my calibration good?\""),
        "the-report-is-my-calibration-good"
    );
}
