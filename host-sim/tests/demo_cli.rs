//! `host-sim demo`, the README's first command, end to end: the firmware's `Mapper` streams over the
//! simulated faulty link to the base station. The headline lines it prints are the goals; this test
//! reads them back from the program's own output, so a change that breaks the link, the acknowledgements
//! or the wire codec shows here, not only in a figure someone re-runs by hand.

use std::process::Command;

/// Runs `host-sim demo` with `extra` flags; returns its standard output.
fn demo(extra: &[&str]) -> String {
    let out_dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .arg("demo")
        .arg("--out")
        .arg(out_dir.path())
        .args(extra)
        .output()
        .unwrap();
    let stdout = String::from_utf8(out.stdout).unwrap();
    assert!(
        out.status.success(),
        "demo failed: {}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// The line starting with `prefix`, without the prefix.
fn line<'a>(stdout: &'a str, prefix: &str) -> &'a str {
    stdout
        .lines()
        .find_map(|l| l.strip_prefix(prefix))
        .unwrap_or_else(|| panic!("no line `{prefix}` in:\n{stdout}"))
}

/// The first number in `text` (digits and one decimal point).
fn number(text: &str) -> f64 {
    let start = text.find(|c: char| c.is_ascii_digit()).unwrap();
    let end = text[start..]
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .map_or(text.len(), |e| start + e);
    text[start..end].parse().unwrap()
}

/// "N of M" → (N, M).
fn lost_of(text: &str) -> (u64, u64) {
    let (lost, rest) = text.split_once(" of ").unwrap();
    (number(lost) as u64, number(rest) as u64)
}

#[test]
fn demo_with_back_channel_loses_nothing_within_its_byte_budget() {
    let stdout = demo(&[]);
    let (lost, sent) = lost_of(line(&stdout, "points lost on the link: "));
    assert_eq!(lost, 0, "{stdout}");
    assert!(sent > 100_000, "{stdout}");
    // The built-in tile fits the robot's map and link: it takes every point.
    let refused = line(
        &stdout,
        "points the robot's map refused (counted, never sent): ",
    );
    assert!(refused.starts_with("0 ("), "{refused}\n{stdout}");
    let bytes = number(line(&stdout, "wire bytes per integrated point: "));
    assert!(
        bytes > 1.0 && bytes <= 14.0,
        "{bytes} B per point\n{stdout}"
    );
    let agreement = number(line(
        &stdout,
        "base station vs robot map, argmax agreement: ",
    ));
    assert!(agreement >= 99.9, "{agreement} %\n{stdout}");
    // The figures come from the Rice-coded summaries (packed codes stay at RMS 0.043 on this map).
    assert!(line(&stdout, "summary codec: ").starts_with("Rice-coded"));
    let reference = line(&stdout, "base station vs f32 reference of all points: ");
    let rms = number(reference.split_once("RMS ‖Δμ‖/‖μ‖ ").unwrap().1);
    assert!(rms <= 0.03, "RMS {rms}\n{stdout}");
}

#[test]
fn demo_without_back_channel_counts_what_the_link_lost() {
    let stdout = demo(&["--no-back-channel"]);
    let (lost, sent) = lost_of(line(&stdout, "points lost on the link: "));
    // The default link drops 2 % of the frames and damages others: with nobody to ask for a re-send,
    // points are lost, and every one is counted.
    assert!(lost > 0 && lost < sent, "{stdout}");
    assert!(line(&stdout, "points lost on the link: ").contains("no back channel"));
}
