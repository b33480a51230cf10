//! The `prognos` command-line program.
#![forbid(unsafe_code)]

fn main() -> std::process::ExitCode {
    prognos_sim::cli::main_with(prognos_sim::registry::Registry::builtin())
}
