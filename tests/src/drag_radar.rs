//! The nonlinear scenario of `tests/reference/make_filterpy_reference.py`: a point target
//! with quadratic drag and commanded acceleration, seen by a radar at the origin.
//! State `[px, py, vx, vy]`, input `[ax, ay]`, measurement `[range, bearing]`.

use nalgebra::{SVector, Vector2, Vector4};
use prognos_core::model::{Model, Observe, rk4};

/// Drag target; `drag` is the coefficient c of the acceleration `-c |v| v`.
#[derive(Clone, Copy, Debug)]
pub struct DragRadar {
    pub drag: f64,
}

impl Model<f64, 4, 2> for DragRadar {
    fn step(&self, x: &Vector4<f64>, u: &Vector2<f64>, dt: f64) -> Vector4<f64> {
        let c = self.drag;
        let rhs = |s: &Vector4<f64>| {
            let (vx, vy) = (s[2], s[3]);
            let speed = (vx * vx + vy * vy).sqrt();
            Vector4::new(vx, vy, -c * speed * vx + u[0], -c * speed * vy + u[1])
        };
        rk4(rhs, x, dt, 1)
    }
}

impl Observe<f64, 4, 2, 2> for DragRadar {
    fn observe(&self, x: &Vector4<f64>, _u: &Vector2<f64>) -> SVector<f64, 2> {
        Vector2::new((x[0] * x[0] + x[1] * x[1]).sqrt(), x[1].atan2(x[0]))
    }
}
