//! Every path the README names exists, so its file map cannot go stale unnoticed (it named `quant.rs`,
//! `sampling.rs` and `npy_io.rs` long after they had become folders).
//!
//! Two kinds of names are checked:
//! - in the prose, each backticked path and each link target that starts in the checkout (`src/…`,
//!   `host-sim/…`, `docs/…`, …) must exist as written;
//! - in the file map (the code block that starts with `Cargo.toml`), each path-like word not in backticks
//!   must name a file or folder under the section it stands in (`src/`, `host-sim/`, `boards/`, …): a word `record.rs` in the
//!   `host-sim/` section matches `host-sim/station/src/global_map/record.rs`, a `quant.rs` matches nothing.

use std::path::{Path, PathBuf};

/// The checkout's top-level entries a README path can start with.
const ROOTS: &[&str] = &[
    "src",
    "host-sim",
    "docs",
    "boards",
    "selftest",
    "examples",
    "tests",
    "benches",
    "xtask",
    ".ci",
    "Cargo.toml",
    "memory.x",
    "build.rs",
    "README.md",
];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn readme() -> String {
    std::fs::read_to_string(root().join("README.md")).expect("README.md")
}

/// A word that names a file or a folder: ends in `/` or has a file extension, and holds no space.
fn path_like(word: &str) -> bool {
    const EXT: &[&str] = &[
        ".rs", ".md", ".toml", ".sh", ".json", ".py", ".js", ".x", ".tsv", ".laz", ".las", ".png",
    ];
    !word.is_empty()
        && !word.contains(char::is_whitespace)
        && !word.contains("://")
        && (word.ends_with('/') || EXT.iter().any(|e| word.ends_with(e)))
}

/// The words of the README's prose (outside code blocks) in backticks, and its link targets.
fn prose_paths(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut in_block = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
            continue;
        }
        if in_block {
            continue;
        }
        for (i, piece) in line.split('`').enumerate() {
            if i % 2 == 1 {
                out.push(piece.to_string());
            }
        }
        for link in line.split("](").skip(1) {
            if let Some(end) = link.find(')') {
                out.push(link[..end].to_string());
            }
        }
    }
    out.into_iter()
        .map(|p| p.split('#').next().unwrap_or_default().to_string())
        .filter(|p| {
            let first = p.split('/').next().unwrap_or_default();
            ROOTS.contains(&first) && (p.contains('/') || path_like(p))
        })
        .collect()
}

/// Every file and folder under `dir`, as paths relative to the checkout (`target` and hidden folders
/// left out).
fn walk(dir: &Path, out: &mut Vec<String>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        let name = e.file_name().to_string_lossy().into_owned();
        if name == "target" || name.starts_with('.') {
            continue;
        }
        let rel = path
            .strip_prefix(root())
            .expect("under the checkout")
            .to_string_lossy()
            .replace('\\', "/");
        if path.is_dir() {
            out.push(format!("{rel}/"));
            walk(&path, out);
        } else {
            out.push(rel);
        }
    }
}

/// (section, word) for each path-like word of the file map.
fn file_map_words(text: &str) -> Vec<(String, String)> {
    let start = text
        .find("```\nCargo.toml")
        .expect("the README's file map starts with Cargo.toml");
    let block = &text[start + 4..];
    let block = &block[..block.find("```").expect("the file map ends")];
    let mut section = String::new();
    let mut out = Vec::new();
    for line in block.lines() {
        if !line.starts_with(' ') {
            section = line
                .split_whitespace()
                .next()
                .unwrap_or_default()
                .to_string();
        }
        for word in line.split_whitespace() {
            // A word in backticks is code (`mod tests`, `tests.rs` in general), not a path.
            if word.trim_start_matches('(').starts_with('`') {
                continue;
            }
            let word = word.trim_matches(|c: char| ",;:()".contains(c));
            // `.las/.laz` is a kind of file, not a path.
            if path_like(word) && !word.starts_with('.') {
                out.push((section.clone(), word.to_string()));
            }
        }
    }
    out
}

#[test]
fn every_path_in_the_prose_exists() {
    let paths = prose_paths(&readme());
    assert!(paths.len() > 20, "the prose names paths: {paths:?}");
    let missing: Vec<_> = paths.iter().filter(|p| !root().join(p).exists()).collect();
    assert!(
        missing.is_empty(),
        "README names paths that do not exist: {missing:?}"
    );
}

#[test]
fn every_word_of_the_file_map_names_a_file_under_its_section() {
    let words = file_map_words(&readme());
    assert!(words.len() > 60, "the file map names files: {words:?}");
    let mut missing = Vec::new();
    let mut trees = std::collections::HashMap::new();
    for (section, word) in &words {
        if word == section || !section.ends_with('/') {
            assert!(root().join(word).exists(), "{word}");
            continue;
        }
        let all = trees.entry(section.clone()).or_insert_with(|| {
            let mut all = Vec::new();
            walk(&root().join(section), &mut all);
            all
        });
        let hit = all
            .iter()
            .any(|p| p == word || p.ends_with(&format!("/{word}")) || root().join(word).exists());
        if !hit {
            missing.push(format!("{section} … {word}"));
        }
    }
    assert!(
        missing.is_empty(),
        "the file map names what does not exist: {missing:?}"
    );
}

#[test]
fn the_check_sees_a_stale_name() {
    // The stale names the file map once carried are found missing; real ones are found.
    let mut all = Vec::new();
    walk(&root().join("src"), &mut all);
    let found = |w: &str| all.iter().any(|p| p.ends_with(&format!("/{w}")));
    for stale in ["quant.rs", "sampling.rs", "frame/encoder.rs"] {
        assert!(!found(stale), "{stale}");
    }
    for real in [
        "quant/",
        "sampling/",
        "frame/encoder/",
        "wire/codec/",
        "receiver.rs",
    ] {
        assert!(found(real), "{real}");
    }
    let prose =
        prose_paths("see `host-sim/src/base_station/cli.rs` and [x](docs/firmware.md#loop)");
    assert_eq!(
        prose,
        ["host-sim/src/base_station/cli.rs", "docs/firmware.md"]
    );
    assert!(!root().join(&prose[0]).exists());
}
