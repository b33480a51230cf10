fn main() {
    print!("{}", prognos_sim::scooter::demo_summary(1));
}
