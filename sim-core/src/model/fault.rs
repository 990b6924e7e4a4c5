//! Who is at fault in a vehicle–pedestrian collision (docs/MODEL.md 2c; ours, not in the
//! paper): the vehicle is, when the pedestrian stood in its path early enough for it to stop
//! and stayed there, and the vehicle was still moving when they touched.

use crate::geometry::Vec2;

/// Slowest vehicle speed at contact that can make the vehicle at fault, m/s: below it the
/// vehicle has all but stopped, and whoever touches it walked into it.
pub const FAULT_MIN_SPEED: f64 = 0.5;

/// The gap between a vehicle's front face and a pedestrian in its path, m (negative: the
/// pedestrian's disc crosses the front face), or `None` when the pedestrian is not in the path.
///
/// In the vehicle's frame (x forward from its centre, `heading` counter-clockwise from world
/// +x), the pedestrian is in the path when its centre lies ahead of the front face
/// (`x > length / 2`) and within the vehicle's half width plus the pedestrian's radius of the
/// centreline (`|y| < width / 2 + radius`). A pedestrian beside or behind the front face is
/// not in the path: touching the side or the rear is never the vehicle's fault.
pub fn gap_in_path(
    vehicle: Vec2,
    heading: f64,
    length: f64,
    width: f64,
    pedestrian: Vec2,
    radius: f64,
) -> Option<f64> {
    let (s, c) = heading.sin_cos();
    let d = pedestrian - vehicle;
    let x = c * d.x + s * d.y;
    let y = -s * d.x + c * d.y;
    let front = 0.5 * length;
    (x > front && y.abs() < 0.5 * width + radius).then_some(x - front - radius)
}

/// Whether a vehicle at `speed` (m/s) braking at `braking` (m/s², > 0) stops within `gap`
/// metres: `gap >= speed^2 / (2 braking)`.
pub fn room_to_stop(gap: f64, speed: f64, braking: f64) -> bool {
    gap >= speed * speed / (2.0 * braking)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_path_is_the_band_ahead_of_the_front_face() {
        let car = Vec2::new(0.0, 0.0);
        let gap = |x: f64, y: f64| gap_in_path(car, 0.0, 4.0, 1.8, Vec2::new(x, y), 0.3);
        assert!((gap(5.0, 0.0).unwrap() - 2.7).abs() < 1e-12);
        assert!((gap(2.1, 1.1).unwrap() + 0.2).abs() < 1e-12); // touching the front corner
        assert_eq!(gap(2.1, 1.3), None); // beside the front corner
        assert_eq!(gap(1.0, 1.0), None); // at the side
        assert_eq!(gap(-3.0, 0.0), None); // behind
    }

    #[test]
    fn the_path_turns_with_the_heading() {
        let car = Vec2::new(1.0, 1.0);
        let ahead = Vec2::new(1.0, 6.0); // 5 m along +y
        let up = std::f64::consts::FRAC_PI_2;
        assert!((gap_in_path(car, up, 4.0, 1.8, ahead, 0.3).unwrap() - 2.7).abs() < 1e-12);
        assert_eq!(gap_in_path(car, 0.0, 4.0, 1.8, ahead, 0.3), None);
    }

    #[test]
    fn room_to_stop_is_the_braking_distance() {
        assert!(room_to_stop(6.25, 5.0, 2.0));
        assert!(!room_to_stop(6.2, 5.0, 2.0));
        assert!(room_to_stop(0.0, 0.0, 2.0));
    }
}
