//! Loader for a subset of the Mitsuba 3 scene format.
//!
//! Supported: `integrator path` (max_depth, rr_depth), `sensor perspective` (fov, fov_axis,
//! to_world, near/far_clip), `sampler independent` (sample_count), `film hdrfilm` (width,
//! height, rfilter box); BSDFs `diffuse`, `conductor`, `roughconductor`, `dielectric`,
//! `roughdielectric`, `plastic`, `roughplastic` (rough ones GGX only, isotropic alpha; IORs as
//! numbers or Mitsuba's names) and `twosided`; shapes `obj`, `ply`, `sphere`, `rectangle`,
//! `cube`, `disk` (to_world, flip_normals, face_normals for meshes); emitters `area` (nested in
//! a shape), `point`, `constant` and `envmap` (EXR, to_world rotation, scale); `ref id`; and
//! `transform` with matrix/lookat/translate/rotate/scale. The common Mitsuba 0.6 spellings are
//! read too: `<srgb>` colours (`#rrggbb` or numbers, sRGB-decoded), `<spectrum>` with a single
//! value (grey), `lookAt` and `toWorld`.
//!
//! Anything else (an unknown element, plugin type or property) is an error that names the
//! element and its line: nothing is dropped silently.

use crate::bsdf::{Coating, Material};
use crate::emitter::{EnvMap, Environment, PointLight};
use crate::error::{Error, Result};
use crate::obj::parse_obj;
use crate::ply::parse_ply;
use crate::scene::{Camera, Prim, Scene, SceneBuilder, Settings};
use glam::{Mat4, Vec3};
use roxmltree::{Document, Node};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Loads a Mitsuba 3 XML scene from disk (meshes are resolved relative to its folder).
pub fn load_file(path: &Path) -> Result<Scene> {
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    load_str(&text, &path.display().to_string(), &base)
}

/// Loads a Mitsuba 3 XML scene from a string; `file` names it in errors, `base` resolves meshes.
pub fn load_str(text: &str, file: &str, base: &Path) -> Result<Scene> {
    load_str_with(text, file, base, &|path: &Path| std::fs::read(path))
}

/// [`load_str`] with meshes read by `read` (given `base` joined with the mesh's `filename`)
/// instead of from disk: for in-memory scenes, tests and the fuzzer.
pub fn load_str_with(
    text: &str,
    file: &str,
    base: &Path,
    read: &dyn Fn(&Path) -> std::io::Result<Vec<u8>>,
) -> Result<Scene> {
    let doc = Document::parse(text).map_err(|source| Error::XmlSyntax {
        file: file.to_string(),
        source,
    })?;
    let mut ctx = Ctx {
        doc: &doc,
        file: file.to_string(),
        base: base.to_path_buf(),
        read,
        bsdfs: HashMap::new(),
        builder: SceneBuilder::default(),
        default_material: None,
    };
    ctx.scene(doc.root_element())
}

struct Ctx<'a, 'i> {
    doc: &'a Document<'i>,
    file: String,
    base: PathBuf,
    read: &'a dyn Fn(&Path) -> std::io::Result<Vec<u8>>,
    bsdfs: HashMap<String, u32>,
    builder: SceneBuilder,
    default_material: Option<u32>,
}

fn elements<'a, 'i>(n: Node<'a, 'i>) -> impl Iterator<Item = Node<'a, 'i>> {
    n.children().filter(|c| c.is_element())
}

impl<'a, 'i> Ctx<'a, 'i> {
    fn err(&self, n: Node, msg: impl Into<String>) -> Error {
        let pos = self.doc.text_pos_at(n.range().start);
        Error::Xml {
            file: self.file.clone(),
            line: pos.row,
            col: pos.col,
            msg: msg.into(),
        }
    }

    fn attr<'n>(&self, n: Node<'n, 'i>, name: &str) -> Result<&'n str> {
        n.attribute(name).ok_or_else(|| {
            self.err(
                n,
                format!(
                    "<{}> is missing the \"{name}\" attribute",
                    n.tag_name().name()
                ),
            )
        })
    }

    fn unsupported(&self, n: Node, what: &str) -> Error {
        let ty = n
            .attribute("type")
            .or_else(|| n.attribute("name"))
            .unwrap_or("");
        self.err(
            n,
            format!(
                "unsupported {what} <{} {}> (element \"{}\")",
                n.tag_name().name(),
                quoted(ty),
                n.tag_name().name()
            ),
        )
    }

    fn floats(&self, n: Node, s: &str) -> Result<Vec<f32>> {
        s.split(|c: char| c == ',' || c.is_whitespace())
            .filter(|t| !t.is_empty())
            .map(|t| {
                t.parse::<f32>()
                    .map_err(|_| self.err(n, format!("cannot parse number \"{t}\"")))
            })
            .collect()
    }

    fn float(&self, n: Node) -> Result<f32> {
        let v = self.floats(n, self.attr(n, "value")?)?;
        if v.len() != 1 {
            return Err(self.err(n, "expected a single number"));
        }
        Ok(v[0])
    }

    fn integer(&self, n: Node) -> Result<i64> {
        let s = self.attr(n, "value")?;
        s.trim()
            .parse()
            .map_err(|_| self.err(n, format!("cannot parse integer \"{s}\"")))
    }

    fn boolean(&self, n: Node) -> Result<bool> {
        match self.attr(n, "value")?.trim() {
            "true" => Ok(true),
            "false" => Ok(false),
            s => Err(self.err(n, format!("cannot parse boolean \"{s}\""))),
        }
    }

    /// `<rgb value="r, g, b"/>`, `<rgb value="v"/>` or `<float value="v"/>` (linear), and the
    /// Mitsuba 0.6 spellings `<srgb value="#rrggbb"/>` / `<srgb value="r, g, b"/>` (sRGB-encoded,
    /// decoded with the sRGB transfer function as Mitsuba 0.6's `Spectrum::fromSRGB` does) and
    /// `<spectrum value="v"/>` with a single value (grey; wavelength:value lists are refused).
    /// Every use (reflectance, radiance, IOR) needs finite values `>= 0`.
    fn color(&self, n: Node) -> Result<Vec3> {
        let tag = n.tag_name().name();
        match tag {
            "rgb" | "float" | "srgb" | "spectrum" => {
                let s = self.attr(n, "value")?;
                let v = match s.trim().strip_prefix('#') {
                    Some(hex) if tag == "srgb" => self.hex_color(n, hex)?,
                    _ if tag == "spectrum" && s.contains(':') => {
                        return Err(self.err(
                            n,
                            "<spectrum> with wavelength:value pairs is not supported (use a single value or <rgb>)",
                        ))
                    }
                    _ => {
                        let v = self.floats(n, s)?;
                        match (v.len(), tag) {
                            (1, _) => Vec3::splat(v[0]),
                            (3, "rgb" | "srgb") => Vec3::new(v[0], v[1], v[2]),
                            _ if tag == "spectrum" || tag == "float" => {
                                return Err(self.err(n, format!("<{tag}> expects a single number")))
                            }
                            _ => return Err(self.err(n, "expected 1 or 3 numbers")),
                        }
                    }
                };
                let c = if tag == "srgb" {
                    v.map(srgb_to_linear)
                } else {
                    v
                };
                if !(c.is_finite() && c.min_element() >= 0.0) {
                    return Err(self.err(n, format!("colour {c} must be finite and >= 0")));
                }
                Ok(c)
            }
            _ => Err(self.unsupported(
                n,
                "colour value (only <rgb>, <srgb>, <spectrum> and <float> are supported)",
            )),
        }
    }

    /// `rrggbb` (hex digits, after the `#`) as sRGB-encoded values in `[0, 1]`.
    fn hex_color(&self, n: Node, hex: &str) -> Result<Vec3> {
        let bad = || {
            self.err(
                n,
                format!("cannot parse colour \"#{hex}\" (expected #rrggbb)"),
            )
        };
        if hex.len() != 6 || !hex.is_ascii() {
            return Err(bad());
        }
        let mut v = Vec3::ZERO;
        for i in 0..3 {
            let byte = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).map_err(|_| bad())?;
            v[i] = f32::from(byte) / 255.0;
        }
        Ok(v)
    }

    /// `<point x= y= z=/>` or `value="x, y, z"`.
    fn vec3(&self, n: Node) -> Result<Vec3> {
        if let Some(v) = n.attribute("value") {
            let v = self.floats(n, v)?;
            return match v.len() {
                1 => Ok(Vec3::splat(v[0])),
                3 => Ok(Vec3::new(v[0], v[1], v[2])),
                _ => Err(self.err(n, "expected 1 or 3 numbers")),
            };
        }
        let mut out = Vec3::ZERO;
        for (i, k) in ["x", "y", "z"].iter().enumerate() {
            if let Some(s) = n.attribute(*k) {
                out[i] = self
                    .floats(n, s)?
                    .first()
                    .copied()
                    .ok_or_else(|| self.err(n, "empty number"))?;
            }
        }
        Ok(out)
    }

    /// The `name` attribute, with Mitsuba 0.6's `toWorld` read as `to_world`.
    fn name<'n>(&self, n: Node<'n, 'i>) -> Result<&'n str> {
        self.attr(n, "name").map(prop_name)
    }

    fn transform(&self, n: Node) -> Result<Mat4> {
        let mut m = Mat4::IDENTITY;
        for op in elements(n) {
            let t = match op.tag_name().name() {
                "matrix" => {
                    let v = self.floats(op, self.attr(op, "value")?)?;
                    match v.len() {
                        16 => Mat4::from_cols_slice(&v).transpose(),
                        9 => Mat4::from_mat3(glam::Mat3::from_cols_slice(&v).transpose()),
                        _ => return Err(self.err(op, "matrix needs 16 (or 9) numbers")),
                    }
                }
                "translate" => Mat4::from_translation(self.vec3_xyz(op, 0.0)?),
                "scale" => Mat4::from_scale(self.vec3_xyz(op, 1.0)?),
                "rotate" => {
                    let axis = if let Some(a) = op.attribute("axis") {
                        let v = self.floats(op, a)?;
                        if v.len() != 3 {
                            return Err(self.err(op, "axis needs 3 numbers"));
                        }
                        Vec3::new(v[0], v[1], v[2])
                    } else {
                        self.vec3_xyz(op, 0.0)?
                    };
                    let angle: f32 = self
                        .floats(op, self.attr(op, "angle")?)?
                        .first()
                        .copied()
                        .unwrap_or(0.0);
                    let axis = axis
                        .try_normalize()
                        .ok_or_else(|| self.err(op, "rotation axis is zero"))?;
                    Mat4::from_axis_angle(axis, angle.to_radians())
                }
                // `lookAt` is the Mitsuba 0.6 spelling.
                "lookat" | "lookAt" => {
                    let get = |k: &str| -> Result<Vec3> {
                        let v = self.floats(op, self.attr(op, k)?)?;
                        if v.len() != 3 {
                            return Err(self.err(op, format!("lookat {k} needs 3 numbers")));
                        }
                        Ok(Vec3::new(v[0], v[1], v[2]))
                    };
                    let (o, target) = (get("origin")?, get("target")?);
                    let up = if op.attribute("up").is_some() {
                        get("up")?
                    } else {
                        Vec3::Y
                    };
                    let dir = (target - o)
                        .try_normalize()
                        .ok_or_else(|| self.err(op, "lookat origin == target"))?;
                    let left = up.cross(dir).try_normalize().ok_or_else(|| {
                        self.err(op, "lookat up is parallel to the view direction")
                    })?;
                    let new_up = dir.cross(left);
                    Mat4::from_cols(
                        left.extend(0.0),
                        new_up.extend(0.0),
                        dir.extend(0.0),
                        o.extend(1.0),
                    )
                }
                _ => return Err(self.unsupported(op, "transform operation")),
            };
            // A NaN / infinity in one operation is reported at that element (its line),
            // not later as a non-finite vertex.
            if !t.is_finite() {
                return Err(self.err(
                    op,
                    format!(
                        "<{}> in transform \"{}\" is not finite (NaN or infinity)",
                        op.tag_name().name(),
                        n.attribute("name").unwrap_or("")
                    ),
                ));
            }
            m = t * m;
        }
        if !m.is_finite() {
            return Err(self.err(n, "transform is not finite (overflow)"));
        }
        Ok(m)
    }

    /// `x= y= z=` attributes (missing ones default to `def`) or `value="..."`.
    fn vec3_xyz(&self, n: Node, def: f32) -> Result<Vec3> {
        if let Some(v) = n.attribute("value") {
            let v = self.floats(n, v)?;
            return match v.len() {
                1 => Ok(Vec3::splat(v[0])),
                3 => Ok(Vec3::new(v[0], v[1], v[2])),
                _ => Err(self.err(n, "expected 1 or 3 numbers")),
            };
        }
        let mut out = Vec3::splat(def);
        for (i, k) in ["x", "y", "z"].iter().enumerate() {
            if let Some(s) = n.attribute(*k) {
                out[i] = self.floats(n, s)?.first().copied().unwrap_or(def);
            }
        }
        Ok(out)
    }

    fn scene(&mut self, root: Node<'a, 'i>) -> Result<Scene> {
        if root.tag_name().name() != "scene" {
            return Err(self.err(
                root,
                format!(
                    "root element is <{}>, expected <scene>",
                    root.tag_name().name()
                ),
            ));
        }
        let mut max_depth: Option<(u32, u32)> = None;
        let mut sensor: Option<(Camera, u32, u32, u32)> = None;
        for n in elements(root) {
            match n.tag_name().name() {
                "integrator" => max_depth = Some(self.integrator(n)?),
                "sensor" => {
                    if sensor.is_some() {
                        return Err(self.err(n, "more than one <sensor> is not supported"));
                    }
                    sensor = Some(self.sensor(n)?);
                }
                "bsdf" => {
                    let id = self.attr(n, "id")?.to_string();
                    let idx = self.bsdf(n)?;
                    self.bsdfs.insert(id, idx);
                }
                "shape" => self.shape(n)?,
                "emitter" => self.emitter(n)?,
                _ => return Err(self.unsupported(n, "scene element")),
            }
        }
        let (camera, width, height, spp) =
            sensor.ok_or_else(|| self.err(root, "the scene has no <sensor>"))?;
        let settings = Settings {
            width,
            height,
            spp,
            max_depth: max_depth.map_or(1024, |d| d.0),
            rr_depth: max_depth.map_or(5, |d| d.1),
        };
        let builder = std::mem::take(&mut self.builder);
        builder.build(camera, settings)
    }

    /// `(max_depth, rr_depth)` of `<integrator type="path">`.
    fn integrator(&self, n: Node) -> Result<(u32, u32)> {
        if n.attribute("type") != Some("path") {
            return Err(self.unsupported(n, "integrator type"));
        }
        let (mut depth, mut rr_depth) = (1024, 5);
        for p in elements(n) {
            match (p.tag_name().name(), self.name(p)?) {
                ("integer", "max_depth") => {
                    let d = self.integer(p)?;
                    depth = if d < 0 { 1024 } else { d.min(1 << 20) as u32 };
                }
                // Russian roulette start depth (used with `--rr`; RR is off by default).
                ("integer", "rr_depth") => {
                    rr_depth = self.integer(p)?.clamp(1, 1 << 20) as u32;
                }
                _ => return Err(self.unsupported(p, "integrator property")),
            }
        }
        Ok((depth, rr_depth))
    }

    fn sensor(&self, n: Node) -> Result<(Camera, u32, u32, u32)> {
        if n.attribute("type") != Some("perspective") {
            return Err(self.unsupported(n, "sensor type"));
        }
        let (mut fov, mut axis, mut to_world) = (None, "x".to_string(), Mat4::IDENTITY);
        let (mut w, mut h, mut spp) = (768u32, 576u32, 4u32);
        for p in elements(n) {
            match p.tag_name().name() {
                "float" if self.name(p)? == "fov" => fov = Some(self.float(p)?),
                // Clipping planes do not change the image of a closed-form pinhole for these scenes.
                "float" if matches!(self.name(p)?, "near_clip" | "far_clip") => {}
                "string" if self.name(p)? == "fov_axis" => {
                    axis = self.attr(p, "value")?.to_string()
                }
                "transform" if self.name(p)? == "to_world" => to_world = self.transform(p)?,
                "sampler" => {
                    if p.attribute("type") != Some("independent") {
                        return Err(self.unsupported(p, "sampler type"));
                    }
                    for q in elements(p) {
                        match (q.tag_name().name(), self.name(q)?) {
                            ("integer", "sample_count") => spp = self.positive(q)?,
                            ("integer", "seed") => {}
                            _ => return Err(self.unsupported(q, "sampler property")),
                        }
                    }
                }
                "film" => {
                    if p.attribute("type") != Some("hdrfilm") {
                        return Err(self.unsupported(p, "film type"));
                    }
                    for q in elements(p) {
                        match q.tag_name().name() {
                            "integer" if self.name(q)? == "width" => w = self.positive(q)?,
                            "integer" if self.name(q)? == "height" => h = self.positive(q)?,
                            "rfilter" => {
                                if q.attribute("type") != Some("box") {
                                    return Err(self.unsupported(q, "reconstruction filter"));
                                }
                            }
                            _ => return Err(self.unsupported(q, "film property")),
                        }
                    }
                }
                _ => return Err(self.unsupported(p, "sensor property")),
            }
        }
        let fov = fov.ok_or_else(|| self.err(n, "perspective sensor needs a \"fov\" float"))?;
        if !(fov > 0.0 && fov < 180.0) {
            return Err(self.err(n, format!("fov {fov} must be in (0, 180) degrees")));
        }
        let cam =
            Camera::new(to_world, fov, &axis, w, h).map_err(|e| self.err(n, e.to_string()))?;
        Ok((cam, w, h, spp))
    }

    fn positive(&self, n: Node) -> Result<u32> {
        let v = self.integer(n)?;
        if v <= 0 || v > 1 << 16 {
            return Err(self.err(n, format!("value {v} out of range (1..=65536)")));
        }
        Ok(v as u32)
    }

    /// An index of refraction: `<float>` or a named material (Mitsuba's `lookup_ior` table).
    fn ior(&self, p: Node) -> Result<f32> {
        let v = match p.tag_name().name() {
            "float" => self.float(p)?,
            "string" => {
                let name = self.attr(p, "value")?;
                named_ior(name).ok_or_else(|| {
                    self.err(p, format!("unknown index-of-refraction name \"{name}\""))
                })?
            }
            _ => return Err(self.unsupported(p, "index of refraction (float or string)")),
        };
        if !(v.is_finite() && v > 0.0) {
            return Err(self.err(p, format!("index of refraction {v} must be positive")));
        }
        Ok(v)
    }

    /// GGX roughness and distribution properties shared by the rough BSDFs; returns true if
    /// the property was one of them.
    fn rough_property(&self, p: Node, distribution: &mut String, alpha: &mut f32) -> Result<bool> {
        match (p.tag_name().name(), self.name(p)?) {
            ("string", "distribution") => *distribution = self.attr(p, "value")?.to_string(),
            ("float", "alpha") => *alpha = self.float(p)?,
            // Visible-normal sampling is what we do anyway; `false` would only change variance.
            ("boolean", "sample_visible") => {}
            _ => return Ok(false),
        }
        Ok(true)
    }

    fn check_rough(&self, n: Node, distribution: &str, alpha: f32) -> Result<f32> {
        let ty = n.attribute("type").unwrap_or("");
        if distribution != "ggx" {
            return Err(self.err(n, format!("{ty} distribution \"{distribution}\" is not supported (only \"ggx\"; Mitsuba's default is beckmann)")));
        }
        if !(alpha > 0.0 && alpha.is_finite()) {
            return Err(self.err(n, format!("alpha {alpha} must be positive")));
        }
        Ok(alpha.max(1e-4))
    }

    /// Parses a `<bsdf>` (nested ones of `twosided` first), adds it to the scene and returns
    /// its material index.
    fn bsdf(&mut self, n: Node<'a, 'i>) -> Result<u32> {
        let ty = n.attribute("type").unwrap_or("");
        let m = match ty {
            "diffuse" => {
                let mut reflectance = Vec3::splat(0.5);
                for p in elements(n) {
                    match self.name(p)? {
                        "reflectance" => reflectance = self.color(p)?,
                        _ => return Err(self.unsupported(p, "diffuse property")),
                    }
                }
                Material::Diffuse { reflectance }
            }
            "conductor" | "roughconductor" => {
                let (mut alpha, mut eta, mut k) = (0.1f32, Vec3::ZERO, Vec3::ONE);
                let mut specular = Vec3::ONE;
                let mut distribution = "beckmann".to_string();
                for p in elements(n) {
                    if ty == "roughconductor"
                        && self.rough_property(p, &mut distribution, &mut alpha)?
                    {
                        continue;
                    }
                    match (p.tag_name().name(), self.name(p)?) {
                        ("string", "material") => {
                            if self.attr(p, "value")? != "none" {
                                return Err(self.err(p, format!("named conductor material \"{}\" is not supported (use rgb eta/k, or \"none\")", self.attr(p, "value")?)));
                            }
                            eta = Vec3::ZERO;
                            k = Vec3::ONE;
                        }
                        (_, "eta") => eta = self.color(p)?,
                        (_, "k") => k = self.color(p)?,
                        (_, "specular_reflectance") if ty == "conductor" => {
                            specular = self.color(p)?
                        }
                        _ => return Err(self.unsupported(p, &format!("{ty} property"))),
                    }
                }
                if ty == "conductor" {
                    Material::Conductor { eta, k, specular }
                } else {
                    let alpha = self.check_rough(n, &distribution, alpha)?;
                    Material::RoughConductor { alpha, eta, k }
                }
            }
            "dielectric" | "roughdielectric" => {
                let (mut int_ior, mut ext_ior, mut alpha) = (1.5046f32, 1.000_277f32, 0.1f32);
                let (mut reflectance, mut transmittance) = (Vec3::ONE, Vec3::ONE);
                let mut distribution = "beckmann".to_string();
                for p in elements(n) {
                    if ty == "roughdielectric"
                        && self.rough_property(p, &mut distribution, &mut alpha)?
                    {
                        continue;
                    }
                    match self.name(p)? {
                        "int_ior" => int_ior = self.ior(p)?,
                        "ext_ior" => ext_ior = self.ior(p)?,
                        "specular_reflectance" => reflectance = self.color(p)?,
                        "specular_transmittance" => transmittance = self.color(p)?,
                        _ => return Err(self.unsupported(p, &format!("{ty} property"))),
                    }
                }
                if int_ior == ext_ior {
                    return Err(self.err(n, "int_ior and ext_ior must differ"));
                }
                let eta = int_ior / ext_ior;
                if ty == "dielectric" {
                    Material::Dielectric {
                        eta,
                        reflectance,
                        transmittance,
                    }
                } else {
                    let alpha = self.check_rough(n, &distribution, alpha)?;
                    Material::RoughDielectric {
                        alpha,
                        eta,
                        reflectance,
                        transmittance,
                    }
                }
            }
            "plastic" | "roughplastic" => {
                let (mut int_ior, mut ext_ior, mut alpha) = (1.49f32, 1.000_277f32, 0.1f32);
                let (mut diffuse, mut specular) = (Vec3::splat(0.5), Vec3::ONE);
                let mut nonlinear = false;
                let mut distribution = "beckmann".to_string();
                for p in elements(n) {
                    if ty == "roughplastic"
                        && self.rough_property(p, &mut distribution, &mut alpha)?
                    {
                        continue;
                    }
                    match (p.tag_name().name(), self.name(p)?) {
                        (_, "int_ior") => int_ior = self.ior(p)?,
                        (_, "ext_ior") => ext_ior = self.ior(p)?,
                        (_, "diffuse_reflectance") => diffuse = self.color(p)?,
                        (_, "specular_reflectance") => specular = self.color(p)?,
                        ("boolean", "nonlinear") => nonlinear = self.boolean(p)?,
                        _ => return Err(self.unsupported(p, &format!("{ty} property"))),
                    }
                }
                if int_ior == ext_ior {
                    return Err(self.err(n, "int_ior and ext_ior must differ"));
                }
                let eta = int_ior / ext_ior;
                if ty == "plastic" {
                    Material::Plastic(Coating::smooth(diffuse, specular, eta, nonlinear))
                } else {
                    let alpha = self.check_rough(n, &distribution, alpha)?;
                    Material::RoughPlastic(Coating::rough(diffuse, specular, eta, nonlinear, alpha))
                }
            }
            "twosided" => {
                let mut sides = Vec::new();
                for p in elements(n) {
                    let idx = match p.tag_name().name() {
                        "bsdf" => self.bsdf(p)?,
                        "ref" => self.bsdf_ref(p)?,
                        _ => return Err(self.unsupported(p, "twosided property")),
                    };
                    let inner = &self.builder.materials()[idx as usize];
                    if !inner.one_sided() || matches!(inner, Material::TwoSided { .. }) {
                        return Err(self.err(p, "twosided can only wrap opaque, one-sided BSDFs (not dielectrics or another twosided)"));
                    }
                    sides.push(idx);
                }
                match sides.as_slice() {
                    [f] => Material::TwoSided {
                        front: *f,
                        back: *f,
                    },
                    [f, b] => Material::TwoSided {
                        front: *f,
                        back: *b,
                    },
                    _ => return Err(self.err(n, "twosided needs one or two nested BSDFs")),
                }
            }
            _ => return Err(self.unsupported(n, "bsdf type")),
        };
        Ok(self.builder.material(m))
    }

    /// A top-level `<emitter>`: `point`, `constant` or `envmap` (area emitters live in shapes).
    fn emitter(&mut self, n: Node) -> Result<()> {
        let ty = n.attribute("type").unwrap_or("");
        let mut to_world = None;
        let mut value = Vec3::ONE;
        let mut position = None;
        let (mut filename, mut scale) = (None, 1.0f32);
        for p in elements(n) {
            let pname = prop_name(p.attribute("name").unwrap_or(""));
            match (p.tag_name().name(), pname, ty) {
                ("transform", "to_world", "point" | "envmap") => {
                    to_world = Some(self.transform(p)?)
                }
                ("point", "position", "point") => position = Some(self.vec3(p)?),
                (_, "intensity", "point") | (_, "radiance", "constant") => value = self.color(p)?,
                ("string", "filename", "envmap") => {
                    filename = Some(self.attr(p, "value")?.to_string())
                }
                ("float", "scale", "envmap") => scale = self.float(p)?,
                ("string", "filter_type", "envmap") if p.attribute("value") == Some("bilinear") => {
                }
                ("boolean", "mis_compensation", "envmap")
                    if p.attribute("value") == Some("false") => {}
                _ => return Err(self.unsupported(p, &format!("property of emitter \"{ty}\""))),
            }
        }
        if !value.is_finite() || value.min_element() < 0.0 {
            return Err(self.err(
                n,
                format!("emitter value {value} must be finite and non-negative"),
            ));
        }
        let env = match ty {
            "point" => {
                let pos = match (position, to_world) {
                    (Some(_), Some(_)) => {
                        return Err(
                            self.err(n, "point emitter: give position or to_world, not both")
                        )
                    }
                    (Some(p), None) => p,
                    (None, Some(m)) => m.transform_point3(Vec3::ZERO),
                    (None, None) => Vec3::ZERO,
                };
                self.builder.point_light(PointLight {
                    position: pos,
                    intensity: value,
                });
                return Ok(());
            }
            "constant" => Environment::Constant(value),
            "envmap" => {
                let f =
                    filename.ok_or_else(|| self.err(n, "envmap needs a \"filename\" string"))?;
                let path = self.base.join(&f);
                let img = crate::output::read_exr(&path)?;
                let map = EnvMap::new(img.width, img.height, &img.pixels, scale)
                    .map_err(|e| self.err(n, format!("envmap {}: {e}", path.display())))?;
                let m = glam::Mat3::from_mat4(to_world.unwrap_or(Mat4::IDENTITY));
                // The sampler's pdf assumes a rigid rotation (no Jacobian for scale or shear).
                let rigid = (m.transpose() * m - glam::Mat3::IDENTITY)
                    .to_cols_array()
                    .iter()
                    .all(|x| x.abs() < 1e-3)
                    && m.determinant() > 0.0;
                if !rigid {
                    return Err(self.err(
                        n,
                        "envmap to_world must be a rotation (no scale, shear or mirroring)",
                    ));
                }
                Environment::Map {
                    map: Box::new(map),
                    to_world: m,
                }
            }
            _ => return Err(self.unsupported(n, "emitter type")),
        };
        if !self.builder.environment(env) {
            return Err(self.err(
                n,
                "only one environment emitter (constant or envmap) is supported",
            ));
        }
        Ok(())
    }

    fn bsdf_ref(&self, p: Node) -> Result<u32> {
        let id = self.attr(p, "id")?;
        self.bsdfs
            .get(id)
            .copied()
            .ok_or_else(|| self.err(p, format!("reference to unknown bsdf id \"{id}\"")))
    }

    fn shape(&mut self, n: Node<'a, 'i>) -> Result<()> {
        let ty = n.attribute("type").unwrap_or("");
        let mut to_world = Mat4::IDENTITY;
        let (mut flip, mut face_normals) = (false, false);
        let mut material = None;
        let mut emission = None;
        let mut filename = None;
        let (mut center, mut radius) = (Vec3::ZERO, 1.0f32);
        for p in elements(n) {
            let tag = p.tag_name().name();
            let pname = prop_name(p.attribute("name").unwrap_or(""));
            match (tag, pname, ty) {
                ("transform", "to_world", _) => to_world = self.transform(p)?,
                ("boolean", "flip_normals", _) => flip = self.boolean(p)?,
                ("boolean", "face_normals", "obj" | "ply") => face_normals = self.boolean(p)?,
                ("string", "filename", "obj" | "ply") => {
                    filename = Some(self.attr(p, "value")?.to_string())
                }
                ("point", "center", "sphere") => center = self.vec3(p)?,
                ("float", "radius", "sphere") => radius = self.float(p)?,
                ("ref", _, _) => material = Some(self.bsdf_ref(p)?),
                ("bsdf", _, _) => material = Some(self.bsdf(p)?),
                ("emitter", _, _) => {
                    if p.attribute("type") != Some("area") {
                        return Err(self.unsupported(p, "emitter type inside a shape"));
                    }
                    let mut radiance = Vec3::ONE;
                    for q in elements(p) {
                        match q.attribute("name") {
                            Some("radiance") => radiance = self.color(q)?,
                            _ => return Err(self.unsupported(q, "area emitter property")),
                        }
                    }
                    emission = Some(radiance);
                }
                _ => return Err(self.unsupported(p, &format!("property of shape \"{ty}\""))),
            }
        }
        let nmat = Mat4::from_mat3(glam::Mat3::from_mat4(to_world).inverse().transpose());
        let xf_n = |v: Vec3| nmat.transform_vector3(v).normalize_or_zero();
        let mut prims = match ty {
            "obj" | "ply" => {
                let f = filename.ok_or_else(|| {
                    self.err(n, format!("{ty} shape needs a \"filename\" string"))
                })?;
                let path = self.base.join(&f);
                let bytes = (self.read)(&path).map_err(|source| Error::Io {
                    path: path.clone(),
                    source,
                })?;
                let name = path.display().to_string();
                let mut tris = if ty == "obj" {
                    let text = String::from_utf8(bytes)
                        .map_err(|_| self.err(n, format!("{name} is not UTF-8 text")))?;
                    parse_obj(&text, &name)?
                } else {
                    parse_ply(&bytes, &name)?
                };
                for t in &mut tris {
                    if let Prim::Tri { p, n } = t {
                        *p = p.map(|v| to_world.transform_point3(v));
                        *n = if face_normals {
                            None
                        } else {
                            n.map(|n| n.map(xf_n))
                        };
                    }
                }
                tris
            }
            "sphere" => {
                let m = to_world
                    * Mat4::from_translation(center)
                    * Mat4::from_scale(Vec3::splat(radius));
                let c = m.transform_point3(Vec3::ZERO);
                let axes = [
                    m.x_axis.truncate().length(),
                    m.y_axis.truncate().length(),
                    m.z_axis.truncate().length(),
                ];
                if (axes[0] - axes[1]).abs() > 1e-4 * axes[0]
                    || (axes[0] - axes[2]).abs() > 1e-4 * axes[0]
                {
                    return Err(self.err(n, "sphere with a non-uniform scale is not supported"));
                }
                if axes[0].is_nan() || axes[0] <= 0.0 {
                    return Err(self.err(n, "sphere radius must be positive"));
                }
                vec![Prim::Sphere {
                    center: c,
                    radius: axes[0],
                    flip: false,
                }]
            }
            "rectangle" => {
                let c = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
                    .map(|(x, y)| to_world.transform_point3(Vec3::new(x, y, 0.0)));
                let nz = xf_n(Vec3::Z);
                let mut tris = vec![
                    Prim::Tri {
                        p: [c[0], c[1], c[2]],
                        n: None,
                    },
                    Prim::Tri {
                        p: [c[0], c[2], c[3]],
                        n: None,
                    },
                ];
                if (c[1] - c[0]).cross(c[2] - c[0]).dot(nz) < 0.0 {
                    for t in &mut tris {
                        if let Prim::Tri { p, .. } = t {
                            p.swap(1, 2);
                        }
                    }
                }
                tris
            }
            "cube" => {
                // Mitsuba's cube: [-1, 1]³, 12 triangles, outward face normals.
                let mut tris = Vec::with_capacity(12);
                for axis in 0..3 {
                    for sign in [-1.0f32, 1.0] {
                        let mut nl = Vec3::ZERO;
                        nl[axis] = sign;
                        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                        let c =
                            [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(x, y)| {
                                let mut q = nl;
                                q[u] = x;
                                q[v] = y;
                                to_world.transform_point3(q)
                            });
                        let nw = xf_n(nl);
                        let mut t = [[c[0], c[1], c[2]], [c[0], c[2], c[3]]];
                        if (c[1] - c[0]).cross(c[2] - c[0]).dot(nw) < 0.0 {
                            for p in &mut t {
                                p.swap(1, 2);
                            }
                        }
                        tris.extend(t.map(|p| Prim::Tri { p, n: None }));
                    }
                }
                tris
            }
            "disk" => {
                let center = to_world.transform_point3(Vec3::ZERO);
                let (a, b) = (
                    to_world.transform_vector3(Vec3::X),
                    to_world.transform_vector3(Vec3::Y),
                );
                let area = a.cross(b).length();
                if area.is_nan() || area <= 0.0 {
                    return Err(self.err(n, "disk to_world is degenerate"));
                }
                vec![Prim::Disk {
                    center,
                    a,
                    b,
                    n: xf_n(Vec3::Z),
                }]
            }
            _ => return Err(self.unsupported(n, "shape type")),
        };
        if flip {
            for pr in &mut prims {
                match pr {
                    Prim::Tri { p, n } => {
                        p.swap(1, 2);
                        if let Some(n) = n {
                            n.swap(1, 2);
                            *n = n.map(|v| -v);
                        }
                    }
                    Prim::Sphere { flip, .. } => *flip = !*flip,
                    Prim::Disk { n, .. } => *n = -*n,
                }
            }
        }
        let material = match material {
            Some(m) => m,
            None => match self.default_material {
                Some(m) => m,
                None => {
                    let m = self.builder.material(Material::Diffuse {
                        reflectance: Vec3::splat(0.5),
                    });
                    self.default_material = Some(m);
                    m
                }
            },
        };
        self.builder.shape(prims, material, emission);
        Ok(())
    }
}

/// Mitsuba 0.6 property names that Mitsuba 3 renamed (only `toWorld` so far).
fn prop_name(s: &str) -> &str {
    match s {
        "toWorld" => "to_world",
        s => s,
    }
}

/// sRGB transfer function inverse (IEC 61966-2-1), as Mitsuba 0.6's `fromSRGB`.
fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn quoted(s: &str) -> String {
    if s.is_empty() {
        String::new()
    } else {
        format!("type=\"{s}\"")
    }
}

/// Mitsuba's named indices of refraction (`lookup_ior`).
fn named_ior(name: &str) -> Option<f32> {
    Some(match name {
        "vacuum" => 1.0,
        "helium" => 1.000_036,
        "hydrogen" => 1.000_132,
        "air" => 1.000_277,
        "carbon dioxide" => 1.000_45,
        "water" => 1.333,
        "acetone" => 1.36,
        "ethanol" => 1.361,
        "carbon tetrachloride" => 1.461,
        "glycerol" => 1.4729,
        "benzene" => 1.501,
        "silicone oil" => 1.520_45,
        "bromine" => 1.661,
        "water ice" => 1.31,
        "fused quartz" => 1.458,
        "pyrex" => 1.470,
        "acrylic glass" => 1.49,
        "polypropylene" => 1.49,
        "bk7" => 1.5046,
        "sodium chloride" => 1.544,
        "amber" => 1.55,
        "pet" => 1.575,
        "diamond" => 2.419,
        _ => return None,
    })
}
