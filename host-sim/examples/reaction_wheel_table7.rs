//! Table 7 of Alidadi & Rahimi (2023), three-month runs: `cargo run --release -p prognos-sim
//! --example reaction_wheel_table7 -- [runs]` (default 20).
fn main() {
    let runs: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let start = std::time::Instant::now();
    println!("{}", prognos_sim::reaction_wheel::table7(runs, 3000));
    println!("{:.0} s", start.elapsed().as_secs_f64());
}
