//! Scenes constructed in code: `builtin:cornell-box`, `builtin:furnace`, `builtin:door`.

use crate::error::{Error, Result};
use crate::scene::bsdf::{Coating, Material, Microfacet};
use crate::scene::texture::{Texture, UvMap};
use crate::scene::{Camera, MaterialTextures, Prim, Scene, SceneBuilder, Settings};
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

/// Axis-aligned box `[x0, x1] x [y0, y1] x [z0, z1]`; faces point outwards.
fn slab(b: &mut SceneBuilder, x: (f32, f32), y: (f32, f32), z: (f32, f32), mat: u32) {
    aa_quad(b, 0, x.0, y, z, -1.0, mat, None);
    aa_quad(b, 0, x.1, y, z, 1.0, mat, None);
    aa_quad(b, 1, y.0, z, x, -1.0, mat, None);
    aa_quad(b, 1, y.1, z, x, 1.0, mat, None);
    aa_quad(b, 2, z.0, x, y, -1.0, mat, None);
    aa_quad(b, 2, z.1, x, y, 1.0, mat, None);
}

/// Veach's door scene (the "light through a door ajar" test of Veach & Guibas's Metropolis
/// light transport, 1997; Bitterli's "Veach, Ajar" is a later rendition): two rooms joined by
/// a doorway. The camera looks into room A (x < 0), whose only opening is the doorway in the
/// dividing wall x = 0; its door is hinged at the doorway's -z jamb and stands ajar by
/// [`DOOR_OPEN_DEG`] into room A. The only light is a ceiling panel in room B (x > 0) on the
/// hinge side, behind the door, so direct light enters room A only through the narrow wedge
/// between the door's free edge and the far jamb and falls as a bright patch on the floor in
/// front of the door; everything else the camera sees (the walls and ceiling, the face of the
/// door, a table with a glossy top and a rough copper block on it, a box) is lit indirectly —
/// the classic hard case for unguided path tracing. Glossy surfaces: the checkered floor and
/// the table top (rough plastic, GGX alpha 0.15) and the block (rough copper, alpha 0.25).
/// About 60 quads; 320x240, 64 spp, max_depth 8 by default.
pub fn door() -> Result<Scene> {
    let mut b = SceneBuilder::default();
    let mats = DoorMaterials::new(&mut b);
    door_rooms(&mut b, &mats);
    door_furniture(&mut b, &mats);
    // Ceiling light in room B, behind the door (hinge side), facing down.
    aa_quad(
        &mut b,
        1,
        ROOM_HEIGHT - 0.01,
        (-2.3, -1.5),
        (0.8, 1.8),
        -1.0,
        mats.black,
        Some(Vec3::splat(LIGHT)),
    );
    let camera = Camera::new(
        look_at(
            Vec3::new(-4.8, 1.7, 2.3),
            Vec3::new(-0.8, 0.6, -0.9),
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

/// The materials of `builtin:door` (indices into its builder), added in this order.
struct DoorMaterials {
    white: u32,
    /// The light's own surface.
    black: u32,
    /// The door and the table legs.
    door_mat: u32,
    crate_mat: u32,
    /// Checkered rough plastic.
    floor: u32,
    table_top: u32,
    /// The rough copper block on the table.
    copper: u32,
}

impl DoorMaterials {
    fn new(b: &mut SceneBuilder) -> Self {
        let white = b.material(Material::Diffuse {
            reflectance: Vec3::splat(0.7),
        });
        let black = b.material(Material::Diffuse {
            reflectance: Vec3::ZERO,
        });
        let door_mat = b.material(Material::Diffuse {
            reflectance: Vec3::new(0.55, 0.4, 0.28),
        });
        let crate_mat = b.material(Material::Diffuse {
            reflectance: Vec3::new(0.5, 0.5, 0.55),
        });
        // Glossy coatings share one (distribution, alpha, eta), so the coating tables are
        // computed once.
        let (dist, alpha, eta) = (Microfacet::Ggx, 0.15f32, 1.5f32);
        let checker = b.texture(Texture::Checkerboard {
            color0: Vec3::new(0.7, 0.68, 0.64),
            color1: Vec3::new(0.15, 0.13, 0.12),
            uv: UvMap {
                // One checker period is two tiles.
                m: glam::Mat2::from_diagonal(glam::Vec2::splat(0.5 / TILE)),
                t: glam::Vec2::ZERO,
            },
        });
        let floor = b.textured_material(
            Material::RoughPlastic(
                Coating::smooth(Vec3::splat(0.5), Vec3::ONE, eta, false).roughened(dist, alpha),
            ),
            MaterialTextures {
                diffuse: Some(checker),
                ..Default::default()
            },
        );
        let table_top = b.material(Material::RoughPlastic(
            Coating::smooth(Vec3::new(0.25, 0.12, 0.06), Vec3::ONE, eta, false)
                .roughened(dist, alpha),
        ));
        let copper = b.material(Material::RoughConductor {
            distribution: Microfacet::Ggx,
            alpha: 0.25,
            eta: Vec3::new(0.2004, 0.9240, 1.1022),
            k: Vec3::new(3.9129, 2.4528, 2.1421),
            specular: Vec3::ONE,
        });
        Self {
            white,
            black,
            door_mat,
            crate_mat,
            floor,
            table_top,
            copper,
        }
    }
}

/// The two rooms of `builtin:door` (floors, walls, ceilings), the dividing wall with its
/// doorway and the door standing ajar in it.
fn door_rooms(b: &mut SceneBuilder, mats: &DoorMaterials) {
    let (h, za, zb) = (ROOM_HEIGHT, -2.5f32, 2.5f32);
    let (xa, xb) = (-5.0f32, 3.0f32);
    let white = mats.white;
    // Room A (viewed): x in [xa, 0], checkered glossy floor; room B (lit): x in [0, xb].
    let (ua, ub) = (glam::Vec2::new(xa, za), glam::Vec2::new(0.0, zb));
    let fl = |x: f32, z: f32| Vec3::new(x, 0.0, z);
    b.shape_with(
        vec![
            Prim::Tri {
                p: [fl(xa, za), fl(xa, zb), fl(0.0, zb)],
                n: None,
            },
            Prim::Tri {
                p: [fl(xa, za), fl(0.0, zb), fl(0.0, za)],
                n: None,
            },
        ],
        Some(vec![
            [ua, glam::Vec2::new(xa, zb), ub],
            [ua, ub, glam::Vec2::new(0.0, za)],
        ]),
        mats.floor,
        None,
        None,
    );
    aa_quad(b, 1, 0.0, (za, zb), (0.0, xb), 1.0, white, None);
    for (x0, x1) in [(xa, 0.0f32), (0.0, xb)] {
        aa_quad(b, 1, h, (za, zb), (x0, x1), -1.0, white, None);
        aa_quad(b, 2, za, (x0, x1), (0.0, h), 1.0, white, None);
        aa_quad(b, 2, zb, (x0, x1), (0.0, h), -1.0, white, None);
    }
    aa_quad(b, 0, xa, (0.0, h), (za, zb), 1.0, white, None);
    aa_quad(b, 0, xb, (0.0, h), (za, zb), -1.0, white, None);
    // Dividing wall at x = 0 with the doorway z in [d0, d1], y in [0, top]: one
    // zero-thickness sheet, white on both sides. (Two coincident one-sided quads facing away
    // from each other tie at every hit, and the BVH then returns the back face about a third
    // of the time, which a one-sided diffuse BSDF absorbs.)
    let wall = b.material(Material::TwoSided {
        front: white,
        back: white,
    });
    let (d0, d1, top) = (-1.6f32, -0.7f32, 2.1f32);
    aa_quad(b, 0, 0.0, (0.0, h), (za, d0), 1.0, wall, None);
    aa_quad(b, 0, 0.0, (0.0, h), (d1, zb), 1.0, wall, None);
    aa_quad(b, 0, 0.0, (top, h), (d0, d1), 1.0, wall, None);
    // The door: hinged at (0, d0), swung into room A by DOOR_OPEN_DEG, 4 cm thick.
    let th = DOOR_OPEN_DEG.to_radians();
    let (u, n) = (
        glam::Vec2::new(-th.sin(), th.cos()) * (d1 - d0),
        glam::Vec2::new(-th.cos(), -th.sin()) * 0.04,
    );
    let hinge = glam::Vec2::new(0.0, d0);
    let foot = [hinge, hinge + u, hinge + u + n, hinge + n].map(|p| (p.x, p.y));
    boxx(b, foot, top, mats.door_mat);
}

/// The furniture of `builtin:door`'s room A: a table with a glossy top and a rough copper
/// block on it, and a box against the back wall.
fn door_furniture(b: &mut SceneBuilder, mats: &DoorMaterials) {
    let (tx, tz, tw, td, ty) = (-2.2f32, -1.75f32, 0.75f32, 0.45f32, 0.75f32);
    slab(
        b,
        (tx - tw, tx + tw),
        (ty - 0.05, ty),
        (tz - td, tz + td),
        mats.table_top,
    );
    for (lx, lz) in [(-1.0f32, -1.0f32), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
        let (cx, cz) = (tx + lx * (tw - 0.08), tz + lz * (td - 0.08));
        slab(
            b,
            (cx - 0.03, cx + 0.03),
            (0.0, ty - 0.05),
            (cz - 0.03, cz + 0.03),
            mats.door_mat,
        );
    }
    slab(
        b,
        (tx - 0.35, tx - 0.05),
        (ty, ty + 0.3),
        (tz - 0.1, tz + 0.2),
        mats.copper,
    );
    boxx(
        b,
        [(-2.0, 0.9), (-1.45, 0.75), (-1.3, 1.3), (-1.85, 1.45)],
        0.6,
        mats.crate_mat,
    );
}

/// Angle by which the door of `builtin:door` stands open.
pub const DOOR_OPEN_DEG: f32 = 20.0;
/// Ceiling height of `builtin:door`'s rooms (m).
const ROOM_HEIGHT: f32 = 2.6;
/// Side of the floor tiles of `builtin:door` (m).
const TILE: f32 = 0.5;
/// Radiance of the light of `builtin:door`.
const LIGHT: f32 = 800.0;
