//! Reproduces Tables 4 and 6 of Yu et al. (2020): `cargo run --release -p prognos-sim
//! --example scooter_tables -- [runs] [seed]`.
fn main() {
    let mut args = std::env::args().skip(1);
    let runs = args.next().and_then(|s| s.parse().ok()).unwrap_or(20);
    let seed = args.next().and_then(|s| s.parse().ok()).unwrap_or(1);
    print!("{}", prognos_sim::scooter::tables(runs, seed));
    print!("{}", prognos_sim::scooter::table5_text(runs, seed));
}
