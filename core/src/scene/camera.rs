//! The pinhole camera every shader uses (the CPU shader, the reference renderer, the wgpu
//! shader and the viewer): primary rays and the camera basis, defined once.
//!
//! Image coordinates: `px` grows to the right, `py` downwards, row 0 is the top of the image;
//! pixel `(x, y)` covers `[x, x + 1) x [y, y + 1)`, so its centre is `(x + 0.5, y + 0.5)`.
//! `fov_y_degrees` is the full vertical field of view; pixels are square.
//!
//! Anti-aliasing: `samples_per_pixel` is `n^2`, and pixel `(x, y)` averages the rays through
//! the centres of an `n x n` grid of equal cells, `(x + (i + 0.5) / n, y + (j + 0.5) / n)`
//! ([`Camera::sample`]): a box filter, stratified. One sample is the pixel centre.

use crate::error::{CoreError, Result};
use glam::Vec3;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position (world).
    pub position: Vec3,
    /// The point at the image centre (world).
    pub target: Vec3,
    /// Approximate up direction (world); made orthogonal to the view direction.
    pub up: Vec3,
    /// Full vertical field of view in degrees, in (0, 180).
    pub fov_y_degrees: f32,
    pub width: u32,
    pub height: u32,
    /// Rays per pixel, a square `n^2` (1, 4, 9, ... up to [`MAX_SAMPLES_PER_PIXEL`]).
    pub samples_per_pixel: u32,
}

/// The most rays per pixel a camera takes (16 x 16).
pub const MAX_SAMPLES_PER_PIXEL: u32 = 256;

/// `n` for `samples = n^2` rays per pixel, or what is wrong with `samples` (to follow the
/// key's name in a message).
pub fn samples_per_axis_of(samples: u32) -> std::result::Result<u32, String> {
    let n = (samples as f64).sqrt().round() as u32;
    match n >= 1 && n * n == samples && samples <= MAX_SAMPLES_PER_PIXEL {
        true => Ok(n),
        false => Err(format!("must be a square (1, 4, 9, 16, ...) of at most {MAX_SAMPLES_PER_PIXEL}, got {samples}")),
    }
}

impl Camera {
    /// A camera looking at the centre of the box `[min, max]` from the direction given by
    /// `azimuth_degrees` (about +Y; 0 looks from +Z towards -Z, 90 from +X) and
    /// `elevation_degrees` (90 looks straight down), at the distance where the box's bounding
    /// sphere exactly fits the narrower image dimension. The up vector is the derivative of the
    /// viewing direction with respect to elevation, so it is well defined even looking straight
    /// down (then image up is -Z rotated by the azimuth).
    pub fn frame_bounds(
        min: Vec3,
        max: Vec3,
        width: u32,
        height: u32,
        azimuth_degrees: f32,
        elevation_degrees: f32,
        fov_y_degrees: f32,
    ) -> Camera {
        let (min, max) = (min.as_dvec3(), max.as_dvec3());
        let centre = 0.5 * (min + max);
        let radius = 0.5 * (max - min).length();
        let radius = if radius > 0.0 && radius.is_finite() { radius } else { 1.0 };
        let (az, el) = ((azimuth_degrees as f64).to_radians(), (elevation_degrees as f64).to_radians());
        let back = glam::DVec3::new(el.cos() * az.sin(), el.sin(), el.cos() * az.cos());
        let up = glam::DVec3::new(-el.sin() * az.sin(), el.cos(), -el.sin() * az.cos());
        let half_y = (fov_y_degrees as f64).to_radians() * 0.5;
        let aspect = width.max(1) as f64 / height.max(1) as f64;
        let half_x = (half_y.tan() * aspect).atan();
        let distance = radius / half_y.min(half_x).sin();
        Camera {
            position: (centre + back * distance).as_vec3(),
            target: centre.as_vec3(),
            up: up.as_vec3(),
            fov_y_degrees,
            width,
            height,
            samples_per_pixel: 1,
        }
    }

    /// `n`, the side of the pixel's sample grid (`samples_per_pixel = n^2`; 1 if it is not a
    /// square, which [`Camera::validate`] refuses).
    pub fn samples_per_axis(&self) -> u32 {
        samples_per_axis_of(self.samples_per_pixel).unwrap_or(1)
    }

    /// The image position of sample `(i, j)` of pixel `(x, y)`: the centre of cell `(i, j)` of
    /// the pixel's `n x n` grid.
    pub fn sample(&self, x: u32, y: u32, i: u32, j: u32) -> (f32, f32) {
        let n = self.samples_per_axis() as f32;
        (x as f32 + (i as f32 + 0.5) / n, y as f32 + (j as f32 + 0.5) / n)
    }

    /// The camera whose pixels are this camera's samples: `n` times the width and height, one
    /// sample per pixel, same view. Pixel `(n x + i, n y + j)`'s centre is sample `(i, j)` of
    /// pixel `(x, y)` ([`Camera::sample`]), so shading it and box-filtering with
    /// [`crate::scene::Render::box_filtered`] is this camera's anti-aliased image (the GPU
    /// shader's supersampled visibility buffer).
    pub fn supersampled(&self) -> Camera {
        let n = self.samples_per_axis();
        Camera { width: self.width * n, height: self.height * n, samples_per_pixel: 1, ..*self }
    }

    /// Check the camera can produce rays.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(CoreError::Invalid(format!("camera: {m}")));
        if self.width == 0 || self.height == 0 {
            return bad(format!("empty image {}x{}", self.width, self.height));
        }
        if !(self.fov_y_degrees > 0.0 && self.fov_y_degrees < 180.0) {
            return bad(format!("fov_y_degrees must be in (0, 180), got {}", self.fov_y_degrees));
        }
        if !(self.position.is_finite() && self.target.is_finite() && self.up.is_finite()) {
            return bad("non-finite position, target or up".into());
        }
        if (self.target - self.position).length_squared() == 0.0 {
            return bad("position equals target".into());
        }
        if let Err(what) = samples_per_axis_of(self.samples_per_pixel) {
            return bad(format!("samples_per_pixel {what}"));
        }
        Ok(())
    }

    /// Orthonormal `(right, up, forward)` in world space. When `up` is (nearly) parallel to the
    /// viewing direction, the world axis least aligned with it stands in.
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let f = (self.target - self.position).normalize_or(Vec3::NEG_Z);
        let mut r = f.cross(self.up);
        if r.length_squared() < 1e-12 * self.up.length_squared().max(1e-30) || !r.is_finite() {
            let a = f.abs();
            let axis = if a.x <= a.y && a.x <= a.z {
                Vec3::X
            } else if a.y <= a.z {
                Vec3::Y
            } else {
                Vec3::Z
            };
            r = f.cross(axis);
        }
        let r = r.normalize();
        (r, r.cross(f), f)
    }

    /// The primary ray through image point `(px, py)` (pixel centres at `+0.5`, row 0 at the
    /// top): `(origin, unit direction)`.
    pub fn ray(&self, px: f32, py: f32) -> (Vec3, Vec3) {
        self.rays().ray(px, py)
    }

    /// What every primary ray of this camera shares (its basis and the image plane's scale),
    /// worked out once: [`Rays::ray`] is [`Self::ray`] bit for bit, without the basis's
    /// normalisations per ray (a frame of 320x240 at 4 samples makes 307,200 rays).
    pub fn rays(&self) -> Rays {
        let (r, u, f) = self.basis();
        let t = (self.fov_y_degrees.to_radians() * 0.5).tan();
        let (w, h) = (self.width.max(1) as f32, self.height.max(1) as f32);
        Rays { position: self.position, r, u, f, t, w, h }
    }
}

/// A camera's primary rays ([`Camera::rays`]).
#[derive(Clone, Copy, Debug)]
pub struct Rays {
    position: Vec3,
    r: Vec3,
    u: Vec3,
    f: Vec3,
    t: f32,
    w: f32,
    h: f32,
}

impl Rays {
    /// [`Camera::ray`].
    #[inline]
    pub fn ray(&self, px: f32, py: f32) -> (Vec3, Vec3) {
        let Rays { position, r, u, f, t, w, h } = *self;
        let sx = (2.0 * px / w - 1.0) * t * (w / h);
        let sy = (1.0 - 2.0 * py / h) * t;
        (position, (f + r * sx + u * sy).normalize())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_ray_hits_target_and_corners_are_symmetric() {
        let cam = Camera {
            position: Vec3::new(0.0, 0.0, 5.0),
            target: Vec3::ZERO,
            up: Vec3::Y,
            fov_y_degrees: 60.0,
            width: 200,
            height: 100,
            samples_per_pixel: 1,
        };
        cam.validate().unwrap();
        let (o, d) = cam.ray(100.0, 50.0);
        assert_eq!(o, cam.position);
        assert!((d - Vec3::NEG_Z).length() < 1e-6);
        // Top edge centre is fov/2 above the axis; row 0 is the top.
        let (_, top) = cam.ray(100.0, 0.0);
        assert!((top.y / -top.z - 30f32.to_radians().tan()).abs() < 1e-5 && top.y > 0.0);
        // Right edge: tan(half_x) = aspect * tan(half_y); +X is to the right looking down -Z.
        let (_, right) = cam.ray(200.0, 50.0);
        assert!((right.x / -right.z - 2.0 * 30f32.to_radians().tan()).abs() < 1e-5);
        // Pixel centres at +0.5: pixel (0, 0) and pixel (199, 99) are mirror images.
        let (_, a) = cam.ray(0.5, 0.5);
        let (_, b) = cam.ray(199.5, 99.5);
        assert!((a.x + b.x).abs() < 1e-6 && (a.y + b.y).abs() < 1e-6 && (a.z - b.z).abs() < 1e-6);
    }

    #[test]
    fn frame_bounds_fits_the_bounding_sphere() {
        let (min, max) = (Vec3::new(-1.0, 0.0, -2.0), Vec3::new(3.0, 1.0, 0.0));
        let (c, r) = ((min + max) * 0.5, (max - min).length() * 0.5);
        for (w, h, az, el) in
            [(640, 480, 30.0, 20.0), (100, 300, -120.0, 60.0), (64, 64, 0.0, 90.0), (64, 64, 45.0, -90.0)]
        {
            let cam = Camera::frame_bounds(min, max, w, h, az, el, 40.0);
            cam.validate().unwrap();
            let (_, _, f) = cam.basis();
            assert!((cam.target - c).length() < 1e-5);
            // Distance from the bounding sphere's centre to the frustum side planes equals r
            // for the narrower dimension, and is >= r for the other.
            let dist_to_side = |px: f32, py: f32| {
                let (o, d) = cam.ray(px, py);
                // Plane through the eye containing the edge ray and perpendicular to the image
                // axis: its normal is d x (edge direction).
                let (_, d2) = if px == w as f32 * 0.5 { cam.ray(px + 1.0, py) } else { cam.ray(px, py + 1.0) };
                let n = d.cross(d2).normalize();
                (c - o).dot(n).abs()
            };
            let dy = dist_to_side(w as f32 * 0.5, 0.0);
            let dx = dist_to_side(0.0, h as f32 * 0.5);
            let tight = dx.min(dy);
            assert!((tight - r).abs() < 1e-3 * r, "w={w} h={h}: {dx} {dy} vs {r}");
            assert!(dx >= r * 0.999 && dy >= r * 0.999);
            if el == 90.0 {
                assert!((f - Vec3::NEG_Y).length() < 1e-5);
            }
            let el_r = el.to_radians();
            assert!((f.y + el_r.sin()).abs() < 1e-5, "elevation");
        }
        // Azimuth 90 looks from +X.
        let cam = Camera::frame_bounds(Vec3::splat(-1.0), Vec3::ONE, 10, 10, 90.0, 0.0, 40.0);
        assert!(cam.position.x > 1.0 && cam.position.z.abs() < 1e-5);
    }

    #[test]
    fn degenerate_cameras_are_rejected_or_handled() {
        let mut cam = Camera {
            position: Vec3::Y,
            target: Vec3::ZERO,
            up: Vec3::Y,
            fov_y_degrees: 45.0,
            width: 8,
            height: 8,
            samples_per_pixel: 1,
        };
        let (r, u, f) = cam.basis();
        assert!(r.is_normalized() && u.is_normalized() && (f - Vec3::NEG_Y).length() < 1e-6, "up parallel to view");
        cam.width = 0;
        assert!(cam.validate().is_err());
        cam.width = 8;
        cam.fov_y_degrees = 180.0;
        assert!(cam.validate().is_err());
        cam.fov_y_degrees = 45.0;
        cam.target = cam.position;
        assert!(cam.validate().is_err());
    }
}
