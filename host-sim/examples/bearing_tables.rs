//! Prints the bearing tables (Anger et al. 2012 Tables 4-6 and the campaign) as Markdown.
//! Usage: cargo run --release -p prognos-sim --example bearing_tables [trials] [training]
use prognos_sim::bearing::{CampaignConfig, tables, trial::TrialGenerator};
fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let mut c = CampaignConfig::default();
    if let Some(n) = args.get(1) {
        c.trials = n.parse()?;
    }
    if let Some(n) = args.get(2) {
        c.training = n.parse()?;
    }
    let t0 = std::time::Instant::now();
    let t = tables(&TrialGenerator::new(), c)?;
    println!("{}", t.to_markdown());
    eprintln!(
        "R = {:.4}, {:.1} s",
        t.measurement_variance,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
