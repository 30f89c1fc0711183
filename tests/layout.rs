//! The house rules a newcomer relies on, checked: no source file of the core, the desktop twin, the base
//! station, the self-test or xtask holds more than 500 lines outside its tests, and a module's unit tests inside `src`
//! are its `mod tests` — at the end of its file, or beside it in `tests.rs` (a `tests/` folder for
//! several) — never a third pattern such as `*_tests.rs`.

use std::path::{Path, PathBuf};

const MAX_LINES: usize = 500;

/// The source folders the rules cover.
const TREES: &[&str] = &[
    "src",
    "host-sim/src",
    "host-sim/station/src",
    "xtask/src",
    "selftest/src",
];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).expect("a source folder").flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

fn files() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut out = Vec::new();
    for t in TREES {
        rust_files(&root.join(t), &mut out);
    }
    assert!(out.len() > 100, "found the sources: {}", out.len());
    out
}

/// Whether a file holds tests only: `tests.rs`, anything under a `tests/` folder of a module.
fn is_test_file(p: &Path) -> bool {
    p.file_name().is_some_and(|n| n == "tests.rs")
        || p.components().any(|c| c.as_os_str() == "tests")
}

/// Lines outside `#[cfg(test)]` items (an item is its line up to `;`, or its braces).
fn non_test_lines(text: &str) -> usize {
    let lines: Vec<&str> = text.lines().collect();
    let (mut count, mut i) = (0, 0);
    while i < lines.len() {
        if lines[i].trim_start().starts_with("#[cfg(test)]") {
            let (mut depth, mut opened) = (0i32, false);
            let mut j = i + 1;
            while j < lines.len() {
                let l = lines[j];
                depth += l.matches('{').count() as i32 - l.matches('}').count() as i32;
                opened |= l.contains('{');
                if (opened && depth <= 0) || (!opened && l.trim_end().ends_with(';')) {
                    break;
                }
                j += 1;
            }
            i = j + 1;
            continue;
        }
        count += 1;
        i += 1;
    }
    count
}

#[test]
fn no_source_file_is_over_500_lines_outside_its_tests() {
    let long: Vec<String> = files()
        .iter()
        .filter(|p| !is_test_file(p))
        .filter_map(|p| {
            let n = non_test_lines(&std::fs::read_to_string(p).expect("readable"));
            (n > MAX_LINES).then(|| format!("{} ({n})", p.display()))
        })
        .collect();
    assert!(
        long.is_empty(),
        "over {MAX_LINES} lines outside tests: {long:?}"
    );
}

#[test]
fn the_line_count_leaves_tests_out() {
    let text = "fn a() {}\n#[cfg(test)]\nmod tests {\n    #[test]\n    fn t() {}\n}\nfn b() {}\n";
    assert_eq!(non_test_lines(text), 2);
    assert_eq!(non_test_lines("#[cfg(test)]\nmod tests;\nfn c() {}\n"), 1);
}

#[test]
fn unit_tests_in_src_are_each_modules_mod_tests() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut core = Vec::new();
    rust_files(&root, &mut core);
    let mut odd = Vec::new();
    for p in &core {
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        if name.ends_with("_tests.rs") {
            odd.push(p.display().to_string());
        }
        let text = std::fs::read_to_string(p).expect("readable");
        let lines: Vec<&str> = text.lines().collect();
        for w in lines.windows(2) {
            let gated = w[0].trim_start().starts_with("#[cfg(test)]")
                || w[0].trim_start().starts_with("#[cfg(all(test");
            let module = w[1].trim_start().strip_prefix("mod ");
            if let (true, Some(m)) = (gated, module) {
                if !(m.starts_with("tests;") || m.starts_with("tests {")) {
                    odd.push(format!("{}: mod {m}", p.display()));
                }
            }
        }
    }
    assert!(
        odd.is_empty(),
        "test modules other than `mod tests`: {odd:?}"
    );
}
