//! Agent footprints and the clearance between them (model.md section 1).
//!
//! Pedestrians are discs; a vehicle is an oriented rectangle centred on its position with its long
//! side along the heading, or a disc. Clearance is the gap between two footprints, floored at 0; a
//! collision is clearance `<= 0`.

use nalgebra::Vector2;
use serde::{Deserialize, Serialize};

pub type Vec2 = Vector2<f64>;

/// An agent's footprint.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Shape {
    /// A disc of `radius` metres.
    Disc { radius: f64 },
    /// A rectangle `length` metres along the heading and `width` metres across, centred on the
    /// agent's position.
    Rect { length: f64, width: f64 },
}

impl Shape {
    /// Radius of the smallest disc around the shape's centre that contains it (metres).
    pub fn bounding_radius(&self) -> f64 {
        match *self {
            Shape::Disc { radius } => radius,
            Shape::Rect { length, width } => 0.5 * length.hypot(width),
        }
    }
}

/// A footprint placed in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placed {
    pub shape: Shape,
    pub position: Vec2,
    /// Heading in radians (only matters for rectangles).
    pub heading: f64,
}

/// Signed gap between a disc (centre `c`, radius `r`) and an oriented rectangle: negative when
/// they overlap. Also returns the unit vector from the nearest point of the rectangle towards the
/// disc centre (the direction in which the rectangle pushes the disc).
pub fn disc_rect_gap(
    c: Vec2,
    r: f64,
    rect_pos: Vec2,
    heading: f64,
    length: f64,
    width: f64,
) -> (f64, Vec2) {
    disc_rect_gap_oriented(c, r, rect_pos, heading.sin_cos(), length, width)
}

/// [`disc_rect_gap`] with the rectangle's `heading.sin_cos()` given.
fn disc_rect_gap_oriented(
    c: Vec2,
    r: f64,
    rect_pos: Vec2,
    (s, co): (f64, f64),
    length: f64,
    width: f64,
) -> (f64, Vec2) {
    let d = c - rect_pos;
    // Disc centre in the rectangle's frame (x along the heading).
    let local = Vec2::new(co * d.x + s * d.y, -s * d.x + co * d.y);
    let (hx, hy) = (0.5 * length, 0.5 * width);
    let clamped = Vec2::new(local.x.clamp(-hx, hx), local.y.clamp(-hy, hy));
    let out = local - clamped;
    let out_norm = out.norm();
    let (gap, n_local) = if out_norm > 0.0 {
        (out_norm - r, out / out_norm)
    } else {
        // Centre inside the rectangle: the gap is minus the depth to the nearest side.
        let dx = hx - local.x.abs();
        let dy = hy - local.y.abs();
        if dx < dy {
            (-dx - r, Vec2::new(local.x.signum_or_one(), 0.0))
        } else {
            (-dy - r, Vec2::new(0.0, local.y.signum_or_one()))
        }
    };
    let n = Vec2::new(
        co * n_local.x - s * n_local.y,
        s * n_local.x + co * n_local.y,
    );
    (gap, n)
}

trait SignumOrOne {
    fn signum_or_one(self) -> f64;
}

impl SignumOrOne for f64 {
    fn signum_or_one(self) -> f64 {
        if self < 0.0 {
            -1.0
        } else {
            1.0
        }
    }
}

fn rect_corners(p: &Placed, (s, c): (f64, f64), length: f64, width: f64) -> [Vec2; 4] {
    let ax = Vec2::new(c, s) * (0.5 * length);
    let ay = Vec2::new(-s, c) * (0.5 * width);
    [
        p.position + ax + ay,
        p.position - ax + ay,
        p.position - ax - ay,
        p.position + ax - ay,
    ]
}

fn point_segment_distance(p: Vec2, a: Vec2, b: Vec2) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(&ab) / ab.norm_squared()).clamp(0.0, 1.0);
    (p - (a + ab * t)).norm()
}

fn point_in_convex(p: Vec2, poly: &[Vec2; 4]) -> bool {
    // Corners are counter-clockwise: inside means left of (or on) every edge.
    (0..4).all(|k| {
        let a = poly[k];
        let b = poly[(k + 1) % 4];
        let e = b - a;
        e.x * (p.y - a.y) - e.y * (p.x - a.x) >= 0.0
    })
}

fn segments_intersect(a: Vec2, b: Vec2, c: Vec2, d: Vec2) -> bool {
    let cross = |o: Vec2, p: Vec2, q: Vec2| (p.x - o.x) * (q.y - o.y) - (p.y - o.y) * (q.x - o.x);
    let d1 = cross(c, d, a);
    let d2 = cross(c, d, b);
    let d3 = cross(a, b, c);
    let d4 = cross(a, b, d);
    ((d1 > 0.0) != (d2 > 0.0)) && ((d3 > 0.0) != (d4 > 0.0))
}

/// Gap between two oriented rectangles (0 when they touch or overlap).
fn rect_rect_gap(
    (a, sc_a, la, wa): (&Placed, (f64, f64), f64, f64),
    (b, sc_b, lb, wb): (&Placed, (f64, f64), f64, f64),
) -> f64 {
    let ca = rect_corners(a, sc_a, la, wa);
    let cb = rect_corners(b, sc_b, lb, wb);
    let overlap = ca.iter().any(|p| point_in_convex(*p, &cb))
        || cb.iter().any(|p| point_in_convex(*p, &ca))
        || (0..4).any(|i| {
            (0..4).any(|j| segments_intersect(ca[i], ca[(i + 1) % 4], cb[j], cb[(j + 1) % 4]))
        });
    if overlap {
        return 0.0;
    }
    let mut best = f64::INFINITY;
    for i in 0..4 {
        for k in 0..4 {
            best = best
                .min(point_segment_distance(ca[i], cb[k], cb[(k + 1) % 4]))
                .min(point_segment_distance(cb[i], ca[k], ca[(k + 1) % 4]));
        }
    }
    best
}

/// `1 / dist`, and 1 for coincident centres (`dist` = 0): an unconditional division keeps the
/// loops that call it vectorisable.
#[inline(always)]
pub fn inv_distance(dist: f64) -> f64 {
    1.0 / if dist > 0.0 { dist } else { 1.0 }
}

/// Clearance between two placed footprints in metres, floored at 0 (model.md section 1).
pub fn clearance(a: &Placed, b: &Placed) -> f64 {
    clearance_and_normal(a, b).0
}

/// Clearance between `a` and `b` (floored at 0) and the unit vector pointing from `b` towards `a`
/// (the direction of the repulsive force that `b` exerts on `a`). For a rectangle the direction
/// starts at its nearest point; for coincident centres it is the zero vector.
pub fn clearance_and_normal(a: &Placed, b: &Placed) -> (f64, Vec2) {
    clearance_and_normal_oriented(a, axes(a.shape, a.heading), b, axes(b.shape, b.heading))
}

/// `heading.sin_cos()` for a rectangle, which [`clearance_and_normal_oriented`] needs; any
/// value for a disc, which it ignores.
#[inline]
pub fn axes(shape: Shape, heading: f64) -> (f64, f64) {
    match shape {
        Shape::Rect { .. } => heading.sin_cos(),
        Shape::Disc { .. } => (0.0, 1.0),
    }
}

/// [`clearance_and_normal`] with each footprint's [`axes`] given: for many clearances against
/// one rectangle, whose sine and cosine are then computed once (same results, to the bit).
pub fn clearance_and_normal_oriented(
    a: &Placed,
    axes_a: (f64, f64),
    b: &Placed,
    axes_b: (f64, f64),
) -> (f64, Vec2) {
    let centre_dir = || {
        let d = a.position - b.position;
        let n = d.norm();
        if n > 0.0 {
            d / n
        } else {
            Vec2::zeros()
        }
    };
    match (a.shape, b.shape) {
        (Shape::Disc { radius: ra }, Shape::Disc { radius: rb }) => {
            let d = a.position - b.position;
            let n = d.norm();
            let dir = if n > 0.0 { d / n } else { Vec2::zeros() };
            ((n - (ra + rb)).max(0.0), dir)
        }
        (Shape::Disc { radius }, Shape::Rect { length, width }) => {
            let (gap, n) =
                disc_rect_gap_oriented(a.position, radius, b.position, axes_b, length, width);
            (gap.max(0.0), n)
        }
        (Shape::Rect { length, width }, Shape::Disc { radius }) => {
            let (gap, n) =
                disc_rect_gap_oriented(b.position, radius, a.position, axes_a, length, width);
            (gap.max(0.0), -n)
        }
        (
            Shape::Rect {
                length: la,
                width: wa,
            },
            Shape::Rect {
                length: lb,
                width: wb,
            },
        ) => (
            rect_rect_gap((a, axes_a, la, wa), (b, axes_b, lb, wb)),
            centre_dir(),
        ),
    }
}
