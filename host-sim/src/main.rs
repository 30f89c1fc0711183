//! `host-sim`: the command line of the desktop twin. Every command lives in [`host_sim::cli`].

fn main() -> std::process::ExitCode {
    host_sim::cli::main()
}
