//! AV kinematics and the action mapping (model.md section 2).

use crate::geometry::Vec2;
use crate::params::VehicleParams;

/// A physical vehicle command.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VehicleCommand {
    /// Longitudinal acceleration, m/s².
    pub acc: f64,
    /// Yaw rate, rad/s.
    pub omega: f64,
}

/// Maps a normalised action in `[-1, 1]^2` linearly onto `[-acc_max, acc_max] x [-omega_max,
/// omega_max]`. Out-of-range components are clipped first; the flag says whether any was.
pub fn map_action(action: [f64; 2], p: &VehicleParams) -> (VehicleCommand, bool) {
    let a0 = action[0].clamp(-1.0, 1.0);
    let a1 = action[1].clamp(-1.0, 1.0);
    let clipped = a0 != action[0] || a1 != action[1];
    (
        VehicleCommand {
            acc: a0 * p.acc_max,
            omega: a1 * p.omega_max,
        },
        clipped,
    )
}

/// Vehicle state for the unicycle model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UnicycleState {
    pub position: Vec2,
    /// Speed along the heading, m/s (never negative).
    pub speed: f64,
    /// Heading, rad.
    pub heading: f64,
}

/// Semi-implicit unicycle: `speed' = clip(speed + acc dt, 0, speed_max)`,
/// `theta' = theta + omega dt`, `x' = x + speed' (cos theta', sin theta') dt`.
pub fn unicycle_step(
    s: UnicycleState,
    cmd: VehicleCommand,
    dt: f64,
    speed_max: f64,
) -> UnicycleState {
    let speed = (s.speed + cmd.acc * dt).clamp(0.0, speed_max);
    let heading = s.heading + cmd.omega * dt;
    let (sin, cos) = heading.sin_cos();
    UnicycleState {
        position: s.position + Vec2::new(cos, sin) * (speed * dt),
        speed,
        heading,
    }
}

/// Wraps an angle into `(-pi, pi]`.
pub fn wrap_angle(a: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let mut w = a % two_pi;
    if w <= -std::f64::consts::PI {
        w += two_pi;
    } else if w > std::f64::consts::PI {
        w -= two_pi;
    }
    w
}
