//! The core's modules point one way: each top-level module may use only
//! modules of its own layer or below, and no two files import each other.
//! Layers, from the bottom:
//!
//! 0. mesh and topology, errors, progress and cancellation (`control`)
//! 1. formats (`io`) and the test shapes (`shapes`)
//! 2. fitting primitives (`fit`)
//! 3. smoothing steps (`smoothing`) and quality fixes (`quality`)
//! 4. pipeline, parameters and report
//! 5. the job layer (`job`)
//!
//! Above the core, the front ends (the CLI and the service) handle meshes
//! only through the job layer. Test modules (`#[cfg(test)]`) may use
//! anything.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The layer of each top-level module of the core.
const LAYERS: &[(&str, u8)] = &[
    ("control", 0),
    ("error", 0),
    ("mesh", 0),
    ("sort", 0),
    ("io", 1),
    ("shapes", 1),
    ("fit", 2),
    ("quality", 3),
    ("smoothing", 3),
    ("params", 4),
    ("pipeline", 4),
    ("report", 4),
    ("job", 5),
];

fn layer(module: &str) -> Option<u8> {
    LAYERS.iter().find(|(m, _)| *m == module).map(|&(_, l)| l)
}

/// A source file: its module path (`smoothing::adaptive::growth`) and the
/// code outside its test modules, comments removed.
struct Source {
    file: String,
    module: Vec<String>,
    code: String,
}

fn module_of(relative: &Path) -> Vec<String> {
    let mut parts: Vec<String> = relative
        .iter()
        .map(|p| p.to_string_lossy().trim_end_matches(".rs").to_owned())
        .collect();
    if parts.last().is_some_and(|p| p == "mod" || p == "lib") {
        parts.pop();
    }
    parts
}

/// The code before the file's first `#[cfg(test)]` item (test modules
/// close the files of this crate), without comments.
fn non_test_code(text: &str) -> String {
    let code = match text.find("#[cfg(test)]") {
        Some(at) => &text[..at],
        None => text,
    };
    code.lines()
        .map(|l| l.split("//").next().unwrap_or_default())
        .collect::<Vec<_>>()
        .join("\n")
}

fn sources(root: &Path) -> Vec<Source> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).expect("read the source folder") {
            let path = entry.expect("a folder entry").path();
            if path.is_dir() {
                walk(&path, out);
            } else if path.extension().is_some_and(|e| e == "rs") {
                out.push(path);
            }
        }
    }
    let mut files = Vec::new();
    walk(root, &mut files);
    files.sort();
    files
        .into_iter()
        .map(|path| {
            let relative = path.strip_prefix(root).expect("under the root");
            let text = std::fs::read_to_string(&path).expect("read a source file");
            Source {
                file: relative.display().to_string(),
                module: module_of(relative),
                code: non_test_code(&text),
            }
        })
        .collect()
}

/// Every module path the code names: `crate::a::b` and `super::b` (resolved
/// against `module`), as far as the path's lower-case segments go, from
/// `use` items and paths in code alike.
fn references(module: &[String], code: &str) -> BTreeSet<Vec<String>> {
    let mut found = BTreeSet::new();
    let bytes = code.as_bytes();
    for start in ["crate::", "super::"] {
        let mut from = 0;
        while let Some(at) = code[from..].find(start).map(|i| i + from) {
            from = at + start.len();
            let preceded =
                at > 0 && (bytes[at - 1].is_ascii_alphanumeric() || bytes[at - 1] == b'_');
            if preceded {
                continue;
            }
            let mut path: Vec<String> = if start == "super::" {
                module[..module.len().saturating_sub(1)].to_vec()
            } else {
                Vec::new()
            };
            let mut rest = &code[from..];
            // `super::super::`
            while let Some(r) = rest.strip_prefix("super::") {
                path.pop();
                rest = r;
            }
            for segment in rest.split("::") {
                let name: String = segment
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                if name.is_empty() || !name.starts_with(|c: char| c.is_ascii_lowercase()) {
                    break;
                }
                path.push(name.clone());
                if name.len() != segment.len() {
                    break;
                }
            }
            if !path.is_empty() {
                found.insert(path);
            }
        }
    }
    found
}

/// What breaks the layering of `sources`: upward uses and pairs of files
/// that import each other.
fn violations(sources: &[Source]) -> Vec<String> {
    let files: BTreeMap<&[String], &str> = sources
        .iter()
        .map(|s| (s.module.as_slice(), s.file.as_str()))
        .collect();
    // The file a module path lives in: its longest prefix that is a file.
    let file_of = |path: &[String]| {
        (1..=path.len())
            .rev()
            .find_map(|n| files.get(&path[..n]).copied())
    };
    let mut found = Vec::new();
    let mut edges: BTreeSet<(&str, &str)> = BTreeSet::new();
    for s in sources {
        let Some(own) = s.module.first() else {
            continue; // lib.rs: the crate's table of contents.
        };
        let Some(own_layer) = layer(own) else {
            found.push(format!("{}: module `{own}` has no layer", s.file));
            continue;
        };
        for path in references(&s.module, &s.code) {
            let Some(target) = path.first() else { continue };
            match layer(target) {
                Some(l) if l > own_layer => found.push(format!(
                    "{} (layer {own_layer}) uses `{}` (layer {l})",
                    s.file,
                    path.join("::")
                )),
                Some(_) => {}
                None => found.push(format!("{}: `{}` has no layer", s.file, path.join("::"))),
            }
            if let Some(to) = file_of(&path)
                && to != s.file
            {
                edges.insert((s.file.as_str(), to));
            }
        }
    }
    for &(a, b) in &edges {
        if a < b && edges.contains(&(b, a)) {
            found.push(format!("{a} and {b} import each other"));
        }
    }
    found
}

fn source(file: &str, code: &str) -> Source {
    Source {
        file: file.to_owned(),
        module: module_of(Path::new(file)),
        code: non_test_code(code),
    }
}

#[test]
fn no_module_uses_one_above_it() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let sources = sources(&root);
    let used: usize = sources
        .iter()
        .map(|s| references(&s.module, &s.code).len())
        .sum();
    assert!(
        sources.len() > 40 && used > 100,
        "the sources were not read"
    );
    let found = violations(&sources);
    assert!(found.is_empty(), "layering broken:\n{}", found.join("\n"));
}

#[test]
fn the_check_finds_upward_uses_and_mutual_imports() {
    let found = violations(&[
        source(
            "smoothing/initial.rs",
            "use crate::pipeline::check;\nuse super::project::fit_pass;\n",
        ),
        source("smoothing/project.rs", "fn f() { super::initial::g() }\n"),
        source("pipeline.rs", "use crate::smoothing::initial;\n"),
        source(
            "fit/frame.rs",
            "use crate::mesh::Mesh;\n#[cfg(test)]\nmod tests { use crate::job::run; }\n",
        ),
        source("mesh/mod.rs", "pub struct Mesh;\n"),
    ]);
    assert_eq!(
        found,
        [
            "smoothing/initial.rs (layer 3) uses `pipeline::check` (layer 4)",
            "pipeline.rs and smoothing/initial.rs import each other",
            "smoothing/initial.rs and smoothing/project.rs import each other",
        ],
        "{found:#?}"
    );
}

/// The front ends read, smooth and write meshes only through the job layer.
#[test]
fn front_ends_handle_meshes_through_the_job_layer() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../src");
    if !root.is_dir() {
        return; // The core on its own, outside the workspace.
    }
    let mut found = Vec::new();
    for s in sources(&root) {
        for call in [
            "meshsmooth_core::run",
            "pipeline::run",
            "io::read",
            "io::write",
            "read_with",
            "write_with",
        ] {
            if s.code.contains(call) {
                found.push(format!("{} calls {call}", s.file));
            }
        }
    }
    assert!(found.is_empty(), "{}", found.join("\n"));
}
