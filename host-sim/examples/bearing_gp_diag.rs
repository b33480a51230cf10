use prognos_sim::bearing::train::*;
use prognos_sim::bearing::trial::TrialGenerator;
fn main() -> anyhow::Result<()> {
    let g = TrialGenerator::new();
    let trials: Vec<_> = (100..108).map(|s| g.trial(s)).collect();
    let refs: Vec<_> = trials.iter().collect();
    for (name, set) in [
        ("t0", vec![refs[0]]),
        ("t1", vec![refs[1]]),
        ("pooled", refs.clone()),
    ] {
        let d = Dataset::from_trials(&set);
        let gp = train(&d, GP_POINTS)?;
        println!(
            "{name}: n={} hyper {:?} mean {:.5} nlml {:.1}",
            d.targets.len(),
            gp.hyper,
            gp.mean_offset,
            gp.nlml
        );
        let core = gp.to_core::<GP_POINTS>()?;
        for r in [0.0, 0.1, 0.2, 0.4, 0.6, 0.8, 1.0] {
            let p0 = core
                .predict(&nalgebra::Vector2::new(r, 0.0))
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            let p1 = core
                .predict(&nalgebra::Vector2::new(r, 0.2))
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            println!(
                "  r {r:.1}: du0 {:.5} +- {:.5}  du0.2 {:.5} +- {:.5} {}",
                p0.mean,
                p0.variance().sqrt(),
                p1.mean,
                p1.variance().sqrt(),
                p0.extrapolating
            );
        }
    }
    for t in &trials {
        println!(
            "eol {} du mean {:.3}",
            t.eol,
            t.load_diff[..t.eol].iter().sum::<f64>() / t.eol as f64
        );
    }
    Ok(())
}
