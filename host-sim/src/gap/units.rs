//! The units a meta file's `[units]` may give a column, and their conversion to the unit
//! the plant reads (a speed logged in rpm replayed as rad/s is a sensor scale of 0.105).

/// What a unit measures; units convert only within one dimension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dimension {
    /// A flag or a ratio.
    Dimensionless,
    /// Time.
    Time,
    /// Length or position.
    Length,
    /// Linear speed.
    Velocity,
    /// Angle.
    Angle,
    /// Angular speed.
    AngularVelocity,
    /// Electric current.
    Current,
    /// Voltage.
    Voltage,
    /// Pressure.
    Pressure,
    /// Volume flow.
    VolumeFlow,
    /// Temperature.
    Temperature,
    /// Torque.
    Torque,
    /// Force.
    Force,
}

impl Dimension {
    /// Lower-case name for messages.
    pub fn name(self) -> &'static str {
        match self {
            Dimension::Dimensionless => "dimensionless",
            Dimension::Time => "time",
            Dimension::Length => "length",
            Dimension::Velocity => "speed",
            Dimension::Angle => "angle",
            Dimension::AngularVelocity => "angular speed",
            Dimension::Current => "current",
            Dimension::Voltage => "voltage",
            Dimension::Pressure => "pressure",
            Dimension::VolumeFlow => "volume flow",
            Dimension::Temperature => "temperature",
            Dimension::Torque => "torque",
            Dimension::Force => "force",
        }
    }
}

/// A unit: its value in the SI unit of its dimension is `value * scale + offset`.
#[derive(Clone, Copy, Debug)]
pub struct Unit {
    /// Spellings, after [`normalise`].
    pub names: &'static [&'static str],
    /// Dimension.
    pub dimension: Dimension,
    /// Factor to the SI unit.
    pub scale: f64,
    /// Offset to the SI unit (temperatures only).
    pub offset: f64,
}

const fn unit(names: &'static [&'static str], dimension: Dimension, scale: f64) -> Unit {
    Unit {
        names,
        dimension,
        scale,
        offset: 0.0,
    }
}

const PI: f64 = core::f64::consts::PI;

/// Every unit converted. SI temperature is kelvin.
pub const UNITS: &[Unit] = &[
    unit(
        &["1", "-", "none", "dimensionless", "flag", "bool"],
        Dimension::Dimensionless,
        1.0,
    ),
    unit(&["s", "sec", "second", "seconds"], Dimension::Time, 1.0),
    unit(&["ms"], Dimension::Time, 1e-3),
    unit(
        &["m", "metre", "meter", "metres", "meters"],
        Dimension::Length,
        1.0,
    ),
    unit(&["cm"], Dimension::Length, 1e-2),
    unit(&["mm"], Dimension::Length, 1e-3),
    unit(&["um", "µm", "μm"], Dimension::Length, 1e-6),
    unit(&["in", "inch"], Dimension::Length, 0.0254),
    unit(&["m/s"], Dimension::Velocity, 1.0),
    unit(&["km/h", "kph", "kmh"], Dimension::Velocity, 1.0 / 3.6),
    unit(&["mph"], Dimension::Velocity, 0.44704),
    unit(&["rad", "radian", "radians"], Dimension::Angle, 1.0),
    unit(
        &["deg", "°", "degree", "degrees"],
        Dimension::Angle,
        PI / 180.0,
    ),
    unit(&["rev", "turn"], Dimension::Angle, 2.0 * PI),
    unit(&["rad/s"], Dimension::AngularVelocity, 1.0),
    unit(
        &["rpm", "RPM", "rev/min", "r/min", "1/min"],
        Dimension::AngularVelocity,
        2.0 * PI / 60.0,
    ),
    unit(&["rev/s", "rps"], Dimension::AngularVelocity, 2.0 * PI),
    unit(&["deg/s", "°/s"], Dimension::AngularVelocity, PI / 180.0),
    unit(&["A", "amp", "ampere", "amperes"], Dimension::Current, 1.0),
    unit(&["mA"], Dimension::Current, 1e-3),
    unit(&["uA", "µA", "μA"], Dimension::Current, 1e-6),
    unit(&["V", "volt", "volts"], Dimension::Voltage, 1.0),
    unit(&["mV"], Dimension::Voltage, 1e-3),
    unit(&["kV"], Dimension::Voltage, 1e3),
    unit(&["Pa", "N/m^2"], Dimension::Pressure, 1.0),
    unit(&["hPa", "mbar"], Dimension::Pressure, 1e2),
    unit(&["kPa"], Dimension::Pressure, 1e3),
    unit(&["MPa"], Dimension::Pressure, 1e6),
    unit(&["bar"], Dimension::Pressure, 1e5),
    unit(&["psi"], Dimension::Pressure, 6_894.757_293_168_361),
    unit(&["atm"], Dimension::Pressure, 101_325.0),
    unit(&["m^3/s", "m3/s"], Dimension::VolumeFlow, 1.0),
    unit(&["L/s", "l/s", "dm^3/s"], Dimension::VolumeFlow, 1e-3),
    unit(
        &["L/min", "l/min", "lpm", "LPM"],
        Dimension::VolumeFlow,
        1e-3 / 60.0,
    ),
    unit(
        &["mL/s", "ml/s", "cm^3/s", "cm3/s", "cc/s"],
        Dimension::VolumeFlow,
        1e-6,
    ),
    Unit {
        names: &["K", "kelvin"],
        dimension: Dimension::Temperature,
        scale: 1.0,
        offset: 0.0,
    },
    Unit {
        names: &["degC", "°C", "C", "celsius", "Celsius"],
        dimension: Dimension::Temperature,
        scale: 1.0,
        offset: 273.15,
    },
    Unit {
        names: &["degF", "°F", "F", "fahrenheit", "Fahrenheit"],
        dimension: Dimension::Temperature,
        scale: 5.0 / 9.0,
        offset: 273.15 - 32.0 * 5.0 / 9.0,
    },
    unit(&["Nm", "N.m", "N-m"], Dimension::Torque, 1.0),
    unit(&["mNm", "mN.m"], Dimension::Torque, 1e-3),
    unit(&["N", "newton", "newtons"], Dimension::Force, 1.0),
];

/// A spelling as [`UNITS`] lists it: blanks and multiplication dots dropped, `²`/`³` as
/// `^2`/`^3`, `/sec` as `/s`.
pub fn normalise(name: &str) -> String {
    let mut s: String = name
        .trim()
        .chars()
        .filter(|c| !c.is_whitespace() && *c != '*' && *c != '·' && *c != '⋅')
        .collect();
    s = s.replace('²', "^2").replace('³', "^3");
    if let Some(stem) = s.strip_suffix("/sec") {
        s = format!("{stem}/s");
    }
    s
}

/// The unit spelt `name`, if known.
pub fn lookup(name: &str) -> Option<&'static Unit> {
    let key = normalise(name);
    UNITS.iter().find(|u| u.names.contains(&key.as_str()))
}

/// How a column given in one unit is read in another.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Conversion {
    /// `to = from * scale + offset`.
    Linear {
        /// Factor.
        scale: f64,
        /// Offset.
        offset: f64,
    },
    /// The given unit is not one [`UNITS`] knows (the column is read as it is).
    UnknownUnit,
    /// Both known, of different dimensions.
    Mismatch {
        /// The given unit's dimension.
        given: Dimension,
        /// The plant's.
        wanted: Dimension,
    },
}

/// Conversion of a column given in `given` to the plant's `wanted` (a known unit).
pub fn conversion(given: &str, wanted: &str) -> Conversion {
    let (Some(from), Some(to)) = (lookup(given), lookup(wanted)) else {
        return Conversion::UnknownUnit;
    };
    if from.dimension != to.dimension {
        return Conversion::Mismatch {
            given: from.dimension,
            wanted: to.dimension,
        };
    }
    // from -> SI -> to.
    Conversion::Linear {
        scale: from.scale / to.scale,
        offset: (from.offset - to.offset) / to.scale,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn linear(given: &str, wanted: &str) -> (f64, f64) {
        match conversion(given, wanted) {
            Conversion::Linear { scale, offset } => (scale, offset),
            other => panic!("{given} -> {wanted}: {other:?}"),
        }
    }

    #[test]
    fn units_convert_within_their_dimension() {
        let (s, o) = linear("rpm", "rad/s");
        assert!((3000.0 * s + o - 314.159_265_358_979_3).abs() < 1e-9);
        let (s, o) = linear("bar", "Pa");
        assert_eq!(3.5 * s + o, 350_000.0);
        let (s, o) = linear("°C", "K");
        assert!((20.0 * s + o - 293.15).abs() < 1e-12);
        let (s, o) = linear("K", "degC");
        assert!((293.15 * s + o - 20.0).abs() < 1e-12);
        let (s, o) = linear("degF", "degC");
        assert!((212.0 * s + o - 100.0).abs() < 1e-9);
        let (s, o) = linear("L/min", "m^3/s");
        assert!((60.0 * s + o - 1e-3).abs() < 1e-15);
        let (s, _) = linear("m³/s", "m^3/s");
        assert_eq!(s, 1.0);
        let (s, _) = linear("rad/sec", "rad/s");
        assert_eq!(s, 1.0);
        let (s, _) = linear("N m", "Nm");
        assert_eq!(s, 1.0);
        let (s, _) = linear("mA", "A");
        assert_eq!(s, 1e-3);
        // Case matters where it names a prefix.
        let (s, _) = linear("MPa", "Pa");
        assert_eq!(s, 1e6);
        assert_eq!(conversion("mPa", "Pa"), Conversion::UnknownUnit);
    }

    #[test]
    fn units_of_other_dimensions_or_unknown_do_not_convert() {
        assert_eq!(
            conversion("Pa", "rad/s"),
            Conversion::Mismatch {
                given: Dimension::Pressure,
                wanted: Dimension::AngularVelocity
            }
        );
        assert_eq!(conversion("furlong", "m"), Conversion::UnknownUnit);
    }

    #[test]
    fn every_spelling_is_its_own_normal_form_and_names_one_unit() {
        for u in UNITS {
            for n in u.names {
                assert_eq!(normalise(n), *n);
                let owners = UNITS.iter().filter(|v| v.names.contains(n)).count();
                assert_eq!(owners, 1, "{n}");
            }
        }
    }
}
