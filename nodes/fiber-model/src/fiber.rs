//! Fibre geometry and state (paper §2.1): a chain of N rigid cylindrical segments joined
//! by ball-and-socket joints, with per-segment mass and inertia of a solid cylinder.

use crate::error::FiberError;
use crate::hydro::SegmentShape;
use nalgebra::{Matrix3, Vector3};

/// Kinematic state of one segment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Centre of mass r_i (unwrapped: periodic directions are never folded).
    pub r: Vector3<f64>,
    /// Unit axis ẑ_i.
    pub z: Vector3<f64>,
    /// Velocity ṙ_i.
    pub v: Vector3<f64>,
    /// Angular velocity ω_i.
    pub w: Vector3<f64>,
    /// Material normal n_i ⊥ ẑ_i, carried with the segment's rotation; it measures twist.
    pub n: Vector3<f64>,
    /// Hydrodynamic force of the last step, F^h_i = A_i·(v(r_i) − ṙ_i) at the new velocity
    /// (eq. 4, viscous and inertial drag as the step used them; gravity not included):
    /// what two-way coupling returns to the fluid, reversed. Zero before the first step.
    pub f: Vector3<f64>,
}

/// Fixed properties of one segment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentProps {
    pub shape: SegmentShape,
    pub mass: f64,
    /// Moment of inertia about the axis (m R²/2) and about a diameter (m(3R² + l²)/12).
    pub inertia_axial: f64,
    pub inertia_perp: f64,
}

/// Segments as messages and checkpoints carry them: flat arrays of 3 values per segment,
/// fibre-major.
#[derive(Debug, Clone, Copy)]
pub struct FlatSegments<'a> {
    pub centre: &'a [f64],
    pub axis: &'a [f64],
    pub velocity: &'a [f64],
    pub angular_velocity: &'a [f64],
    pub normal: &'a [f64],
}

impl FlatSegments<'_> {
    /// Segment `j`, with hydrodynamic force `f` (the arrays' lengths are the caller's to
    /// check).
    pub fn get(&self, j: usize, f: Vector3<f64>) -> Segment {
        let v = |a: &[f64]| Vector3::new(a[3 * j], a[3 * j + 1], a[3 * j + 2]);
        Segment {
            r: v(self.centre),
            z: v(self.axis),
            v: v(self.velocity),
            w: v(self.angular_velocity),
            n: v(self.normal),
            f,
        }
    }
}

impl SegmentProps {
    pub fn new(length: f64, diameter: f64, density: f64) -> Self {
        let r = 0.5 * diameter;
        let mass = density * std::f64::consts::PI * r * r * length;
        Self {
            shape: SegmentShape::new(length, diameter),
            mass,
            inertia_axial: 0.5 * mass * r * r,
            inertia_perp: mass * (3.0 * r * r + length * length) / 12.0,
        }
    }

    /// Inertia tensor in the global frame, I = I⊥ δ + (I∥ − I⊥) ẑẑ.
    pub fn inertia(&self, z: &Vector3<f64>) -> Matrix3<f64> {
        self.inertia_perp * Matrix3::identity()
            + (self.inertia_axial - self.inertia_perp) * (z * z.transpose())
    }
}

/// One fibre: its segments and their properties.
#[derive(Debug, Clone, PartialEq)]
pub struct Fiber {
    pub segments: Vec<Segment>,
    pub props: Vec<SegmentProps>,
    /// Density of the fibre material.
    pub density: f64,
}

impl Fiber {
    /// A straight fibre centred at `centre` along `axis`, with the given segment lengths
    /// and diameters; velocities zero.
    pub fn straight(
        centre: Vector3<f64>,
        axis: Vector3<f64>,
        lengths: &[f64],
        diameters: &[f64],
        density: f64,
    ) -> Result<Self, FiberError> {
        let n = lengths.len();
        if n == 0 {
            return Err(FiberError::Config(
                "fibre.segments must be >= 1 (got 0)".into(),
            ));
        }
        if diameters.len() != n {
            return Err(FiberError::Config(format!(
                "fibre.diameters has {} entries, fibre.lengths has {n}",
                diameters.len()
            )));
        }
        if !(density > 0.0 && density.is_finite()) {
            return Err(FiberError::Config(format!(
                "fibre.density must be positive and finite (got {density})"
            )));
        }
        for (i, (&l, &d)) in lengths.iter().zip(diameters).enumerate() {
            if !(d > 0.0 && d.is_finite()) {
                return Err(FiberError::Config(format!(
                    "fibre.diameter of segment {i} must be positive and finite (got {d})"
                )));
            }
            if !(l > d && l.is_finite()) {
                return Err(FiberError::Config(format!(
                    "fibre.length of segment {i} must exceed its diameter {d} (got {l})"
                )));
            }
        }
        let norm = axis.norm();
        if !(norm > 0.0 && norm.is_finite()) {
            return Err(FiberError::Config(
                "fibre axis must be a non-zero finite vector".into(),
            ));
        }
        let z = axis / norm;
        // any unit vector normal to the axis (the same for every segment: no initial twist)
        let helper = if z.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let normal = (helper - z * z.dot(&helper)).normalize();
        let total: f64 = lengths.iter().sum();
        let mut s = -0.5 * total;
        let mut segments = Vec::with_capacity(n);
        for &l in lengths {
            segments.push(Segment {
                r: centre + (s + 0.5 * l) * z,
                z,
                v: Vector3::zeros(),
                w: Vector3::zeros(),
                n: normal,
                f: Vector3::zeros(),
            });
            s += l;
        }
        let props = lengths
            .iter()
            .zip(diameters)
            .map(|(&l, &d)| SegmentProps::new(l, d, density))
            .collect();
        Ok(Self {
            segments,
            props,
            density,
        })
    }

    pub fn len(&self) -> usize {
        self.segments.len()
    }

    pub fn is_empty(&self) -> bool {
        self.segments.is_empty()
    }

    /// Joint positions: the N+1 segment end points, start of segment 0 first.
    pub fn joints(&self) -> Vec<Vector3<f64>> {
        let mut out = Vec::with_capacity(self.len() + 1);
        for (s, p) in self.segments.iter().zip(&self.props) {
            out.push(s.r - 0.5 * p.shape.length * s.z);
        }
        if let (Some(s), Some(p)) = (self.segments.last(), self.props.last()) {
            out.push(s.r + 0.5 * p.shape.length * s.z);
        }
        out
    }

    /// Largest gap between the end of one segment and the start of the next (eq. 2).
    pub fn max_joint_gap(&self) -> f64 {
        let mut m: f64 = 0.0;
        for i in 0..self.len().saturating_sub(1) {
            let a = self.segments[i].r + 0.5 * self.props[i].shape.length * self.segments[i].z;
            let b = self.segments[i + 1].r
                - 0.5 * self.props[i + 1].shape.length * self.segments[i + 1].z;
            m = m.max((a - b).norm());
        }
        m
    }

    /// Re-chains the segments outward from the fixed middle segment so that every joint
    /// coincides (paper §2.5: the middle segment is fixed, the others translated).
    pub fn rechain(&mut self) {
        let n = self.len();
        let m = (n - 1) / 2;
        for i in m + 1..n {
            let prev = self.segments[i - 1];
            let hp = 0.5 * self.props[i - 1].shape.length;
            let h = 0.5 * self.props[i].shape.length;
            self.segments[i].r = prev.r + hp * prev.z + h * self.segments[i].z;
        }
        for i in (0..m).rev() {
            let next = self.segments[i + 1];
            let hn = 0.5 * self.props[i + 1].shape.length;
            let h = 0.5 * self.props[i].shape.length;
            self.segments[i].r = next.r - hn * next.z - h * self.segments[i].z;
        }
    }

    /// Twist angle across joint k (between segments k and k+1): the angle about ẑ_{k+1}
    /// between n_{k+1} and n_k parallel-transported onto segment k+1.
    pub fn twist(&self, k: usize) -> f64 {
        let (a, b) = (&self.segments[k], &self.segments[k + 1]);
        let moved = parallel_transport(&a.z, &b.z, &a.n);
        let t = moved.cross(&b.n).dot(&b.z);
        t.atan2(moved.dot(&b.n))
    }

    /// Total mass.
    pub fn mass(&self) -> f64 {
        self.props.iter().map(|p| p.mass).sum()
    }
}

/// Rotates `v` by the minimal rotation that takes unit vector `from` onto `to`.
pub fn parallel_transport(
    from: &Vector3<f64>,
    to: &Vector3<f64>,
    v: &Vector3<f64>,
) -> Vector3<f64> {
    let axis = from.cross(to);
    let s = axis.norm();
    let c = from.dot(to);
    if s < 1e-15 {
        return *v;
    }
    let k = axis / s;
    v * c + k.cross(v) * s + k * (k.dot(v) * (1.0 - c))
}
