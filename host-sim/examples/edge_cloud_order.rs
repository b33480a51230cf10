//! FPE and MDL (Eqs. 14-16) over AR orders 1-12 on real vibration windows (12 snapshots,
//! ORIV with q = n): `cargo run --release -p prognos-sim --example edge_cloud_order`.
//! Prints the order each criterion picks on healthy windows (after the 1500-s warm-up) of
//! each learning bearing.

use prognos_core::learn::ar::{
    ArModel, OrivConfig, WindowCheck, best_order, combined_order, identify,
};
use prognos_sim::edge_cloud::PAPER_TABLE1_PH_MIN;
use prognos_sim::edge_cloud::bearing::load_bearing;
use std::path::PathBuf;

macro_rules! criteria {
    ($window:expr, $($n:literal),*) => {{
        let mut fpe = Vec::new();
        let mut mdl = Vec::new();
        $(
            if let Ok(m) = identify::<f64, $n, $n, _>(
                $window.clone(), &OrivConfig::default(), &WindowCheck::default()) {
                let m: ArModel<f64, $n> = m;
                if let (Ok(f), Ok(d)) = (m.fpe(), m.mdl()) {
                    fpe.push(($n, f));
                    mdl.push(($n, d));
                }
            }
        )*
        (best_order(fpe), best_order(mdl))
    }};
}

fn main() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../data/pronostia");
    for (name, _) in PAPER_TABLE1_PH_MIN {
        let record = load_bearing(&root.join(format!("{name}.csv"))).expect("bearing file");
        let mut picks = Vec::new();
        for start in [150usize, 200, 250, 300, 350] {
            let Some(snaps) = record.snapshots.get(start..start + 12) else {
                continue;
            };
            let window = snaps.iter().flat_map(|s| s.horizontal.iter().copied());
            let (fpe, mdl) = criteria!(window, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12);
            if let (Some(f), Some(m)) = (fpe, mdl) {
                picks.push(format!("FPE {f:>2} MDL {m:>2} -> {}", combined_order(f, m)));
            }
        }
        println!("{name}: {}", picks.join(" | "));
    }
}
