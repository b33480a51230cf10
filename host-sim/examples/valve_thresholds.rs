//! Recomputes the valve damage thresholds recorded in
//! `prognos_core::plants::valve::PROGPY_THRESHOLDS` (bisection on the cycle simulation).
//! Run: `cargo run --release -p prognos-sim --example valve_thresholds`.

use prognos_core::plants::valve::{
    DamageMode, PROGPY_LIMITS, Requirements, ValveParams, compute_damage_thresholds,
};

fn main() {
    let params = ValveParams::<f64>::progpy_stable();
    let req = Requirements::default();
    let Some((t, functional)) = compute_damage_thresholds(&params, &req, &PROGPY_LIMITS) else {
        eprintln!("the nominal valve fails its requirements");
        std::process::exit(1);
    };
    for (mode, f) in DamageMode::ALL.iter().zip(functional) {
        let how = if f {
            "functional (bisection)"
        } else {
            "progpy limit (never fails)"
        };
        eprintln!("{:>22}: {:e}  {how}", mode.name(), t.of(*mode));
    }
    println!("pub const PROGPY_THRESHOLDS: DamageThresholds<f64> = DamageThresholds {{");
    println!("    r_max: {:e},", t.r_max);
    println!("    k_min: {:e},", t.k_min);
    println!("    a_i_max: {:e},", t.a_i_max);
    println!("    a_et_max: {:e},", t.a_et_max);
    println!("    a_eb_max: {:e},", t.a_eb_max);
    println!("}};");
}
