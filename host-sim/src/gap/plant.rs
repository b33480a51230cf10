//! The plant interface of the gap diagnoser: what a user implements to diagnose their own
//! system.
//!
//! A [`GapPlant`] is a nominal model that can be replayed open loop over recorded inputs,
//! with named parameters (the `[model]` table of the meta file) and its own catalogue of
//! candidate effects. Each effect is switched on by name and acts through model parameters
//! (its fitted parameters *are* model parameters, so an effect the user's model already has
//! is listed in `sim_effects` and takes its values from `[model]`). The generic sensor
//! catalogue ([`crate::gap::effects::GenericKind`]) is added by the diagnoser to every plant.
//!
//! To add a plant: implement the trait (see [`crate::gap::dc_motor`] for a complete worked
//! example) and add it to [`builtin_plant`].

use crate::gap::estimate::{Estimates, Sensors};
use std::collections::BTreeMap;

/// How a parameter is searched between its bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scale {
    /// Evenly spaced.
    Linear,
    /// Evenly spaced in the logarithm (bounds must be positive).
    Log,
}

/// A named model parameter with its default value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParamSpec {
    /// Name as written in `[model]`.
    pub name: &'static str,
    /// The project's default value.
    pub default: f64,
    /// Unit and meaning.
    pub doc: &'static str,
}

/// The search range of one fitted parameter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitRange {
    /// Model parameter name.
    pub name: &'static str,
    /// Lower bound.
    pub lo: f64,
    /// Upper bound.
    pub hi: f64,
    /// Search scale.
    pub scale: Scale,
    /// Which side of the user's model value the effect can move the parameter to.
    pub side: Side,
}

/// The direction a catalogue effect moves its parameter from the user's model value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Side {
    /// Either way (the effect is a departure, not a named wear).
    Either,
    /// Only down (a wear that lowers it, such as a weakening spring).
    BelowModel,
    /// Only up (a wear that raises it, such as growing friction).
    AboveModel,
}

/// One effect of a plant's own catalogue.
#[derive(Clone, Debug, PartialEq)]
pub struct EffectSpec {
    /// Name used in `sim_effects` and in the verdict.
    pub name: &'static str,
    /// What the effect adds to the model.
    pub doc: &'static str,
    /// The model parameters fitted when the effect is a candidate.
    pub fit: Vec<FitRange>,
    /// Input channels the effect needs (it is not a candidate when one is absent).
    pub needs_inputs: Vec<&'static str>,
    /// Generic effects `(kind name, channel)` this effect is the plant's own name for
    /// (the same prediction, e.g. an encoder efficiency is a sensor scale): they are not
    /// candidates beside it.
    pub replaces_generic: Vec<(&'static str, &'static str)>,
}

impl EffectSpec {
    /// An effect with one fitted parameter and no required inputs.
    pub fn single(
        name: &'static str,
        doc: &'static str,
        param: &'static str,
        lo: f64,
        hi: f64,
        scale: Scale,
    ) -> Self {
        Self {
            name,
            doc,
            fit: vec![FitRange {
                name: param,
                lo,
                hi,
                scale,
                side: Side::Either,
            }],
            needs_inputs: Vec::new(),
            replaces_generic: Vec::new(),
        }
    }

    /// The same effect, its parameters moved from the model value to `side` only.
    pub fn toward(mut self, side: Side) -> Self {
        for r in &mut self.fit {
            r.side = side;
        }
        self
    }
}

/// When a row's sample is taken relative to the row's input: the three conventions a
/// record may follow. A plant replays its [`GapPlant::native_timing`] (`Before`, the
/// valve's `After`); [`PlantData::with_timing`] moves records of the other onto it, and a
/// plant with direct feedthrough ([`GapPlant::feedthrough`]) reads `At` itself.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum InputTiming {
    /// The row's input acts from the row's time to the next (zero-order hold) and the
    /// sample was taken just before: an output that follows the input at once still shows
    /// the previous row's input (what `gap-bench` writes).
    #[default]
    Before,
    /// The row's input acts from the row's time to the next, and an output that follows the
    /// input at once already shows it (`y_k = C x_k + D u_k`, the textbook discrete loop).
    At,
    /// The row's input acted over the interval that ends at the row's time, and the sample
    /// was taken after it (the lockstep runner's log).
    After,
}

impl InputTiming {
    /// Every timing, the default first.
    pub const ALL: [InputTiming; 3] = [InputTiming::Before, InputTiming::At, InputTiming::After];

    /// Name as written in the meta file's `input_timing`.
    pub fn name(self) -> &'static str {
        match self {
            InputTiming::Before => "before",
            InputTiming::At => "at",
            InputTiming::After => "after",
        }
    }

    /// The timing written `name`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }

    /// Rows by which a held input is written later than under `Before`.
    pub fn rows_late(self) -> isize {
        match self {
            InputTiming::Before | InputTiming::At => 0,
            InputTiming::After => 1,
        }
    }
}

/// `u` written `rows` rows later (`rows` < 0: earlier), the end rows keeping their own.
pub fn shift_rows(u: &mut Vec<f64>, rows: isize) {
    if u.len() < 2 {
        return;
    }
    if rows > 0 {
        u.pop();
        u.insert(0, u[0]);
    } else if rows < 0 {
        u.remove(0);
        u.push(u[u.len() - 1]);
    }
}

/// Recorded data as the plant sees it: time, inputs by name, measurements by name (NaN =
/// missing sample), truth by name.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlantData {
    /// Time stamps (s), strictly increasing.
    pub t: Vec<f64>,
    /// Nominal sample time (s) from the meta file.
    pub dt: f64,
    /// Input columns `u:<name>` (missing samples hold the previous value).
    pub inputs: BTreeMap<String, Vec<f64>>,
    /// Measurement columns `y:<name>`.
    pub outputs: BTreeMap<String, Vec<f64>>,
    /// Truth columns `x:<name>` (empty for real data).
    pub truth: BTreeMap<String, Vec<f64>>,
    /// Span (s) from the start over which [`PlantData::first_output`] fits a line to pin
    /// the initial condition below the noise (0: the first sample).
    pub initial_window: f64,
    /// Offsets added to [`PlantData::first_output`] (the diagnoser perturbs the initial
    /// condition with them to measure its effect on the replay).
    pub initial_offsets: BTreeMap<String, f64>,
    /// How the rows relate inputs and samples; after [`PlantData::with_timing`] the
    /// plant's native timing, or `At`.
    pub input_timing: InputTiming,
}

impl PlantData {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// An input column, if present.
    pub fn input(&self, name: &str) -> Option<&[f64]> {
        self.inputs.get(name).map(Vec::as_slice)
    }

    /// The data, written under `timing`, as a plant whose replay reads `native` sees them:
    /// every held input (those not in `sampled`, the readings taken at the sample time such
    /// as a measured angle) moves by the rows between the two (a lockstep log read by a
    /// `before` replay: one row earlier, so that row k holds the input acting from t_k on).
    pub fn with_timing(
        &self,
        timing: InputTiming,
        native: InputTiming,
        sampled: &[&str],
    ) -> PlantData {
        let mut data = self.clone();
        data.input_timing = if timing == InputTiming::At {
            InputTiming::At
        } else {
            native
        };
        let rows = native.rows_late() - timing.rows_late();
        for (name, u) in data.inputs.iter_mut() {
            if !sampled.contains(&name.as_str()) {
                shift_rows(u, rows);
            }
        }
        data
    }

    /// A measured column, if present.
    pub fn output(&self, name: &str) -> Option<&[f64]> {
        self.outputs.get(name).map(Vec::as_slice)
    }

    /// Initial value of a measured column for the replay: the intercept at `t[0]` of a
    /// least-squares line through the finite samples of the first `initial_window` seconds
    /// (so the replay does not start off by one noise sample, which a slow plant would carry
    /// through the whole record); the first finite sample when the window holds fewer than 3.
    pub fn first_output(&self, name: &str) -> Option<f64> {
        let offset = self.initial_offsets.get(name).copied().unwrap_or(0.0);
        self.fitted_start(name).map(|v| v + offset)
    }

    fn fitted_start(&self, name: &str) -> Option<f64> {
        let y = self.output(name)?;
        let t0 = *self.t.first()?;
        let pts: Vec<(f64, f64)> = self
            .t
            .iter()
            .zip(y)
            .take_while(|(t, _)| **t - t0 <= self.initial_window)
            .filter(|(_, v)| v.is_finite())
            .map(|(t, v)| (*t - t0, *v))
            .collect();
        if pts.len() < 3 {
            return y.iter().copied().find(|v| v.is_finite());
        }
        let m = pts.len() as f64;
        let (st, sy) = pts.iter().fold((0.0, 0.0), |(a, b), (t, v)| (a + t, b + v));
        let (mt, my) = (st / m, sy / m);
        let (sxy, sxx) = pts.iter().fold((0.0, 0.0), |(a, b), (t, v)| {
            (a + (t - mt) * (v - my), b + (t - mt).powi(2))
        });
        let slope = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        Some(my - slope * mt)
    }
}

/// Parameter values by name (defaults overridden by `[model]`, then by fitted values).
pub type Params = BTreeMap<String, f64>;

/// Looks up a parameter the plant declared (0 if a plant asks for one it did not declare,
/// which its own tests catch).
pub fn param(params: &Params, name: &str) -> f64 {
    params.get(name).copied().unwrap_or(0.0)
}

/// One open-loop replay.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Simulation {
    /// Predicted measurement per output channel, in [`GapPlant::outputs`] order.
    pub outputs: Vec<Vec<f64>>,
    /// Simulated states by name, compared with `x:<name>` truth columns when present.
    pub states: BTreeMap<String, Vec<f64>>,
    /// Per output channel, the variance the replay adds to each reading on top of the
    /// sensor noise, where it predicts a spread rather than a value (a torque ripple whose
    /// phase is unknown); empty or `None` where it predicts values only.
    pub variances: Vec<Option<Vec<f64>>>,
    /// The outputs are one-step predictions that took in the readings before each sample
    /// (a wheel ripple's kicks tracked on the measured speed): their held-out misfit is
    /// that of innovations, and says less of how much the replay explains.
    pub innovations: bool,
}

/// A labelled operating regime: the sample indices that belong to it.
#[derive(Clone, Debug, PartialEq)]
pub struct Regime {
    /// Label, e.g. `low_speed` or `q4(u:command)`.
    pub label: String,
    /// Whether every sample belongs to it (samples may be in several regimes).
    pub mask: Vec<bool>,
}

impl Regime {
    /// The regime `label` of the samples `0..n` where `inside` holds.
    pub fn from_fn(label: &str, n: usize, inside: impl Fn(usize) -> bool) -> Self {
        Self {
            label: label.to_string(),
            mask: (0..n).map(inside).collect(),
        }
    }
}

/// Central-difference derivative of `x` sampled at `t` (one-sided at the ends).
pub fn derivative(t: &[f64], x: &[f64]) -> Vec<f64> {
    let n = x.len().min(t.len());
    (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            if b > a {
                (x[b] - x[a]) / (t[b] - t[a])
            } else {
                0.0
            }
        })
        .collect()
}

/// Integration sub-steps for one sample of length `dt` with steps of at most `max_step`
/// (a replay's accuracy then does not depend on the data's sample rate); at least 1.
pub fn substeps_for(dt: f64, max_step: f64) -> u32 {
    if !(dt > 0.0 && max_step > 0.0) {
        return 1;
    }
    // The tolerance keeps 0.02 / 0.0025 at 8 despite the time stamps' rounding.
    ((dt / max_step) * (1.0 - 1e-9)).ceil().clamp(1.0, 1e6) as u32
}

/// Speed thresholds of [`motion_regimes`] (same unit as the speed, and per second).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionThresholds {
    /// `zero_crossing` below this |speed|.
    pub zero: f64,
    /// `low_speed` below this |speed|.
    pub low: f64,
    /// `high_speed` above this |speed|.
    pub high: f64,
    /// `accelerating` above this |acceleration|, `steady` at or below it.
    pub acceleration: f64,
}

impl MotionThresholds {
    /// Thresholds relative to the largest |speed| and |acceleration| of a replay: 5 %, 20 %
    /// and 70 % of the top speed, 10 % of the top acceleration.
    pub fn relative(speed: &[f64], acceleration: &[f64]) -> Self {
        let top = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(x.abs())).max(1e-9);
        let (w, a) = (top(speed), top(acceleration));
        Self {
            zero: 0.05 * w,
            low: 0.2 * w,
            high: 0.7 * w,
            acceleration: 0.1 * a,
        }
    }
}

/// The regimes of a rotating or moving plant: `zero_crossing`, `low_speed`, `high_speed`,
/// `reverse`, `accelerating`, `steady` (the acceleration from `accel_speed`, typically the
/// replay, which is noise-free).
pub fn motion_regimes(
    t: &[f64],
    speed: &[f64],
    accel_speed: &[f64],
    limits: Option<MotionThresholds>,
) -> Vec<Regime> {
    let n = speed.len();
    let accel = derivative(t, accel_speed);
    let th = limits.unwrap_or_else(|| MotionThresholds::relative(accel_speed, &accel));
    vec![
        Regime::from_fn("zero_crossing", n, |k| speed[k].abs() < th.zero),
        Regime::from_fn("low_speed", n, |k| speed[k].abs() < th.low),
        Regime::from_fn("high_speed", n, |k| speed[k].abs() > th.high),
        Regime::from_fn("reverse", n, |k| speed[k] < 0.0),
        Regime::from_fn("accelerating", n, |k| accel[k].abs() > th.acceleration),
        Regime::from_fn("steady", n, |k| accel[k].abs() <= th.acceleration),
    ]
}

/// A system the gap diagnoser can replay.
pub trait GapPlant: Sync {
    /// Name as written in the meta file's `plant`.
    fn name(&self) -> &'static str;
    /// Every model parameter with its default.
    fn parameters(&self) -> Vec<ParamSpec>;
    /// Input channels the replay needs (`u:<name>`).
    fn required_inputs(&self) -> Vec<&'static str>;
    /// Input channels the replay uses when present, with what for.
    fn optional_inputs(&self) -> Vec<(&'static str, &'static str)> {
        Vec::new()
    }
    /// Measured channels the model predicts (`y:<name>`), in simulation order.
    fn outputs(&self) -> Vec<&'static str>;
    /// The plant's own catalogue of candidate effects.
    fn effects(&self) -> Vec<EffectSpec>;
    /// Replays the inputs open loop with `active` effects on (names from
    /// [`GapPlant::effects`]), starting from the first measurements.
    fn simulate(
        &self,
        params: &Params,
        active: &[&str],
        data: &PlantData,
    ) -> Result<Simulation, String>;
    /// Plant-specific operating regimes (the diagnoser adds generic quantile bins).
    fn regimes(&self, data: &PlantData, nominal: &Simulation) -> Vec<Regime>;

    /// The project's estimator for the plant run over the record (closed loop on the
    /// readings) with the model at `params` and `active` effects, reading the outputs
    /// through `sensors` (one per [`GapPlant::outputs`]; see [`crate::gap::estimate`]): its
    /// state estimates by name, compared with the record's `x:<name>` truth columns.
    /// `None` (the default): the plant has no estimator, and only the replay's error is
    /// reported.
    fn estimate(
        &self,
        _params: &Params,
        _active: &[&str],
        _data: &PlantData,
        _sensors: &Sensors,
    ) -> Option<Result<Estimates, String>> {
        None
    }

    /// Catalogue effects that a model with these parameters already has beside
    /// `sim_effects` (the valve's orifices choke unless `[model]` says they never do);
    /// they are no candidates.
    fn model_effects(&self, _params: &Params) -> Vec<&'static str> {
        Vec::new()
    }

    /// Whether an output follows an input at once (the wheel's current without its
    /// driver lag): only then do [`InputTiming::At`] records differ from `Before` ones, and
    /// the replay must read [`PlantData::input_timing`].
    fn feedthrough(&self) -> bool {
        false
    }

    /// The timing `simulate` reads rows in (the valve's, as progpy writes: `After`); a
    /// record is read in it first.
    fn native_timing(&self) -> InputTiming {
        InputTiming::Before
    }

    /// Inputs that are readings taken at the sample time (a measured angle), not commands
    /// held over the step: [`PlantData::with_timing`] leaves them in their rows.
    fn sampled_inputs(&self) -> Vec<&'static str> {
        Vec::new()
    }

    /// The unit the replay reads each column in (`("y:speed", "rad/s")`, spelt as in
    /// [`crate::gap::units::UNITS`]): a column the meta file's `[units]` gives in another
    /// unit of the same dimension is converted. Empty: columns are read as they are.
    fn units(&self) -> Vec<(&'static str, &'static str)> {
        Vec::new()
    }

    /// The unit of `column` (`u:` or `y:` prefixed), if the plant gives one.
    fn unit_of(&self, column: &str) -> Option<&'static str> {
        self.units()
            .into_iter()
            .find(|(c, _)| *c == column)
            .map(|(_, u)| u)
    }

    /// Span (s) over which the initial condition is fitted from the first samples (see
    /// [`PlantData::first_output`]); 0 for plants whose initial error dies out in a few
    /// samples.
    fn initial_window(&self) -> f64 {
        0.0
    }

    /// Default parameter values as a map.
    fn default_params(&self) -> Params {
        self.parameters()
            .iter()
            .map(|p| (p.name.to_string(), p.default))
            .collect()
    }
}

/// A plant's interface as the meta file and the CSV see it, as Markdown: inputs,
/// outputs, `[model]` parameters with defaults, and its catalogue.
pub fn describe(plant: &dyn GapPlant) -> String {
    let list = |v: Vec<String>| v.join(", ");
    let mut s = format!("### `{}`\n\n", plant.name());
    let column = |c: String| match plant.unit_of(&c) {
        Some("1") => format!("`{c}` (0/1)"),
        Some(unit) => format!("`{c}` in {unit}"),
        None => format!("`{c}`"),
    };
    let optional: Vec<String> = plant
        .optional_inputs()
        .iter()
        .map(|(u, why)| format!("{} ({why})", column(format!("u:{u}"))))
        .collect();
    s.push_str(&format!(
        "- required inputs: {}\n- optional inputs: {}\n- outputs: {}\n- rows read first \
         as `input_timing = \"{}\"`\n\n",
        list(
            plant
                .required_inputs()
                .iter()
                .map(|u| column(format!("u:{u}")))
                .collect()
        ),
        if optional.is_empty() {
            "none".to_string()
        } else {
            list(optional)
        },
        list(
            plant
                .outputs()
                .iter()
                .map(|y| column(format!("y:{y}")))
                .collect()
        ),
        plant.native_timing().name()
    ));
    s.push_str("| `[model]` parameter | default | meaning |\n|---|---|---|\n");
    for p in plant.parameters() {
        s.push_str(&format!("| `{}` | {:?} | {} |\n", p.name, p.default, p.doc));
    }
    s.push_str("\n| effect | fitted parameters | needs inputs | model |\n|---|---|---|---|\n");
    for e in plant.effects() {
        let fitted = e
            .fit
            .iter()
            .map(|r| {
                let side = match r.side {
                    Side::Either => "",
                    Side::BelowModel => ", below the model value",
                    Side::AboveModel => ", above the model value",
                };
                format!("`{}` in [{:?}, {:?}]{side}", r.name, r.lo, r.hi)
            })
            .collect();
        let needs: Vec<String> = e.needs_inputs.iter().map(|u| format!("`u:{u}`")).collect();
        s.push_str(&format!(
            "| `{}` | {} | {} | {} |\n",
            e.name,
            list(fitted),
            if needs.is_empty() {
                "-".to_string()
            } else {
                list(needs)
            },
            e.doc
        ));
    }
    s
}

/// The built-in plant called `name`.
/// Case, blanks and `-` are folded (`Reaction-Wheel` is `reaction_wheel`).
pub fn builtin_plant(name: &str) -> Option<Box<dyn GapPlant>> {
    let folded: String = name
        .trim()
        .chars()
        .map(|c| match c {
            '-' | ' ' => '_',
            c => c.to_ascii_lowercase(),
        })
        .collect();
    match folded.as_str() {
        "reaction_wheel" => Some(Box::new(crate::gap::wheel::WheelGapPlant)),
        "dc_motor" => Some(Box::new(crate::gap::dc_motor::DcMotorPlant)),
        "valve" => Some(Box::new(crate::gap::valve::ValveGapPlant)),
        "scooter" => Some(Box::new(crate::gap::scooter::ScooterGapPlant)),
        _ => None,
    }
}

/// Names of the built-in plants (for error messages).
pub const BUILTIN_PLANTS: &[&str] = &["reaction_wheel", "valve", "scooter", "dc_motor"];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plant_names_fold_case_blanks_and_hyphens() {
        for name in [
            "reaction_wheel",
            "Reaction-Wheel",
            " reaction wheel ",
            "DC_Motor",
        ] {
            let plant = builtin_plant(name).expect(name);
            assert!(BUILTIN_PLANTS.contains(&plant.name()), "{name}");
        }
        assert!(builtin_plant("toaster").is_none());
        assert!(builtin_plant("reactionwheel").is_none());
    }
}
