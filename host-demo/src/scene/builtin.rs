//! Scenes constructed in code: `builtin:cornell-box`, `builtin:furnace`, `builtin:door`.

use crate::error::{Error, Result};
use crate::scene::bsdf::Material;
use crate::scene::{Camera, Prim, Scene, SceneBuilder, Settings};
use glam::{Mat4, Vec3};

/// Names accepted after `builtin:`.
pub const BUILTIN_NAMES: [&str; 3] = ["cornell-box", "furnace", "door"];

/// Albedo of the furnace sphere.
pub const FURNACE_ALBEDO: f32 = 0.5;

/// Analytic pixel value of `builtin:furnace` for a Mitsuba `max_depth` `d`:
/// every camera ray hits the inside of a sphere with radiance 1 and albedo rho, and every
/// bounce hits it again, so `L = sum_{k=0}^{d-1} rho^k = (1 - rho^d) / (1 - rho)`
/// (-> `1 / (1 - rho)` as `d -> inf`).
pub fn furnace_expected(max_depth: u32) -> f64 {
    let rho = FURNACE_ALBEDO as f64;
    (1.0 - rho.powi(max_depth.min(100_000) as i32)) / (1.0 - rho)
}

/// Builds a built-in scene by name.
pub fn load_builtin(name: &str) -> Result<Scene> {
    match name {
        "cornell-box" => cornell_box(),
        "furnace" => furnace(),
        "door" => door(),
        _ => Err(Error::Scene(format!(
            "unknown built-in scene \"{name}\" (have: {})",
            BUILTIN_NAMES.join(", ")
        ))),
    }
}

/// Adds a planar quad whose winding is fixed so its normal points along `facing`.
fn quad(b: &mut SceneBuilder, mut q: [Vec3; 4], facing: Vec3, mat: u32, emission: Option<Vec3>) {
    if (q[1] - q[0]).cross(q[2] - q[0]).dot(facing) < 0.0 {
        q.reverse();
    }
    b.quad(q, mat, emission);
}

/// Axis-aligned quad helper: `axis` is the constant coordinate (0=x,1=y,2=z) at `c`, spanning
/// `[a0,a1] x [b0,b1]` over the other two axes in cyclic order.
#[allow(clippy::too_many_arguments)] // a private geometry helper; a struct would only add noise
fn aa_quad(
    b: &mut SceneBuilder,
    axis: usize,
    c: f32,
    r0: (f32, f32),
    r1: (f32, f32),
    facing: f32,
    mat: u32,
    em: Option<Vec3>,
) {
    let mk = |u: f32, v: f32| {
        let mut p = [0.0; 3];
        p[axis] = c;
        p[(axis + 1) % 3] = u;
        p[(axis + 2) % 3] = v;
        Vec3::from(p)
    };
    let q = [
        mk(r0.0, r1.0),
        mk(r0.1, r1.0),
        mk(r0.1, r1.1),
        mk(r0.0, r1.1),
    ];
    let mut f = [0.0; 3];
    f[axis] = facing;
    quad(b, q, Vec3::from(f), mat, em);
}

/// Vertical box from a footprint (4 corners at y = 0) and a height; faces point outwards.
fn boxx(b: &mut SceneBuilder, foot: [(f32, f32); 4], h: f32, mat: u32) {
    let lo = foot.map(|(x, z)| Vec3::new(x, 0.0, z));
    let hi = foot.map(|(x, z)| Vec3::new(x, h, z));
    let c = (lo[0] + lo[1] + lo[2] + lo[3]) * 0.25 + Vec3::Y * h * 0.5;
    let mut faces = vec![hi, lo];
    for i in 0..4 {
        let j = (i + 1) % 4;
        faces.push([lo[i], lo[j], hi[j], hi[i]]);
    }
    for f in faces {
        let fc = (f[0] + f[1] + f[2] + f[3]) * 0.25;
        quad(b, f, fc - c, mat, None);
    }
}

/// Mitsuba's `lookat` transform.
pub fn look_at(origin: Vec3, target: Vec3, up: Vec3) -> Mat4 {
    let dir = (target - origin).normalize();
    let left = up.cross(dir).normalize();
    let new_up = dir.cross(left);
    Mat4::from_cols(
        left.extend(0.0),
        new_up.extend(0.0),
        dir.extend(0.0),
        origin.extend(1.0),
    )
}

/// The Cornell box of `shared/scenes/cornell-box` (Bitterli's version), built from quads.
pub fn cornell_box() -> Result<Scene> {
    let mut b = SceneBuilder::default();
    let white = b.material(Material::Diffuse {
        reflectance: Vec3::new(0.725, 0.71, 0.68),
    });
    let red = b.material(Material::Diffuse {
        reflectance: Vec3::new(0.63, 0.065, 0.05),
    });
    let green = b.material(Material::Diffuse {
        reflectance: Vec3::new(0.14, 0.45, 0.091),
    });
    let black = b.material(Material::Diffuse {
        reflectance: Vec3::ZERO,
    });
    aa_quad(&mut b, 1, 0.0, (-1.0, 1.0), (-1.0, 1.0), 1.0, white, None); // floor
    aa_quad(&mut b, 1, 2.0, (-1.0, 1.0), (-1.0, 1.0), -1.0, white, None); // ceiling
    aa_quad(&mut b, 2, -1.0, (-1.0, 1.0), (0.0, 2.0), 1.0, white, None); // back
    aa_quad(&mut b, 0, 1.0, (0.0, 2.0), (-1.0, 1.0), -1.0, green, None); // right (x = +1)
    aa_quad(&mut b, 0, -1.0, (0.0, 2.0), (-1.0, 1.0), 1.0, red, None); // left (x = -1)
    boxx(
        &mut b,
        [
            (-0.0460751, 0.573007),
            (0.124253, 0.00310463),
            (0.703337, 0.176177),
            (0.533009, 0.746079),
        ],
        0.6,
        white,
    );
    boxx(
        &mut b,
        [
            (-0.720444, -0.473882),
            (-0.146892, -0.673479),
            (0.0495656, -0.108948),
            (-0.523986, 0.0906493),
        ],
        1.2,
        white,
    );
    aa_quad(
        &mut b,
        1,
        1.98,
        (-0.22, 0.16),
        (-0.24, 0.23),
        -1.0,
        black,
        Some(Vec3::new(17.0, 12.0, 4.0)),
    );
    let to_world = Mat4::from_cols_array(&[
        -1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 6.8, 1.0,
    ]);
    let camera = Camera::new(to_world, 19.5, "smaller", 256, 256)?;
    b.build(
        camera,
        Settings {
            width: 256,
            height: 256,
            spp: 64,
            max_depth: 8,
            rr_depth: 5,
        },
    )
}

/// White furnace: the camera sits inside a sphere (radius 1, normals inwards) that both emits
/// radiance 1 and reflects diffusely with albedo [`FURNACE_ALBEDO`]. Every pixel equals
/// [`furnace_expected`]`(max_depth)` exactly; BSDF sampling alone is noise-free here, NEE+MIS is
/// unbiased but noisy, which makes it a good MIS-weight check.
pub fn furnace() -> Result<Scene> {
    let mut b = SceneBuilder::default();
    let m = b.material(Material::Diffuse {
        reflectance: Vec3::splat(FURNACE_ALBEDO),
    });
    b.shape(
        vec![Prim::Sphere {
            center: Vec3::ZERO,
            radius: 1.0,
            flip: true,
        }],
        m,
        Some(Vec3::ONE),
    );
    let camera = Camera::new(
        look_at(Vec3::new(0.0, 0.0, -0.5), Vec3::new(0.3, 0.1, 1.0), Vec3::Y),
        60.0,
        "x",
        32,
        32,
    )?;
    b.build(
        camera,
        Settings {
            width: 32,
            height: 32,
            spp: 16,
            max_depth: 8,
            rr_depth: 5,
        },
    )
}

/// Two rooms joined by a door that stands open only by a 5 cm slit; the only light is on the
/// ceiling of the far room, so everything the camera sees is lit through the slit (the classic
/// hard case for unguided path tracing).
pub fn door() -> Result<Scene> {
    let mut b = SceneBuilder::default();
    let white = b.material(Material::Diffuse {
        reflectance: Vec3::splat(0.7),
    });
    let wood = b.material(Material::Diffuse {
        reflectance: Vec3::new(0.6, 0.45, 0.3),
    });
    let black = b.material(Material::Diffuse {
        reflectance: Vec3::ZERO,
    });
    let (h, za, zb) = (2.5f32, -2.0f32, 2.0f32);
    // Room A: x in [-4, 0] (camera); room B: x in [0, 3] (light). Floors, ceilings, side walls.
    for (x0, x1, mat) in [(-4.0f32, 0.0f32, wood), (0.0, 3.0, white)] {
        aa_quad(&mut b, 1, 0.0, (za, zb), (x0, x1), 1.0, mat, None);
        aa_quad(&mut b, 1, h, (za, zb), (x0, x1), -1.0, white, None);
        aa_quad(&mut b, 2, za, (x0, x1), (0.0, h), 1.0, white, None);
        aa_quad(&mut b, 2, zb, (x0, x1), (0.0, h), -1.0, white, None);
    }
    aa_quad(&mut b, 0, -4.0, (0.0, h), (za, zb), 1.0, white, None);
    aa_quad(&mut b, 0, 3.0, (0.0, h), (za, zb), -1.0, white, None);
    // Dividing wall at x = 0 with a slit z in [-0.5, -0.45], y in [0, 2]: one zero-thickness
    // sheet, white on both sides. (Two coincident one-sided quads facing away from each other
    // tie at every hit, and the BVH then returns the back face about a third of the time,
    // which a one-sided diffuse BSDF absorbs.)
    let wall = b.material(Material::TwoSided {
        front: white,
        back: white,
    });
    let (s0, s1, top) = (-0.5f32, -0.45f32, 2.0f32);
    aa_quad(&mut b, 0, 0.0, (0.0, h), (za, s0), 1.0, wall, None);
    aa_quad(&mut b, 0, 0.0, (0.0, h), (s1, zb), 1.0, wall, None);
    aa_quad(&mut b, 0, 0.0, (top, h), (s0, s1), 1.0, wall, None);
    // Ceiling light in room B, facing down.
    aa_quad(
        &mut b,
        1,
        h - 0.01,
        (-0.5, 0.5),
        (1.5, 2.5),
        -1.0,
        black,
        Some(Vec3::splat(40.0)),
    );
    let camera = Camera::new(
        look_at(
            Vec3::new(-3.7, 1.3, 1.7),
            Vec3::new(0.0, 0.7, -0.6),
            Vec3::Y,
        ),
        60.0,
        "x",
        320,
        240,
    )?;
    b.build(
        camera,
        Settings {
            width: 320,
            height: 240,
            spp: 64,
            max_depth: 8,
            rr_depth: 5,
        },
    )
}
