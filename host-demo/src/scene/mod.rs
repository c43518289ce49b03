//! Scene representation: triangles and analytic spheres in one CWBVH, materials, area lights
//! and a Mitsuba-style perspective camera.

pub mod bsdf;
pub mod builtin;
pub mod conductors;
pub mod emitter;
pub mod export;
pub mod grid;
pub mod load;
pub mod medium;
pub mod mesh;
pub mod spectrum;
pub mod sunsky;
pub mod texture;

use crate::error::{Error, Result};
use crate::math::{sample_uniform_sphere, Frame, Rng};
use crate::scene::bsdf::Material;
use crate::scene::emitter::{EmitterSample, Environment, PointLight};
use crate::scene::medium::{Medium, MediumInterface, NO_MEDIUM};
use crate::scene::texture::{Param, Texture};
use glam::{Mat4, Vec2, Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::BvhBuildParams;
use std::f32::consts::PI;
use std::time::Duration;

/// The direction handed to the BVH traversal: `d` with exactly-zero components replaced by
/// ±10⁻³⁰ (keeping the zero's sign). obvhs's slab test misses boxes for rays with an exact zero
/// component (`0 · ∞` in the inverse direction; found by the axis-aligned rays of the BVH
/// brute-force test); the nudge moves the ray by at most 10⁻³⁰ per unit length, far below f32
/// resolution, and the primitive tests still use `d` itself.
///
/// Components below 10⁻³⁰ in magnitude (subnormals included, whose inverse overflows to ∞) are
/// nudged the same way, so the inverse direction obvhs computes is always finite.
fn traversal_direction(d: Vec3) -> Vec3 {
    let fix = |x: f32| {
        if x.abs() < 1e-30 {
            1e-30f32.copysign(x)
        } else {
            x
        }
    };
    Vec3::new(fix(d.x), fix(d.y), fix(d.z))
}

/// True if `o + t d` is a ray the BVH can traverse: finite origin and a finite, non-zero
/// direction (a camera or light sample of a degenerate configuration can give a NaN or zero
/// direction; such a ray is treated as a miss rather than reaching obvhs, whose ray
/// constructor asserts finite inverse directions in debug builds).
fn traversable(o: Vec3, d: Vec3) -> bool {
    o.is_finite() && d.is_finite() && d != Vec3::ZERO
}

/// A geometric primitive.
#[derive(Clone, Copy, Debug)]
pub enum Prim {
    /// Triangle with optional per-vertex shading normals. The geometric normal follows the
    /// winding, `(p1 - p0) x (p2 - p0)`.
    Tri {
        /// Vertices.
        p: [Vec3; 3],
        /// Per-vertex shading normals.
        n: Option<[Vec3; 3]>,
    },
    /// Analytic sphere; the normal points outwards unless `flip` (then inwards).
    Sphere {
        /// Centre.
        center: Vec3,
        /// Radius.
        radius: f32,
        /// Normals point inwards.
        flip: bool,
    },
    /// Analytic disk (Mitsuba's `disk`: the unit disk of the local xy plane under an affine
    /// `to_world`, i.e. an ellipse `center + s·a + t·b`, `s² + t² ≤ 1`).
    Disk {
        /// Centre.
        center: Vec3,
        /// Image of the local x axis.
        a: Vec3,
        /// Image of the local y axis.
        b: Vec3,
        /// Unit normal (the transformed local +z, negated by `flip_normals`).
        n: Vec3,
    },
}

/// Local disk coordinates `(s, t)` of `q = p - center` (dual basis of `a`, `b` in their plane).
#[inline]
fn disk_coords(q: Vec3, a: Vec3, b: Vec3) -> (f32, f32) {
    let (aa, ab, bb) = (a.dot(a), a.dot(b), b.dot(b));
    let det = aa * bb - ab * ab;
    let (qa, qb) = (q.dot(a), q.dot(b));
    ((bb * qa - ab * qb) / det, (aa * qb - ab * qa) / det)
}

/// The triangles `a b c` and `a c d` of the quad `[a, b, c, d]` (corners or their uvs).
pub(crate) fn quad_triangles<T: Copy>(q: [T; 4]) -> [[T; 3]; 2] {
    [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
}

impl Prim {
    fn aabb(&self) -> Aabb {
        match *self {
            Prim::Tri { p, .. } => Aabb::from_points(&[p[0].into(), p[1].into(), p[2].into()]),
            Prim::Sphere { center, radius, .. } => Aabb::new(
                Vec3A::from(center - Vec3::splat(radius)),
                Vec3A::from(center + Vec3::splat(radius)),
            ),
            Prim::Disk { center, a, b, .. } => {
                // Extent of an ellipse along each axis: sqrt(a_i² + b_i²).
                let e = (a * a + b * b).map(f32::sqrt);
                Aabb::new(Vec3A::from(center - e), Vec3A::from(center + e))
            }
        }
    }

    /// The primitive under the affine map `m` (normals with the inverse transpose). Fails
    /// for a sphere under a non-uniform scale (it would no longer be a sphere).
    pub fn transformed(&self, m: &Mat4) -> std::result::Result<Prim, String> {
        let nm = glam::Mat3::from_mat4(*m).inverse().transpose();
        let xf_n = |v: Vec3| (nm * v).normalize_or_zero();
        Ok(match *self {
            Prim::Tri { p, n } => Prim::Tri {
                p: p.map(|v| m.transform_point3(v)),
                n: n.map(|n| n.map(xf_n)),
            },
            Prim::Sphere {
                center,
                radius,
                flip,
            } => {
                let axes = [m.x_axis, m.y_axis, m.z_axis].map(|a| a.truncate().length());
                if (axes[0] - axes[1]).abs() > 1e-4 * axes[0]
                    || (axes[0] - axes[2]).abs() > 1e-4 * axes[0]
                {
                    return Err("sphere under a non-uniform scale is not supported".into());
                }
                Prim::Sphere {
                    center: m.transform_point3(center),
                    radius: radius * axes[0],
                    flip,
                }
            }
            Prim::Disk { center, a, b, n } => Prim::Disk {
                center: m.transform_point3(center),
                a: m.transform_vector3(a),
                b: m.transform_vector3(b),
                n: xf_n(n),
            },
        })
    }

    /// Surface area.
    pub fn area(&self) -> f32 {
        match *self {
            Prim::Tri { p, .. } => 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length(),
            Prim::Sphere { radius, .. } => 4.0 * PI * radius * radius,
            Prim::Disk { a, b, .. } => PI * a.cross(b).length(),
        }
    }

    /// Ray intersection; returns `(t, u, v)` for `t` in `(tmin, tmax)`. Public so tests can
    /// check the BVH against a brute-force loop over [`Scene::prims`].
    #[inline]
    pub fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<(f32, f32, f32)> {
        match *self {
            Prim::Tri { p, .. } => {
                // Moller-Trumbore.
                let e1 = p[1] - p[0];
                let e2 = p[2] - p[0];
                let pv = d.cross(e2);
                let det = e1.dot(pv);
                if det.abs() < 1e-12 {
                    return None;
                }
                let inv = 1.0 / det;
                let tv = o - p[0];
                let u = tv.dot(pv) * inv;
                if !(0.0..=1.0).contains(&u) {
                    return None;
                }
                let qv = tv.cross(e1);
                let v = d.dot(qv) * inv;
                if v < 0.0 || u + v > 1.0 {
                    return None;
                }
                let t = e2.dot(qv) * inv;
                (t > tmin && t < tmax).then_some((t, u, v))
            }
            Prim::Sphere { center, radius, .. } => {
                // Numerically robust quadratic (Ray Tracing Gems, ch. 7).
                let f = o - center;
                let b = -f.dot(d);
                let l = f + b * d;
                let disc = radius * radius - l.length_squared();
                if disc < 0.0 {
                    return None;
                }
                let c = f.length_squared() - radius * radius;
                let q = b + b.signum() * disc.sqrt();
                if q == 0.0 {
                    return None;
                }
                let (t0, t1) = {
                    let a = c / q;
                    let b2 = q;
                    if a < b2 {
                        (a, b2)
                    } else {
                        (b2, a)
                    }
                };
                if t0 > tmin && t0 < tmax {
                    Some((t0, 0.0, 0.0))
                } else if t1 > tmin && t1 < tmax {
                    Some((t1, 0.0, 0.0))
                } else {
                    None
                }
            }
            Prim::Disk { center, a, b, n } => {
                let denom = d.dot(n);
                if denom.abs() < 1e-12 {
                    return None;
                }
                let t = (center - o).dot(n) / denom;
                if !(t > tmin && t < tmax) {
                    return None;
                }
                let (s, u) = disk_coords(o + d * t - center, a, b);
                (s * s + u * u <= 1.0).then_some((t, 0.0, 0.0))
            }
        }
    }
}

/// A shape groups primitives that share a material and (optionally) an area emitter.
#[derive(Clone, Debug)]
pub struct Shape {
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// Area emitter radiance, if the shape is a light.
    pub emission: Option<Vec3>,
    /// Opacity of a `mask` BSDF: hits where it is below ½ are skipped by every ray
    /// (camera, bounce and shadow rays alike).
    pub opacity: Option<Param>,
    /// The media on either side, if the shape bounds media (Mitsuba's `interior` /
    /// `exterior`): a ray that crosses it enters [`MediumInterface::target`].
    pub media: Option<MediumInterface>,
}

/// Textured parameters of a material (indices into [`Scene::textures`]); `None` keeps the
/// constant stored in the [`Material`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MaterialTextures {
    /// `reflectance` (diffuse) or `diffuse_reflectance` (plastics, phong, ward).
    pub diffuse: Option<u32>,
    /// `specular_reflectance` (conductor, dielectrics, plastics, phong, ward).
    pub specular: Option<u32>,
    /// `specular_transmittance` (dielectrics).
    pub transmittance: Option<u32>,
    /// A scalar: GGX `alpha` (rough conductor / dielectric) or the `blendbsdf` weight.
    pub scalar: Option<u32>,
}

impl MaterialTextures {
    /// True if nothing is textured.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }
}

/// Local geometry at a ray hit.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceHit {
    /// Hit position.
    pub p: Vec3,
    /// Geometric normal (unit).
    pub ng: Vec3,
    /// Shading normal (unit).
    pub ns: Vec3,
    /// Shape index.
    pub shape: u32,
    /// Primitive index into [`Scene::prims`].
    pub prim: u32,
    /// Distance along the (unit) ray.
    pub t: f32,
    /// Surface texture coordinates.
    pub uv: Vec2,
}

/// Perspective camera with Mitsuba's conventions (local +z forward, image x towards local
/// -x, image y towards local -y): a pinhole, or Mitsuba's `thinlens` when `aperture_radius`
/// is positive.
#[derive(Clone, Copy, Debug)]
pub struct Camera {
    /// Camera-to-world transform.
    pub to_world: Mat4,
    /// tan(fov_x / 2).
    pub tan_x: f32,
    /// tan(fov_y / 2).
    pub tan_y: f32,
    /// Radius of the thin lens (0: pinhole).
    pub aperture_radius: f32,
    /// Distance of the plane in focus along the local z axis (thin lens only).
    pub focus_distance: f32,
}

impl Camera {
    /// Builds a camera from the Mitsuba `fov` (degrees) and `fov_axis` (x, y, smaller, larger).
    pub fn new(
        to_world: Mat4,
        fov_deg: f32,
        fov_axis: &str,
        width: u32,
        height: u32,
    ) -> Result<Self> {
        let aspect = width as f32 / height as f32;
        let t = (fov_deg.to_radians() * 0.5).tan();
        let along_x = match fov_axis {
            "x" => true,
            "y" => false,
            "smaller" => aspect <= 1.0,
            "larger" => aspect > 1.0,
            other => return Err(Error::Scene(format!("unsupported fov_axis \"{other}\""))),
        };
        let (tan_x, tan_y) = if along_x {
            (t, t / aspect)
        } else {
            (t * aspect, t)
        };
        // A field of view so small (or an aspect ratio so extreme) that a half-angle tangent
        // rounds to 0 or overflows gives no image (found by the scene parser's corpus replay:
        // `fov` 1e-39).
        if !(tan_x > 0.0 && tan_x.is_finite() && tan_y > 0.0 && tan_y.is_finite()) {
            return Err(Error::Scene(format!(
                "fov {fov_deg} at {width}x{height} gives no image (tan of the half angles {tan_x}, {tan_y})"
            )));
        }
        Ok(Camera {
            to_world,
            tan_x,
            tan_y,
            aperture_radius: 0.0,
            focus_distance: 1.0,
        })
    }

    /// The same camera with a thin lens (Mitsuba `thinlens`): rays start on a disk of
    /// `aperture_radius` in the lens plane and pass through the point of the pinhole ray at
    /// depth `focus_distance` (local z).
    pub fn with_thin_lens(self, aperture_radius: f32, focus_distance: f32) -> Self {
        Self {
            aperture_radius,
            focus_distance,
            ..self
        }
    }

    /// True if primary rays need a lens sample ([`Camera::ray_lens`]).
    pub fn has_lens(&self) -> bool {
        self.aperture_radius > 0.0
    }

    /// Primary ray through film position `(u, v)` and lens sample `(lu, lv)` in `[0,1)^2`
    /// (a concentric-disk point on the aperture; a pinhole ignores it).
    pub fn ray_lens(&self, u: f32, v: f32, lu: f32, lv: f32) -> (Vec3, Vec3) {
        if !self.has_lens() {
            return self.ray(u, v);
        }
        let dir = Vec3::new(
            (1.0 - 2.0 * u) * self.tan_x,
            (1.0 - 2.0 * v) * self.tan_y,
            1.0,
        );
        let focus = dir * self.focus_distance;
        let (dx, dy) = crate::math::sample_concentric_disk(lu, lv);
        let lens = Vec3::new(dx * self.aperture_radius, dy * self.aperture_radius, 0.0);
        let o = self.to_world.transform_point3(lens);
        let d = self.to_world.transform_vector3(focus - lens).normalize();
        (o, d)
    }

    /// Primary ray through film position `(u, v)` in `[0,1]^2` (top-left origin).
    pub fn ray(&self, u: f32, v: f32) -> (Vec3, Vec3) {
        let local = Vec3::new(
            (1.0 - 2.0 * u) * self.tan_x,
            (1.0 - 2.0 * v) * self.tan_y,
            1.0,
        );
        let o = self.to_world.transform_point3(Vec3::ZERO);
        let d = self.to_world.transform_vector3(local).normalize();
        (o, d)
    }
}

/// Render settings that come with a scene (overridable on the command line).
#[derive(Clone, Copy, Debug)]
pub struct Settings {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Samples per pixel.
    pub spp: u32,
    /// Mitsuba max_depth (1 = directly visible emission only).
    pub max_depth: u32,
    /// Mitsuba rr_depth: with `--rr`, Russian roulette starts at this path depth (default 5).
    pub rr_depth: u32,
}

/// An area light: a shape with emission and an area-weighted CDF over its primitives.
#[derive(Clone, Debug)]
pub struct Light {
    /// Emitted radiance.
    pub radiance: Vec3,
    /// Primitive indices (into `Scene::prims`, BVH order).
    pub prims: Vec<u32>,
    /// Cumulative primitive areas (last = total area).
    pub cdf: Vec<f32>,
    /// Total area.
    pub area: f32,
}

/// A complete renderable scene.
pub struct Scene {
    /// Primitives, in BVH leaf order.
    pub prims: Vec<Prim>,
    /// Shape index of each primitive.
    pub prim_shape: Vec<u32>,
    /// Shapes.
    pub shapes: Vec<Shape>,
    /// Materials.
    pub materials: Vec<Material>,
    /// Area lights.
    pub lights: Vec<Light>,
    /// Light index of each shape (`u32::MAX` if none).
    pub shape_light: Vec<u32>,
    /// Point lights.
    pub point_lights: Vec<PointLight>,
    /// The environment (`constant` or `envmap` emitter), if any.
    pub env: Option<Environment>,
    /// Camera.
    pub camera: Camera,
    /// Default settings.
    pub settings: Settings,
    /// Per-primitive vertex texture coordinates (BVH order); empty when no shape has any
    /// (triangles then use their barycentrics `(b1, b2)` as Mitsuba does).
    pub uvs: Vec<[Vec2; 3]>,
    /// Textures referenced by materials and masks.
    pub textures: Vec<Texture>,
    /// Textured parameters of each material (parallel to `materials`).
    pub material_textures: Vec<MaterialTextures>,
    /// Bytes of decoded texture data (each image counted once).
    pub texture_bytes: usize,
    /// Warnings the loader printed (approximations, ignored elements).
    pub warnings: Vec<String>,
    /// Participating media ([`Shape::media`] and `camera_medium` index them).
    pub media: Vec<Medium>,
    /// The medium the camera sits in ([`NO_MEDIUM`]: vacuum).
    pub camera_medium: u32,
    /// Some shape has a `null` BSDF or bounds a medium: rays may cross surfaces without
    /// scattering and shadow rays carry transmittance ([`Scene::transmittance`]).
    pub has_volumes: bool,
    has_opacity: bool,
    bvh: CwBvh,
}

/// The most `null` surfaces one ray crosses between two scattering events (a ray caught
/// between coincident null surfaces ends there; no published scene comes close).
pub const MAX_NULL_CROSSINGS: u32 = 256;

/// Builder collecting shapes before the BVH is built.
#[derive(Default)]
pub struct SceneBuilder {
    prims: Vec<Prim>,
    prim_shape: Vec<u32>,
    shapes: Vec<Shape>,
    materials: Vec<Material>,
    material_textures: Vec<MaterialTextures>,
    uvs: Vec<[Vec2; 3]>,
    textures: Vec<Texture>,
    point_lights: Vec<PointLight>,
    env: Option<Environment>,
    media: Vec<Medium>,
    camera_medium: Option<u32>,
    /// Bytes of decoded texture data (set by the loader).
    pub texture_bytes: usize,
    /// Loader warnings.
    pub warnings: Vec<String>,
}

/// Texture coordinates of a triangle without any: its barycentrics, `uv = (b1, b2)`.
pub const DEFAULT_TRI_UV: [Vec2; 3] = [Vec2::ZERO, Vec2::X, Vec2::Y];

impl SceneBuilder {
    /// Materials added so far.
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// Textured parameters of the materials added so far.
    pub fn material_textures(&self) -> &[MaterialTextures] {
        &self.material_textures
    }

    /// Adds a participating medium and returns its index.
    pub fn medium(&mut self, m: Medium) -> u32 {
        self.media.push(m);
        self.media.len() as u32 - 1
    }

    /// Media added so far.
    pub fn media(&self) -> &[Medium] {
        &self.media
    }

    /// Makes the last shape added bound media (see [`Shape::media`]).
    pub fn set_last_shape_media(&mut self, media: MediumInterface) {
        if let Some(s) = self.shapes.last_mut() {
            s.media = Some(media);
        }
    }

    /// Puts the camera in medium `m`.
    pub fn set_camera_medium(&mut self, m: u32) {
        self.camera_medium = Some(m);
    }

    /// Adds a material and returns its index.
    pub fn material(&mut self, m: Material) -> u32 {
        self.textured_material(m, MaterialTextures::default())
    }

    /// Adds a material with textured parameters and returns its index.
    pub fn textured_material(&mut self, m: Material, tex: MaterialTextures) -> u32 {
        self.materials.push(m);
        self.material_textures.push(tex);
        (self.materials.len() - 1) as u32
    }

    /// Adds a texture and returns its index.
    pub fn texture(&mut self, t: Texture) -> u32 {
        self.textures.push(t);
        (self.textures.len() - 1) as u32
    }

    /// Textures added so far.
    pub fn textures(&self) -> &[Texture] {
        &self.textures
    }

    /// Adds a shape made of `prims`.
    pub fn shape(&mut self, prims: Vec<Prim>, material: u32, emission: Option<Vec3>) {
        self.shape_with(prims, None, material, emission, None);
    }

    /// Adds a shape with optional per-primitive texture coordinates (one entry per
    /// primitive; ignored for spheres and disks) and an optional `mask` opacity.
    pub fn shape_with(
        &mut self,
        prims: Vec<Prim>,
        uvs: Option<Vec<[Vec2; 3]>>,
        material: u32,
        emission: Option<Vec3>,
        opacity: Option<Param>,
    ) {
        let id = self.shapes.len() as u32;
        self.shapes.push(Shape {
            material,
            emission,
            opacity,
            media: None,
        });
        self.prim_shape.extend(std::iter::repeat_n(id, prims.len()));
        match uvs {
            Some(uv) if uv.len() == prims.len() => {
                self.uvs.resize(self.prims.len(), DEFAULT_TRI_UV);
                self.uvs.extend(uv);
            }
            _ if !self.uvs.is_empty() => {
                self.uvs
                    .resize(self.prims.len() + prims.len(), DEFAULT_TRI_UV);
            }
            _ => {}
        }
        self.prims.extend(prims);
    }

    /// Adds a point light.
    pub fn point_light(&mut self, light: PointLight) {
        self.point_lights.push(light);
    }

    /// Sets the environment; returns `false` (and keeps the first) if one is already set.
    pub fn environment(&mut self, env: Environment) -> bool {
        if self.env.is_some() {
            return false;
        }
        self.env = Some(env);
        true
    }

    /// Adds a quad `a b c d` (counter-clockwise seen from the side its normal points to).
    pub fn quad(&mut self, q: [Vec3; 4], material: u32, emission: Option<Vec3>) {
        let tris = quad_triangles(q).map(|p| Prim::Tri { p, n: None });
        self.shape(tris.to_vec(), material, emission);
    }

    /// Builds the BVH and light tables.
    pub fn build(self, camera: Camera, settings: Settings) -> Result<Scene> {
        if self.prims.is_empty() {
            return Err(Error::Scene("the scene has no shapes".into()));
        }
        for (i, p) in self.prims.iter().enumerate() {
            let ok = match *p {
                Prim::Tri { p, .. } => p.iter().all(|v| v.is_finite()),
                Prim::Sphere { center, radius, .. } => {
                    center.is_finite() && radius.is_finite() && radius > 0.0
                }
                Prim::Disk { center, a, b, n } => {
                    center.is_finite()
                        && n.is_finite()
                        && a.cross(b).length() > 0.0
                        && a.cross(b).is_finite()
                }
            };
            if !ok {
                return Err(Error::Scene(format!(
                    "primitive {i} has non-finite coordinates or a non-positive radius"
                )));
            }
            // Finite coordinates can still overflow the area (|x| ~ 1e19 and beyond), which
            // would turn light pdfs into 0 and radiance estimates into NaN.
            if !p.area().is_finite() {
                return Err(Error::Scene(format!(
                    "primitive {i} is too large (its area overflows f32)"
                )));
            }
        }
        let aabbs: Vec<Aabb> = self.prims.iter().map(Prim::aabb).collect();
        let bvh = obvhs::cwbvh::builder::build_cwbvh(
            &aabbs,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        // Reorder primitives into BVH leaf order so traversal indexes them directly.
        let prims: Vec<Prim> = bvh
            .primitive_indices
            .iter()
            .map(|&i| self.prims[i as usize])
            .collect();
        let prim_shape: Vec<u32> = bvh
            .primitive_indices
            .iter()
            .map(|&i| self.prim_shape[i as usize])
            .collect();
        let uvs: Vec<[Vec2; 3]> = if self.uvs.len() == self.prims.len() {
            bvh.primitive_indices
                .iter()
                .map(|&i| self.uvs[i as usize])
                .collect()
        } else {
            Vec::new()
        };
        let mut shape_light = vec![u32::MAX; self.shapes.len()];
        let mut lights = Vec::new();
        for (s, shape) in self.shapes.iter().enumerate() {
            if let Some(radiance) = shape.emission {
                let mut l = Light {
                    radiance,
                    prims: Vec::new(),
                    cdf: Vec::new(),
                    area: 0.0,
                };
                for (i, p) in prims.iter().enumerate() {
                    if prim_shape[i] as usize == s {
                        l.area += p.area();
                        l.prims.push(i as u32);
                        l.cdf.push(l.area);
                    }
                }
                if !l.area.is_finite() {
                    return Err(Error::Scene(format!(
                        "emitting shape {s} is too large (its total area overflows f32)"
                    )));
                }
                if l.area > 0.0 && radiance.max_element() > 0.0 {
                    shape_light[s] = lights.len() as u32;
                    lights.push(l);
                }
            }
        }
        for (i, m) in self.materials.iter().enumerate() {
            let n = self.materials.len() as u32;
            // Nested materials always come before their wrapper (no cycles).
            match *m {
                Material::TwoSided { front, back } if front >= i as u32 || back >= i as u32 => {
                    return Err(Error::Scene(format!(
                        "material {i}: twosided refers to a missing material"
                    )));
                }
                Material::Blend { a, b, .. } if a >= i as u32 || b >= i as u32 || b >= n => {
                    return Err(Error::Scene(format!(
                        "material {i}: blendbsdf refers to a missing material"
                    )));
                }
                _ => {}
            }
        }
        let nt = self.textures.len() as u32;
        let tex_ok = |t: Option<u32>| t.is_none_or(|t| t < nt);
        for (i, t) in self.material_textures.iter().enumerate() {
            if !(tex_ok(t.diffuse)
                && tex_ok(t.specular)
                && tex_ok(t.transmittance)
                && tex_ok(t.scalar))
            {
                return Err(Error::Scene(format!(
                    "material {i} refers to a missing texture"
                )));
            }
        }
        if self.material_textures.len() != self.materials.len() {
            return Err(Error::Scene("material texture table out of step".into()));
        }
        for s in &self.shapes {
            if s.material as usize >= self.materials.len() {
                return Err(Error::Scene("a shape refers to a missing material".into()));
            }
            if let Some(Param::Tex(t)) = s.opacity {
                if t >= nt {
                    return Err(Error::Scene("a mask refers to a missing texture".into()));
                }
            }
        }
        let nm = self.media.len() as u32;
        let valid = |m: u32| m == NO_MEDIUM || m < nm;
        for s in &self.shapes {
            if let Some(i) = s.media {
                if !(valid(i.interior) && valid(i.exterior)) {
                    return Err(Error::Scene("a shape refers to a missing medium".into()));
                }
            }
        }
        let camera_medium = self.camera_medium.unwrap_or(NO_MEDIUM);
        if !valid(camera_medium) {
            return Err(Error::Scene("the camera refers to a missing medium".into()));
        }
        let has_volumes = self.shapes.iter().any(|s| {
            s.media.is_some() || matches!(self.materials[s.material as usize], Material::Null)
        }) || camera_medium != NO_MEDIUM;
        let has_opacity = self.shapes.iter().any(|s| s.opacity.is_some());
        Ok(Scene {
            prims,
            prim_shape,
            shapes: self.shapes,
            materials: self.materials,
            lights,
            shape_light,
            point_lights: self.point_lights,
            env: self.env,
            camera,
            settings,
            uvs,
            textures: self.textures,
            material_textures: self.material_textures,
            texture_bytes: self.texture_bytes,
            warnings: self.warnings,
            media: self.media,
            camera_medium,
            has_volumes,
            has_opacity,
            bvh,
        })
    }
}

impl Scene {
    /// The diagonal of the region medium `m` fills: the bounding box of the shapes whose
    /// interior it is, or the whole scene's box where it surrounds the camera or lies outside
    /// a shape (it has no bounds of its own there).
    pub fn medium_extent(&self, m: u32) -> f32 {
        let whole = |s: &Self| {
            let (lo, hi) = s.bounds();
            (hi - lo).length()
        };
        if self.camera_medium == m {
            return whole(self);
        }
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for (p, &shape) in self.prims.iter().zip(&self.prim_shape) {
            let Some(mi) = self.shapes[shape as usize].media else {
                continue;
            };
            if mi.exterior == m {
                return whole(self);
            }
            if mi.interior == m {
                let b = p.aabb();
                lo = lo.min(Vec3::from(b.min));
                hi = hi.max(Vec3::from(b.max));
            }
        }
        if lo.cmple(hi).all() {
            (hi - lo).length()
        } else {
            0.0
        }
    }

    /// Axis-aligned bounding box `(min, max)` of every primitive (the guiding grid's box);
    /// `(0, 0)` for an empty scene.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for p in &self.prims {
            let b = p.aabb();
            lo = lo.min(Vec3::from(b.min));
            hi = hi.max(Vec3::from(b.max));
        }
        if lo.cmple(hi).all() {
            (lo, hi)
        } else {
            (Vec3::ZERO, Vec3::ZERO)
        }
    }

    /// Closest hit along the unit-direction ray `o + t d`, `t` in `(tmin, tmax)`.
    /// A ray with a non-finite origin or a non-finite or zero direction misses everything.
    pub fn intersect(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<SurfaceHit> {
        if !traversable(o, d) {
            return None;
        }
        let ray = Ray::new(o.into(), traversal_direction(d).into(), tmin, tmax);
        let mut hit = RayHit::none();
        let mut best = (0.0f32, 0.0f32);
        let found = self.bvh.ray_traverse(ray, &mut hit, |r, id| {
            match self.prims[id].intersect(o, d, r.tmin, r.tmax) {
                Some((t, u, v)) if !self.has_opacity || self.opaque_at(id, o + d * t, u, v) => {
                    best = (u, v);
                    t
                }
                _ => f32::INFINITY,
            }
        });
        if !found {
            return None;
        }
        // `best` holds the (u, v) of the last accepted (= closest) candidate.
        let id = hit.primitive_id as usize;
        let (u, v) = best;
        let p = o + d * hit.t;
        let (ng, ns) = match self.prims[id] {
            Prim::Tri { p: v3, n } => {
                let ng = (v3[1] - v3[0]).cross(v3[2] - v3[0]).normalize_or_zero();
                let ns = match n {
                    Some(n) => (n[0] * (1.0 - u - v) + n[1] * u + n[2] * v).normalize_or(ng),
                    None => ng,
                };
                (ng, ns)
            }
            Prim::Sphere { center, flip, .. } => {
                let n = (p - center).normalize_or_zero();
                let n = if flip { -n } else { n };
                (n, n)
            }
            Prim::Disk { n, .. } => (n, n),
        };
        Some(SurfaceHit {
            p,
            ng,
            ns,
            shape: self.prim_shape[id],
            prim: id as u32,
            t: hit.t,
            uv: self.uv_at(id, p, u, v),
        })
    }

    /// Texture coordinates on primitive `id` at `p` (triangles: barycentrics `(b1, b2)`).
    /// Triangles interpolate their vertex uvs; spheres use Mitsuba's
    /// `(φ / 2π, θ / π)` about the world axes; disks `(r, φ / 2π)`.
    pub fn uv_at(&self, id: usize, p: Vec3, b1: f32, b2: f32) -> Vec2 {
        match self.prims[id] {
            Prim::Tri { .. } => match self.uvs.get(id) {
                Some(t) => t[0] * (1.0 - b1 - b2) + t[1] * b1 + t[2] * b2,
                None => Vec2::new(b1, b2),
            },
            Prim::Sphere { center, .. } => {
                let q = (p - center).normalize_or_zero();
                let phi = q.y.atan2(q.x);
                let phi = if phi < 0.0 { phi + 2.0 * PI } else { phi };
                Vec2::new(phi / (2.0 * PI), q.z.clamp(-1.0, 1.0).acos() / PI)
            }
            Prim::Disk { center, a, b, .. } => {
                let (s, t) = disk_coords(p - center, a, b);
                let phi = t.atan2(s);
                let phi = if phi < 0.0 { phi + 2.0 * PI } else { phi };
                Vec2::new((s * s + t * t).sqrt(), phi / (2.0 * PI))
            }
        }
    }

    /// Value of a parameter at `uv`.
    #[inline]
    pub fn param(&self, p: Param, uv: Vec2) -> Vec3 {
        match p {
            Param::Const(c) => c,
            Param::Tex(t) => self.textures[t as usize].eval(uv),
        }
    }

    /// False where a `mask` makes primitive `id` transparent at `p` (opacity below ½).
    #[inline]
    fn opaque_at(&self, id: usize, p: Vec3, b1: f32, b2: f32) -> bool {
        match self.shapes[self.prim_shape[id] as usize].opacity {
            None => true,
            Some(op) => {
                let v = self.param(op, self.uv_at(id, p, b1, b2));
                v.element_sum() / 3.0 >= 0.5
            }
        }
    }

    /// Resolves the material of a hit for shading: `twosided` picks the side facing `-d`
    /// (flipping the normals on the back), `blendbsdf` picks one component stochastically
    /// with `rng` (`b` with probability `w`), and textured parameters are evaluated at
    /// `uv`. Returns the resolved material index, the concrete material and the normals.
    ///
    /// Stochastic selection is unbiased: the expected BSDF is `(1 − w) f_a + w f_b`, and NEE,
    /// BSDF sampling and their MIS weights all use the one selected component.
    #[allow(clippy::too_many_arguments)] // the hit's geometry plus the random stream
    pub fn resolve_material(
        &self,
        material: u32,
        ng: Vec3,
        ns: Vec3,
        d: Vec3,
        uv: Vec2,
        rng: &mut Rng,
    ) -> (u32, Material, Vec3, Vec3) {
        let (mut id, mut ng, mut ns) = (material, ng, ns);
        // Nested materials always have smaller indices, so this terminates; the bound is a
        // guard only.
        for _ in 0..64 {
            match self.materials[id as usize] {
                Material::TwoSided { front, back } => {
                    if ns.dot(-d) < 0.0 {
                        (id, ng, ns) = (back, -ng, -ns);
                    } else {
                        id = front;
                    }
                }
                Material::Blend { a, b, weight } => {
                    let w = match self.material_textures[id as usize].scalar {
                        Some(t) => self.textures[t as usize].eval_scalar(uv).clamp(0.0, 1.0),
                        None => weight,
                    };
                    id = if rng.next_f32() < w { b } else { a };
                }
                _ => break,
            }
        }
        (id, self.shade(id, uv), ng, ns)
    }

    /// The expected `(f·|cos θo|, pdf)` of material `id` at `uv` over its `blendbsdf`
    /// selections: `Σ P(component) · eval(component)`. This is the BSDF and the sampling
    /// density that [`Scene::resolve_material`] followed by [`Material::sample`] realise
    /// (the chi² test compares them). `twosided` is not looked through (front side only).
    pub fn eval_mixture(&self, id: u32, uv: Vec2, wi: Vec3, wo: Vec3) -> (Vec3, f32) {
        let (mut f, mut pdf) = (Vec3::ZERO, 0.0f32);
        let mut stack = vec![(id, 1.0f32)];
        while let Some((i, p)) = stack.pop() {
            match self.materials[i as usize] {
                Material::Blend { a, b, weight } => {
                    let w = match self.material_textures[i as usize].scalar {
                        Some(t) => self.textures[t as usize].eval_scalar(uv).clamp(0.0, 1.0),
                        None => weight,
                    };
                    stack.push((a, p * (1.0 - w)));
                    stack.push((b, p * w));
                }
                Material::TwoSided { front, .. } => stack.push((front, p)),
                _ => {
                    let (fi, pi) = self.shade(i, uv).eval(wi, wo);
                    f += fi * p;
                    pdf += pi * p;
                }
            }
        }
        (f, pdf)
    }

    /// Material `id` with its textured parameters evaluated at `uv`.
    pub fn shade(&self, id: u32, uv: Vec2) -> Material {
        let mut m = self.materials[id as usize];
        let t = &self.material_textures[id as usize];
        if t.is_empty() {
            return m;
        }
        let tex = |o: Option<u32>, c: Vec3| o.map_or(c, |i| self.textures[i as usize].eval(uv));
        let alpha = |o: Option<u32>, a: f32| {
            o.map_or(a, |i| self.textures[i as usize].eval_scalar(uv).max(1e-4))
        };
        match &mut m {
            Material::Diffuse { reflectance } => *reflectance = tex(t.diffuse, *reflectance),
            Material::RoughDiffuse {
                reflectance,
                alpha: a,
                ..
            } => {
                *reflectance = tex(t.diffuse, *reflectance);
                *a = alpha(t.scalar, *a);
            }
            Material::Conductor { specular, .. } => *specular = tex(t.specular, *specular),
            Material::RoughConductor {
                alpha: a, specular, ..
            } => {
                *a = alpha(t.scalar, *a);
                *specular = tex(t.specular, *specular);
            }
            Material::Dielectric {
                reflectance,
                transmittance,
                ..
            }
            | Material::ThinDielectric {
                reflectance,
                transmittance,
                ..
            } => {
                *reflectance = tex(t.specular, *reflectance);
                *transmittance = tex(t.transmittance, *transmittance);
            }
            Material::RoughDielectric {
                alpha: a,
                reflectance,
                transmittance,
                ..
            } => {
                *a = alpha(t.scalar, *a);
                *reflectance = tex(t.specular, *reflectance);
                *transmittance = tex(t.transmittance, *transmittance);
            }
            Material::Plastic(c) | Material::RoughPlastic(c) => {
                *c = c.with_albedo(tex(t.diffuse, c.diffuse), tex(t.specular, c.specular));
            }
            Material::Phong {
                diffuse, specular, ..
            }
            | Material::Ward {
                diffuse, specular, ..
            } => {
                *diffuse = tex(t.diffuse, *diffuse);
                *specular = tex(t.specular, *specular);
            }
            _ => {}
        }
        m
    }

    /// True if anything blocks the segment `o + t d`, `t` in `(tmin, tmax)` (masked-out
    /// parts of a `mask` BSDF do not block).
    /// A ray with a non-finite origin or a non-finite or zero direction counts as blocked (it
    /// is never traversed, and no light is transported along a direction that does not exist).
    pub fn occluded(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        if !traversable(o, d) {
            return true;
        }
        let ray = Ray::new(o.into(), traversal_direction(d).into(), tmin, tmax);
        !self.bvh.ray_traverse_miss(ray, |r, id| {
            match self.prims[id].intersect(o, d, r.tmin, r.tmax) {
                Some((t, u, v)) if !self.has_opacity || self.opaque_at(id, o + d * t, u, v) => t,
                _ => f32::INFINITY,
            }
        })
    }

    /// True if rays cross shape `shape` without scattering (a `null` BSDF).
    #[inline]
    pub fn is_null(&self, shape: u32) -> bool {
        matches!(
            self.materials[self.shapes[shape as usize].material as usize],
            Material::Null
        )
    }

    /// The transmittance of the shadow ray from `o` along unit `d` over `tmax` (`∞` allowed)
    /// that starts in medium `medium`: zero if a surface that scatters is in the way, else
    /// the product of the media's transmittances ([`Medium::transmittance_along`]: closed form
    /// or ratio tracking with `rng`) over the pieces between the `null` surfaces it
    /// crosses (each crossing of a surface that bounds media moves it into
    /// [`medium::MediumInterface::target`]), as Mitsuba 3's `volpath` evaluates its emitter
    /// samples. Zero after [`MAX_NULL_CROSSINGS`] crossings.
    pub fn transmittance(&self, o: Vec3, d: Vec3, tmax: f32, medium: u32, rng: &mut Rng) -> Vec3 {
        let (mut o, mut left, mut medium, mut tr) = (o, tmax, medium, Vec3::ONE);
        for _ in 0..=MAX_NULL_CROSSINGS {
            let hit = self.intersect(o, d, 0.0, left);
            let piece = hit.as_ref().map_or(left, |h| h.t);
            if let Some(m) = self.media.get(medium as usize) {
                tr *= m.transmittance_along(o, d, piece, rng);
            }
            let Some(h) = hit else {
                return tr;
            };
            if !self.is_null(h.shape) || tr.max_element() <= 0.0 {
                return Vec3::ZERO;
            }
            if let Some(i) = self.shapes[h.shape as usize].media {
                medium = i.target(d, h.ng);
            }
            left -= h.t;
            o = crate::render::wavefront::offset(h.p, h.ng, d);
        }
        Vec3::ZERO
    }

    /// Samples a point uniformly by area on area light `li`: `(point, emitting normal)`.
    fn sample_area(&self, li: usize, u1: f32, u2: f32) -> (Vec3, Vec3) {
        let l = &self.lights[li];
        let target = u1 * l.area;
        let k = l
            .cdf
            .partition_point(|&c| c < target)
            .min(l.prims.len() - 1);
        let lo = if k == 0 { 0.0 } else { l.cdf[k - 1] };
        let width = l.cdf[k] - lo;
        let u1 = if width > 0.0 {
            ((target - lo) / width).clamp(0.0, 1.0)
        } else {
            0.5
        };
        match self.prims[l.prims[k] as usize] {
            Prim::Tri { p, n } => {
                let su = u1.sqrt();
                // Barycentrics: point = p0 (1-b1-b2) + p1 b1 + p2 b2, uniform by area.
                let (b1, b2) = (1.0 - su, u2 * su);
                let pt = p[0] * (1.0 - b1 - b2) + p[1] * b1 + p[2] * b2;
                let ng = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
                let ns = match n {
                    Some(n) => (n[0] * (1.0 - b1 - b2) + n[1] * b1 + n[2] * b2).normalize_or(ng),
                    None => ng,
                };
                (pt, ns)
            }
            Prim::Sphere {
                center,
                radius,
                flip,
            } => {
                let d = sample_uniform_sphere(u1, u2);
                (center + d * radius, if flip { -d } else { d })
            }
            Prim::Disk { center, a, b, n } => {
                // Uniform on the unit disk; the affine map keeps it uniform by area.
                let (x, y) = crate::math::sample_concentric_disk(u1, u2);
                (center + a * x + b * y, n)
            }
        }
    }

    /// Number of emitters: area lights (one per emitting shape), point lights and the
    /// environment. NEE picks one uniformly (as Mitsuba does).
    pub fn emitter_count(&self) -> usize {
        self.lights.len() + self.point_lights.len() + usize::from(self.env.is_some())
    }

    /// True if NEE has something to sample (the NEE stage is skipped otherwise).
    pub fn has_samplable_emitter(&self) -> bool {
        self.emitter_count() > 0
    }

    /// NEE: picks an emitter uniformly with `u0` and samples it from the shading point `p`
    /// (area lights uniformly by area, the environment by its own sampler). `None` if there
    /// is no emitter or the sample is degenerate (behind an area light, zero distance).
    pub fn sample_emitter(&self, p: Vec3, u0: f32, u1: f32, u2: f32) -> Option<EmitterSample> {
        let n = self.emitter_count();
        if n == 0 {
            return None;
        }
        let sel = 1.0 / n as f32;
        let k = ((u0 * n as f32) as usize).min(n - 1);
        if k < self.lights.len() {
            let (lp, ln) = self.sample_area(k, u1, u2);
            let to = lp - p;
            let dist2 = to.length_squared();
            if !(dist2 > 0.0 && dist2.is_finite()) {
                return None;
            }
            let dist = dist2.sqrt();
            let wo = to / dist;
            let cos_l = ln.dot(-wo);
            if cos_l <= 0.0 {
                return None;
            }
            let pdf = sel / self.lights[k].area * dist2 / cos_l;
            return (pdf > 0.0 && pdf.is_finite()).then_some(EmitterSample {
                wo,
                dist,
                p: lp,
                n: ln,
                radiance: self.lights[k].radiance,
                pdf,
                delta: false,
            });
        }
        let k = k - self.lights.len();
        if let Some(pl) = self.point_lights.get(k) {
            let to = pl.position - p;
            let dist2 = to.length_squared();
            if !(dist2 > 0.0 && dist2.is_finite()) {
                return None;
            }
            let dist = dist2.sqrt();
            return Some(EmitterSample {
                wo: to / dist,
                dist,
                p: pl.position,
                n: Vec3::ZERO,
                radiance: pl.intensity / dist2,
                pdf: sel,
                delta: true,
            });
        }
        let env = self.env.as_ref()?;
        let (wo, radiance, pdf) = env.sample(u1, u2)?;
        (pdf > 0.0 && pdf.is_finite()).then_some(EmitterSample {
            wo,
            dist: f32::INFINITY,
            p,
            n: Vec3::ZERO,
            radiance,
            pdf: pdf * sel,
            delta: false,
        })
    }

    /// Area pdf (with selection probability) of sampling a point on the light of `shape`.
    pub fn light_pdf_area(&self, shape: u32) -> f32 {
        let li = self.shape_light[shape as usize];
        if li == u32::MAX {
            return 0.0;
        }
        1.0 / (self.emitter_count() as f32 * self.lights[li as usize].area)
    }

    /// Radiance of the environment seen along `d` (zero without one).
    pub fn env_radiance(&self, d: Vec3) -> Vec3 {
        self.env.as_ref().map_or(Vec3::ZERO, |e| e.eval(d))
    }

    /// Solid-angle pdf (with selection probability) of NEE sampling direction `d` on the
    /// environment.
    pub fn env_pdf(&self, d: Vec3) -> f32 {
        self.env
            .as_ref()
            .map_or(0.0, |e| e.pdf(d) / self.emitter_count() as f32)
    }

    /// Shading frame at a hit.
    pub fn frame(hit: &SurfaceHit) -> Frame {
        Frame::from_z(hit.ns)
    }
}
