//! The viewer's orbit camera: a point on a sphere around a target, +Y up, in the azimuth /
//! elevation convention of `shading::camera::Camera::frame_bounds` (azimuth 0 looks down -Z
//! from +Z, positive azimuth moves the eye towards +X), so the config's camera and the viewer's
//! agree.

use biscale_core::scene::Camera;
use glam::{DVec3, Vec3};

/// Elevation stays this far (radians) from the poles while dragging, so the view never flips.
const POLE_MARGIN: f64 = 1e-3;

/// Orbit state; [`Self::camera`] turns it into a [`Camera`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    pub target: Vec3,
    /// Eye distance from the target.
    pub distance: f64,
    pub azimuth: f64,
    pub elevation: f64,
    pub fov_y_degrees: f32,
}

impl Orbit {
    /// The orbit through `camera`'s position around its target (its `up` is replaced by the
    /// orbit's own, which is +Y tilted with the elevation as `frame_bounds` builds it).
    pub fn from_camera(camera: &Camera) -> Self {
        let back = (camera.position - camera.target).as_dvec3();
        let distance = back.length();
        let (azimuth, elevation) = if distance > 0.0 {
            let b = back / distance;
            (b.x.atan2(b.z), b.y.clamp(-1.0, 1.0).asin())
        } else {
            (0.0, 0.0)
        };
        Self {
            target: camera.target,
            distance: if distance > 0.0 && distance.is_finite() { distance } else { 1.0 },
            azimuth,
            elevation,
            fov_y_degrees: camera.fov_y_degrees,
        }
    }

    /// The camera of this orbit for a `width x height` image.
    pub fn camera(&self, width: u32, height: u32) -> Camera {
        let (az, el) = (self.azimuth, self.elevation);
        let back = DVec3::new(el.cos() * az.sin(), el.sin(), el.cos() * az.cos());
        let up = DVec3::new(-el.sin() * az.sin(), el.cos(), -el.sin() * az.cos());
        Camera {
            position: self.target + (back * self.distance).as_vec3(),
            target: self.target,
            up: up.as_vec3(),
            fov_y_degrees: self.fov_y_degrees,
            width: width.max(1),
            height: height.max(1),
            samples_per_pixel: 1,
        }
    }

    /// Turn by a mouse drag of `(dx, dy)` pixels in a window `height` pixels tall: a drag
    /// across the full height turns by 180 degrees; dragging right moves the eye left around
    /// the target (the object follows the mouse), dragging down raises the eye.
    pub fn drag(&mut self, dx: f64, dy: f64, height: u32) {
        let k = std::f64::consts::PI / height.max(1) as f64;
        self.azimuth = (self.azimuth - dx * k).rem_euclid(std::f64::consts::TAU);
        let limit = std::f64::consts::FRAC_PI_2 - POLE_MARGIN;
        self.elevation = (self.elevation + dy * k).clamp(-limit, limit);
    }

    /// Zoom by `steps` wheel notches (positive: closer), 10 % of the distance per notch,
    /// never closer than `min_distance`.
    pub fn zoom(&mut self, steps: f64, min_distance: f64) {
        self.distance = (self.distance * 0.9f64.powf(steps)).max(min_distance);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(position: Vec3, target: Vec3) -> Camera {
        Camera { position, target, up: Vec3::Y, fov_y_degrees: 30.0, width: 64, height: 48, samples_per_pixel: 1 }
    }

    #[test]
    fn from_camera_round_trips_position_and_target() {
        for (p, t) in [
            (Vec3::new(1.0, 2.0, 3.0), Vec3::ZERO),
            (Vec3::new(-4.0, -1.0, 0.5), Vec3::new(0.3, 0.2, -0.1)),
            (Vec3::new(0.0, 0.0, -2.0), Vec3::ZERO),
        ] {
            let c = Orbit::from_camera(&cam(p, t)).camera(64, 48);
            // f32 positions of magnitude <= 5 through f64 trigonometry: a few f32 ulps.
            assert!((c.position - p).length() < 1e-5, "{:?} vs {p:?}", c.position);
            assert_eq!(c.target, t);
            // The orbit's up is orthogonal to the view direction and points upwards.
            let f = (c.target - c.position).normalize();
            assert!(c.up.dot(f).abs() < 1e-5 && c.up.y > 0.0);
        }
    }

    #[test]
    fn matches_frame_bounds_convention() {
        // frame_bounds: back = (cos el sin az, sin el, cos el cos az). Azimuth 90 degrees,
        // elevation 0 puts the eye on +X.
        let o = Orbit {
            target: Vec3::ZERO,
            distance: 2.0,
            azimuth: 90f64.to_radians(),
            elevation: 0.0,
            fov_y_degrees: 30.0,
        };
        let c = o.camera(10, 10);
        assert!((c.position - Vec3::new(2.0, 0.0, 0.0)).length() < 1e-6);
    }

    #[test]
    fn drag_turns_and_clamps_at_the_poles() {
        let mut o = Orbit { target: Vec3::ZERO, distance: 1.0, azimuth: 0.0, elevation: 0.0, fov_y_degrees: 30.0 };
        // Half the height to the left = +90 degrees of azimuth.
        o.drag(-50.0, 0.0, 100);
        assert!((o.azimuth - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        o.drag(0.0, 1e6, 100);
        assert!(o.elevation < std::f64::consts::FRAC_PI_2 && o.elevation > 1.5);
        let c = o.camera(10, 10);
        assert!(c.position.is_finite() && c.up.is_finite());
        // Still a usable camera basis (not parallel up and view direction).
        let f = (c.target - c.position).normalize();
        assert!(f.cross(c.up).length() > 0.5);
    }

    #[test]
    fn zoom_scales_distance_and_respects_the_minimum() {
        let mut o = Orbit { target: Vec3::ZERO, distance: 1.0, azimuth: 0.0, elevation: 0.0, fov_y_degrees: 30.0 };
        o.zoom(2.0, 0.01);
        assert!((o.distance - 0.81).abs() < 1e-12);
        o.zoom(-1.0, 0.01);
        assert!((o.distance - 0.9).abs() < 1e-12);
        o.zoom(1000.0, 0.01);
        assert_eq!(o.distance, 0.01);
    }
}
