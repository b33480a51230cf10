//! Table 5 of Alidadi & Rahimi (2023): `cargo run --release -p prognos-sim --example
//! reaction_wheel_table5 -- [runs] [N,N,...]` (defaults: 20 runs, all of Table 5's N; the plain
//! PF is run at N = 100 only).
use prognos_core::filter::adaptive::Method;
use prognos_sim::reaction_wheel::{TABLE5_PARTICLES, format_table5, table5};

fn main() {
    let mut args = std::env::args().skip(1);
    let runs: usize = args.next().and_then(|s| s.parse().ok()).unwrap_or(20);
    let particles: Vec<usize> = args
        .next()
        .map(|s| s.split(',').filter_map(|v| v.parse().ok()).collect())
        .unwrap_or_else(|| TABLE5_PARTICLES.to_vec());
    let start = std::time::Instant::now();
    let mut cells = table5(&[100], &[Method::Plain], runs, 1000);
    cells.extend(table5(
        &particles,
        &[Method::AdaptiveResampling, Method::Apf],
        runs,
        1000,
    ));
    println!("{}", format_table5(&cells));
    println!(
        "{runs} runs per cell, {:.0} s",
        start.elapsed().as_secs_f64()
    );
}
