//! What `cargo test` printed, summed over every test binary: the totals, and how each QEMU firmware test
//! ended (named by the `_firmware_in_qemu_` in their names, boards/firmware-tests/tests/firmware_qemu.rs), so the last
//! lines of a long run say whether the firmware really ran.

/// A test's name marks it as one that runs a firmware under QEMU.
pub const FIRMWARE_MARK: &str = "_firmware_in_qemu_";

#[derive(Debug, Default, PartialEq)]
pub struct Summary {
    pub passed: u64,
    pub failed: u64,
    pub ignored: u64,
    /// The firmware tests seen: (name, outcome as printed: `ok`, `FAILED`, `ignored, <reason>`).
    pub firmware: Vec<(String, String)>,
}

impl Summary {
    /// Take one line of `cargo test`'s standard output.
    pub fn read(&mut self, line: &str) {
        if let Some(rest) = line.strip_prefix("test result: ") {
            for part in rest.split(';') {
                let mut words = part.split_whitespace().rev();
                let (Some(what), Some(n)) = (words.next(), words.next()) else {
                    continue;
                };
                let Ok(n) = n.parse::<u64>() else { continue };
                match what {
                    "passed" => self.passed += n,
                    "failed" => self.failed += n,
                    "ignored" => self.ignored += n,
                    _ => {}
                }
            }
        } else if let Some(rest) = line.strip_prefix("test ") {
            if let Some((name, outcome)) = rest.split_once(" ... ") {
                if name.contains(FIRMWARE_MARK) {
                    self.firmware
                        .push((name.to_string(), outcome.trim().to_string()));
                }
            }
        }
    }

    /// The closing lines.
    pub fn report(&self) -> String {
        let mut s = String::from("\n");
        if self.firmware.is_empty() {
            s += "QEMU firmware tests: none ran (not selected by the arguments)\n";
        } else {
            s += "QEMU firmware tests (boards/firmware-tests/tests/firmware_qemu.rs: each board's firmware run in QEMU, its \
                  UART stream checked byte for byte against the host twin):\n";
            for (name, outcome) in &self.firmware {
                // `ignored, <reason>`: the name first, the reason after it.
                let line = match outcome.split_once(", ") {
                    Some((word, reason)) => format!("  {word:<8} {name} ({reason})\n"),
                    None => format!("  {outcome:<8} {name}\n"),
                };
                s += &line;
            }
        }
        s += &format!(
            "total: {} passed, {} failed, {} ignored\n",
            self.passed, self.failed, self.ignored
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sums_every_binary_and_names_the_firmware_tests() {
        let mut s = Summary::default();
        for line in [
            "running 3 tests",
            "test cortex_m4f_firmware_in_qemu_streams_the_map ... ok",
            "test thumbv6m_firmware_in_qemu_streams_the_map has been running for over 60 seconds",
            "test riscv32_firmware_in_qemu_streams_the_map ... FAILED",
            "test thumbv6m_firmware_in_qemu_streams_the_map ... ignored, LATENTBKI_NO_QEMU is set",
            "test result: FAILED. 1 passed; 1 failed; 1 ignored; 0 measured; 0 filtered out; finished in 9.10s",
            "test src/lib.rs - Mapper (line 55) ... ok",
            "test result: ok. 12 passed; 0 failed; 0 ignored; 0 measured; 0 filtered out; finished in 1.00s",
        ] {
            s.read(line);
        }
        assert_eq!((s.passed, s.failed, s.ignored), (13, 1, 1));
        let outcomes: Vec<&str> = s.firmware.iter().map(|(_, o)| o.as_str()).collect();
        assert_eq!(
            outcomes,
            ["ok", "FAILED", "ignored, LATENTBKI_NO_QEMU is set"]
        );
        let report = s.report();
        assert!(report.contains("  ok       cortex_m4f_firmware_in_qemu_streams_the_map\n"));
        assert!(report.contains(
            "  ignored  thumbv6m_firmware_in_qemu_streams_the_map (LATENTBKI_NO_QEMU is set)\n"
        ));
        assert!(report.ends_with("total: 13 passed, 1 failed, 1 ignored\n"));
    }

    #[test]
    fn says_when_no_firmware_test_ran() {
        let mut s = Summary::default();
        s.read("test result: ok. 2 passed; 0 failed; 0 ignored; 0 measured; 5 filtered out; finished in 0.01s");
        assert!(s.report().contains("QEMU firmware tests: none ran"));
    }
}
