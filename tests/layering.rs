//! ARCHITECTURE.md's module table is bottom to top: a module may use only the
//! modules listed before it. This test reads the table and every `crate::` path
//! in `src/`, so a new import from a layer above fails here, not in review.

use std::collections::HashMap;
use std::path::Path;

/// The modules in the table's order (`fsio/sweep` counts as `fsio`).
fn layer_order(architecture: &str) -> Vec<String> {
    let mut order: Vec<String> = Vec::new();
    for line in architecture.lines().filter(|l| l.starts_with("| `")) {
        let first_cell = line.split('|').nth(1).unwrap_or_default();
        for name in first_cell.split('`').skip(1).step_by(2) {
            let module = name.trim_end_matches('/').split('/').next().unwrap_or(name);
            if !order.iter().any(|m| m == module) {
                order.push(module.to_string());
            }
        }
    }
    order
}

/// The top-level modules a source file names as `crate::NAME`, outside comments.
fn crate_paths(source: &str) -> Vec<String> {
    let mut names = Vec::new();
    for line in source.lines() {
        let code = line.split("//").next().unwrap_or_default();
        let mut rest = code;
        while let Some(at) = rest.find("crate::") {
            rest = &rest[at + "crate::".len()..];
            if let Some(group) = rest.strip_prefix('{') {
                let group = group.split('}').next().unwrap_or_default();
                names.extend(group.split(',').filter_map(|item| {
                    let name = item.trim().split("::").next()?.trim();
                    (!name.is_empty()).then(|| name.to_string())
                }));
            } else {
                let name: String = rest
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                names.push(name);
            }
        }
    }
    names
}

fn rust_files(dir: &Path, found: &mut Vec<std::path::PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("read src") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rust_files(&path, found);
        } else if path.extension().is_some_and(|e| e == "rs") {
            found.push(path);
        }
    }
}

#[test]
fn every_module_uses_only_the_layers_below_it() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let architecture =
        std::fs::read_to_string(root.join("ARCHITECTURE.md")).expect("ARCHITECTURE.md");
    let order = layer_order(&architecture);
    assert!(
        order.len() > 20,
        "the module table was not found: {order:?}"
    );
    let rank: HashMap<&str, usize> = order
        .iter()
        .enumerate()
        .map(|(i, m)| (m.as_str(), i))
        .collect();
    // Helpers of a few lines that every layer may call: not layers.
    let utilities = ["suggest", "toml_error"];
    let src = root.join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut problems = Vec::new();
    for file in files {
        let relative = file.strip_prefix(&src).expect("under src");
        let first = relative.components().next().expect("a component");
        let module = first
            .as_os_str()
            .to_string_lossy()
            .trim_end_matches(".rs")
            .to_string();
        if module == "lib" || module == "main" || utilities.contains(&module.as_str()) {
            continue;
        }
        let Some(&own) = rank.get(module.as_str()) else {
            problems.push(format!(
                "src/{module} is not in ARCHITECTURE.md's module table"
            ));
            continue;
        };
        let source = std::fs::read_to_string(&file).expect("read source");
        for used in crate_paths(&source) {
            if used == module || utilities.contains(&used.as_str()) {
                continue;
            }
            match rank.get(used.as_str()) {
                Some(&theirs) if theirs < own => {}
                Some(_) => problems.push(format!(
                    "{}: `{module}` uses `{used}`, which ARCHITECTURE.md lists above it",
                    relative.display()
                )),
                None => problems.push(format!(
                    "{}: `crate::{used}` is not in ARCHITECTURE.md's module table",
                    relative.display()
                )),
            }
        }
    }
    problems.sort();
    problems.dedup();
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn the_crate_path_reader_sees_groups_and_skips_comments() {
    let source = "use crate::{robot::Robot, table};\n// crate::commands\nlet x = crate::fsio::write(); // crate::fleet\n";
    assert_eq!(crate_paths(source), ["robot", "table", "fsio"]);
}
