//! The fuzz harnesses of `tests/src/fuzz.rs` (the same file, so cargo-fuzz and the stable
//! proptest suite check the same properties) with the two test models they use, without the
//! rest of `prognos-tests` (which pulls in the host simulator).
#![forbid(unsafe_code)]

#[path = "../../tests/src/drag_radar.rs"]
pub mod drag_radar;
#[path = "../../tests/src/fuzz.rs"]
pub mod fuzz;
#[path = "../../tests/src/linear_gaussian.rs"]
pub mod linear_gaussian;

/// Runs `harness` on fuzzer bytes; a violated property is a crash with its description.
pub fn run(bytes: &[u8], harness: impl Fn(&mut fuzz::Feed<'_>) -> Result<(), String>) {
    let values = fuzz::Feed::decode(bytes);
    if let Err(violation) = harness(&mut fuzz::Feed::new(&values)) {
        panic!("property violated: {violation}");
    }
}
