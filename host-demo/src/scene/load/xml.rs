//! Loader for Mitsuba 3 scenes and Mitsuba 0.6 / 0.5 files (`docs/manual/scenes.md` has the
//! full table of what is supported, approximated, skipped or rejected).
//!
//! Supported: integrator `path` (max_depth, rr_depth); sensors `perspective` and `thinlens`
//! (fov, fov_axis, to_world, clip planes, aperture_radius, focus_distance); sampler
//! `independent` (sample_count); film `hdrfilm` (width, height, rfilter box); BSDFs `diffuse`,
//! `conductor`, `roughconductor` (rgb `eta`/`k`, Mitsuba's named conductors, textured
//! `specular_reflectance`, 0.6's `ext_eta`), `dielectric`, `thindielectric`, `roughdielectric`,
//! `plastic`, `roughplastic` (GGX or Beckmann microfacets, Beckmann by default as in Mitsuba;
//! IORs as numbers or Mitsuba's names), Mitsuba 0.6's `phong` and
//! `ward` (the three Ward variants, anisotropic alphas, textured reflectances) and
//! `roughdiffuse` (Oren–Nayar), `twosided`,
//! `blendbsdf` and `mask`; textures `bitmap` and `checkerboard` (see [`crate::scene::texture`]) for the
//! colour, alpha, weight and opacity parameters; shapes `obj`, `ply`, `serialized`, `sphere`,
//! `rectangle`, `cube`, `disk` (to_world, flip_normals, face_normals for meshes), `shapegroup` +
//! `instance` (flattened into world-space primitives); emitters `area` (nested in a shape),
//! `point`, `constant`, `envmap` (EXR, to_world rotation, scale) and `sunsky` / `sun` / `sky`
//! (approximated, see [`crate::scene::sunsky`]); `ref id` (also to BSDFs and textures nested in others);
//! `include` (with cycle detection); `<path>` search folders; `<default>` + `$name`
//! substitution ([`LoadOptions::params`] override the defaults); and `transform` with
//! matrix/lookat/translate/rotate/scale. Mitsuba 0.6 spellings: camelCase property names become
//! snake_case (`toWorld`, `maxDepth`, `intIOR`, ...), `<srgb>` colours (`#rrggbb` or numbers,
//! sRGB-decoded), `<spectrum>` with one value (grey), three (RGB) or wavelength:value pairs
//! ([`crate::scene::spectrum`]), `lookAt`.
//!
//! Policy: an **error** only where the scene cannot be rendered or the image would be silently
//! wrong (malformed XML, missing files, unknown ids, non-finite values, invalid parameters);
//! the load goes on after one, so [`Error::Problems`] lists every error of the scene with file
//! and line. Everything else is a **warning** naming file and line and what was done (stderr
//! and [`Scene::warnings`]): unknown properties and elements are ignored, unknown plugins are
//! replaced (integrators by `path` at their max_depth, BSDFs by a grey diffuse, textures by
//! grey; shapes and emitters are skipped), approximations are named. [`LoadOptions::strict`]
//! turns every unknown construct into an error. Nothing is dropped silently.

use crate::error::{Error, Result};
use crate::scene::bsdf::{Coating, Material, Microfacet};
use crate::scene::conductors::named_conductor;
use crate::scene::emitter::{EnvMap, Environment, PointLight};
use crate::scene::load::exr::read_exr;
use crate::scene::load::obj::parse_obj;
use crate::scene::load::ply::parse_ply;
use crate::scene::load::serialized::parse_serialized;
use crate::scene::medium::{MediumInterface, NO_MEDIUM};
use crate::scene::texture::{Filter, ImageCache, Param, Texture, UvMap, Wrap};
use crate::scene::{quad_triangles, Camera, MaterialTextures, Prim, Scene, SceneBuilder, Settings};
use glam::{Mat4, Vec2, Vec3};
use roxmltree::{Document, Node};

mod media;
use std::borrow::Cow;
use std::collections::{HashMap, HashSet};
use std::path::{Component, Path, PathBuf};

/// Options of a scene load.
#[derive(Clone, Debug, Default)]
pub struct LoadOptions {
    /// `$name` parameter values (`-D name=value` on the command line); they override the
    /// scene's `<default>` values.
    pub params: Vec<(String, String)>,
    /// `--strict`: everything the loader does not know (a plugin type, a property, an
    /// element) is an error instead of a warning. Approximations stay warnings.
    pub strict: bool,
}

/// Loads a Mitsuba XML scene from disk (meshes are resolved relative to its folder).
pub fn load_file(path: &Path) -> Result<Scene> {
    load_file_with(path, &LoadOptions::default())
}

/// [`load_file`] with `$param` overrides.
pub fn load_file_with(path: &Path, opts: &LoadOptions) -> Result<Scene> {
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    load_str_opts(
        &text,
        &path.display().to_string(),
        &base,
        &|p: &Path| std::fs::read(p),
        opts,
    )
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
    load_str_opts(text, file, base, read, &LoadOptions::default())
}

/// [`load_str_with`] with options (`$param` overrides).
pub fn load_str_opts(
    text: &str,
    file: &str,
    base: &Path,
    read: &dyn Fn(&Path) -> std::io::Result<Vec<u8>>,
    opts: &LoadOptions,
) -> Result<Scene> {
    let mut ctx = Ctx {
        file: file.to_string(),
        base: base.to_path_buf(),
        root_base: base.to_path_buf(),
        search: Vec::new(),
        read,
        params: opts.params.iter().cloned().collect(),
        strict: opts.strict,
        errors: Vec::new(),
        failed_bsdfs: HashSet::new(),
        aniso: [None, None],
        spectrum_warned: false,
        includes: vec![normalize(&PathBuf::from(file))],
        bsdfs: HashMap::new(),
        mask_opacity: HashMap::new(),
        tex_defs: HashMap::new(),
        tex_ids: HashMap::new(),
        groups: HashMap::new(),
        images: ImageCache::default(),
        builder: SceneBuilder::default(),
        default_material: None,
        integrator: None,
        sensor: None,
        null_material: None,
        black_material: None,
        media: HashMap::new(),
        camera_medium: None,
    };
    let text = substitute(text, file, &ctx.params)?;
    let doc = parse_doc(&text, file)?;
    ctx.scene(doc.root_element())
}

fn parse_doc<'t>(text: &'t str, file: &str) -> Result<Document<'t>> {
    Document::parse(text).map_err(|source| Error::XmlSyntax {
        file: file.to_string(),
        source,
    })
}

/// Lexical normalisation (`a/./b/../c` → `a/c`) for include-cycle detection.
fn normalize(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir if out.file_name().is_some() => {
                out.pop();
            }
            c => out.push(c),
        }
    }
    out
}

/// Replaces `$name` references by parameter values: `params` (command line or includer)
/// first, then the file's own top-level `<default name= value=>`. Values are XML-escaped, and
/// a `$name` left in any attribute afterwards is an error naming its element and line.
fn substitute(text: &str, file: &str, params: &HashMap<String, String>) -> Result<String> {
    if !text.contains('$') {
        return Ok(text.to_string());
    }
    let doc = parse_doc(text, file)?;
    let mut values = params.clone();
    for n in elements(doc.root_element()) {
        if n.tag_name().name() == "default" {
            if let (Some(k), Some(v)) = (n.attribute("name"), n.attribute("value")) {
                values.entry(k.to_string()).or_insert_with(|| v.to_string());
            }
        }
    }
    let bytes = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    let mut last = 0;
    while i < bytes.len() {
        if bytes[i] == b'$' {
            let j = i
                + 1
                + bytes[i + 1..]
                    .iter()
                    .take_while(|c| c.is_ascii_alphanumeric() || **c == b'_')
                    .count();
            if let Some(v) = values.get(&text[i + 1..j]) {
                out.push_str(&text[last..i]);
                for c in v.chars() {
                    match c {
                        '"' => out.push_str("&quot;"),
                        '\'' => out.push_str("&apos;"),
                        '<' => out.push_str("&lt;"),
                        '>' => out.push_str("&gt;"),
                        '&' => out.push_str("&amp;"),
                        c => out.push(c),
                    }
                }
                last = j;
            }
            i = j.max(i + 1);
        } else {
            i += 1;
        }
    }
    out.push_str(&text[last..]);
    let doc = parse_doc(&out, file)?;
    for n in doc.descendants().filter(Node::is_element) {
        for a in n.attributes() {
            if let Some(k) = a.value().find('$') {
                let name: String = a.value()[k + 1..]
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                if name.is_empty() {
                    continue;
                }
                let pos = doc.text_pos_at(n.range().start);
                return Err(Error::Xml {
                    file: file.to_string(),
                    line: pos.row,
                    col: pos.col,
                    msg: format!("undefined parameter \"${name}\" in attribute \"{}\" (add <default name=\"{name}\" value=\"...\"/> or pass -D {name}=VALUE)", a.name()),
                });
            }
        }
    }
    Ok(out)
}

/// A top-level `<texture id=...>`: parsed when defined, its image decoded on first use.
#[derive(Clone, Debug)]
enum TexDef {
    Bitmap {
        path: PathBuf,
        raw: bool,
        filter: Filter,
        wrap: Wrap,
        uv: UvMap,
        at: String,
    },
    Checker(Texture),
}

/// The geometry and appearance of one `<shape>` before it joins the scene (shapegroups keep
/// these to instantiate them).
#[derive(Clone)]
struct ShapeData {
    prims: Vec<Prim>,
    uvs: Option<Vec<[Vec2; 3]>>,
    material: u32,
    emission: Option<Vec3>,
    opacity: Option<Param>,
    media: Option<MediumInterface>,
}

struct Ctx<'r> {
    /// File being read (changes inside `<include>`).
    file: String,
    /// Its folder.
    base: PathBuf,
    /// The main scene's folder (fallback for relative paths in included files).
    root_base: PathBuf,
    /// Folders added by `<path value="..."/>` (Mitsuba 3), as given relative to their file.
    search: Vec<PathBuf>,
    read: &'r dyn Fn(&Path) -> std::io::Result<Vec<u8>>,
    params: HashMap<String, String>,
    /// Unknown constructs are errors ([`LoadOptions::strict`]).
    strict: bool,
    /// Errors of the top-level elements read so far: the load goes on after one so that a
    /// single run reports every problem of the scene.
    errors: Vec<String>,
    /// Ids of top-level BSDFs that failed to load (their error is already reported; a
    /// `<ref>` to them uses the default material instead of adding an "unknown id" error).
    failed_bsdfs: HashSet<String>,
    /// A spectral list in a Mitsuba 0.x file was already warned about.
    spectrum_warned: bool,
    /// `alpha_u`, `alpha_v` of the rough BSDF being read (see [`Ctx::check_rough`]).
    aniso: [Option<f32>; 2],
    /// Include chain (cycle detection).
    includes: Vec<PathBuf>,
    bsdfs: HashMap<String, u32>,
    /// Material index → opacity of `mask` materials.
    mask_opacity: HashMap<u32, Param>,
    tex_defs: HashMap<String, TexDef>,
    tex_ids: HashMap<String, u32>,
    groups: HashMap<String, Vec<ShapeData>>,
    images: ImageCache,
    builder: SceneBuilder,
    default_material: Option<u32>,
    null_material: Option<u32>,
    black_material: Option<u32>,
    integrator: Option<(u32, u32)>,
    sensor: Option<(Camera, u32, u32, u32)>,
    /// Media by id.
    media: HashMap<String, u32>,
    /// The sensor's medium, if it has one.
    camera_medium: Option<u32>,
}

fn elements<'a, 'i>(n: Node<'a, 'i>) -> impl Iterator<Item = Node<'a, 'i>> {
    n.children().filter(|c| c.is_element())
}

impl Ctx<'_> {
    fn err(&self, n: Node, msg: impl Into<String>) -> Error {
        let pos = n.document().text_pos_at(n.range().start);
        Error::Xml {
            file: self.file.clone(),
            line: pos.row,
            col: pos.col,
            msg: msg.into(),
        }
    }

    /// Prints a warning naming the element's file and line (stderr) and keeps it in
    /// [`Scene::warnings`].
    fn warn(&mut self, n: Node, msg: impl Into<String>) {
        let pos = n.document().text_pos_at(n.range().start);
        let w = format!(
            "{}:{}:{}: warning: {}",
            self.file,
            pos.row,
            pos.col,
            msg.into()
        );
        eprintln!("{w}");
        self.builder.warnings.push(w);
    }

    /// The folders a relative file name is looked up in, in order: the current file's, the
    /// `<path>` folders declared so far (Mitsuba 3's file resolver), the main scene's.
    fn search_dirs(&self) -> Vec<PathBuf> {
        let mut dirs = vec![self.base.clone()];
        for d in self.search.iter().chain(std::iter::once(&self.root_base)) {
            if !dirs.contains(d) {
                dirs.push(d.clone());
            }
        }
        dirs
    }

    /// Reads `f` from the first of [`Ctx::search_dirs`] that has it (the error names the
    /// path in the current file's folder).
    fn read_rel(&self, f: &str) -> Result<(PathBuf, Vec<u8>)> {
        let dirs = self.search_dirs();
        let first = dirs[0].join(f);
        match (self.read)(&first) {
            Ok(b) => Ok((first, b)),
            Err(source) => {
                for d in &dirs[1..] {
                    let p = d.join(f);
                    if let Ok(b) = (self.read)(&p) {
                        return Ok((p, b));
                    }
                }
                Err(Error::Io {
                    path: first,
                    source,
                })
            }
        }
    }

    /// The path `f` resolves to (as [`Ctx::read_rel`] would read it), without reading.
    fn resolve_rel(&self, f: &str) -> PathBuf {
        let dirs = self.search_dirs();
        dirs.iter()
            .map(|d| d.join(f))
            .find(|p| p.exists())
            .unwrap_or_else(|| dirs[0].join(f))
    }

    fn attr<'n>(&self, n: Node<'n, '_>, name: &str) -> Result<&'n str> {
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
        self.err(n, format!("unsupported {what} {}", describe(n)))
    }

    /// Something the loader does not know (a property, an element): ignored with a warning,
    /// or an error with [`LoadOptions::strict`].
    fn ignore(&mut self, n: Node, what: &str) -> Result<()> {
        self.fallback(n, what, "ignored")
    }

    /// An unknown construct replaced by `instead` (said in the warning), or an error with
    /// [`LoadOptions::strict`].
    fn fallback(&mut self, n: Node, what: &str, instead: &str) -> Result<()> {
        if self.strict {
            return Err(self.unsupported(n, what));
        }
        self.warn(n, format!("unsupported {what} {}: {instead}", describe(n)));
        Ok(())
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
    /// decoded with the sRGB transfer function as Mitsuba 0.6's `Spectrum::fromSRGB` does),
    /// `<rgb value="#rrggbb"/>` (0.6: the bytes / 255 taken as linear RGB, as its scene
    /// handler does: `fromLinearRGB`, no decoding) and
    /// `<spectrum value="v"/>` with a single value (grey) or three (RGB), and `<spectrum
    /// value="400:0.1, 500:0.5, ..."/>` (wavelength:value pairs, reduced to RGB as Mitsuba 3
    /// does, see [`crate::scene::spectrum`]) as a reflectance-like (bounded) spectrum.
    /// Every use (reflectance, radiance, IOR) needs finite values `>= 0`.
    fn color(&mut self, n: Node) -> Result<Vec3> {
        self.color_with(n, true)
    }

    /// [`Ctx::color`] for emission and indices of refraction: a spectral list is reduced to
    /// RGB without the D65 weighting and not clamped to 1 (Mitsuba 3's unbounded spectra).
    fn unbounded_color(&mut self, n: Node) -> Result<Vec3> {
        self.color_with(n, false)
    }

    fn color_with(&mut self, n: Node, bounded: bool) -> Result<Vec3> {
        let tag = n.tag_name().name();
        match tag {
            "rgb" | "float" | "srgb" | "spectrum" => {
                let s = self.attr(n, "value")?;
                let v = match s.trim().strip_prefix('#') {
                    // Mitsuba 0.6's scene handler reads `#rrggbb` in both `<srgb>` and
                    // `<rgb>` as bytes / 255; `<srgb>` then decodes them (`fromSRGB`, below),
                    // `<rgb>` keeps them as linear values (`fromLinearRGB`).
                    Some(hex) if matches!(tag, "srgb" | "rgb") => self.hex_color(n, hex)?,
                    _ if tag == "spectrum" && s.contains(':') => {
                        self.spectral_list(n, s, bounded)?
                    }
                    _ => {
                        let v = self.floats(n, s)?;
                        match (v.len(), tag) {
                            (1, _) => Vec3::splat(v[0]),
                            // Mitsuba 0.6 reads a 3-value <spectrum> as linear RGB.
                            (3, "rgb" | "srgb" | "spectrum") => Vec3::new(v[0], v[1], v[2]),
                            _ if tag == "spectrum" => {
                                return Err(self
                                    .err(n, "<spectrum> expects one value (grey) or three (RGB)"))
                            }
                            _ if tag == "float" => {
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
    /// `"400:0.1, 500:0.5, ..."` as linear sRGB ([`crate::scene::spectrum::spectrum_to_rgb`]).
    fn spectral_list(&mut self, n: Node, s: &str, bounded: bool) -> Result<Vec3> {
        let mut pairs = Vec::new();
        for item in s.split(',').map(str::trim).filter(|t| !t.is_empty()) {
            let parsed = item
                .split_once(':')
                .and_then(|(l, v)| Some((l.trim().parse().ok()?, v.trim().parse().ok()?)));
            let Some(pair) = parsed else {
                return Err(self.err(n, format!("cannot parse wavelength:value \"{item}\"")));
            };
            pairs.push(pair);
        }
        let rgb = crate::scene::spectrum::spectrum_to_rgb(&pairs, bounded).ok_or_else(|| {
            self.err(
                n,
                "a spectrum needs two or more finite wavelength:value pairs in increasing wavelength",
            )
        })?;
        let version = n.document().root_element().attribute("version");
        if version.is_some_and(|v| v.starts_with('0')) && !self.spectrum_warned {
            self.spectrum_warned = true;
            self.warn(n, "spectra are reduced to RGB as Mitsuba 3 does (CIE 1931, D65-weighted reflectances); Mitsuba 0.6's own reduction differs slightly (further spectra in this file are converted the same way)");
        }
        Ok(Vec3::from(rgb))
    }

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

    /// The upper 3 × 3 of `to_world` on the `ty` emitter `n`, which must be a rotation: the
    /// environment samplers' pdfs have no Jacobian for scale, shear or mirroring.
    fn rotation(&self, n: Node, ty: &str, to_world: Mat4) -> Result<glam::Mat3> {
        let m = glam::Mat3::from_mat4(to_world);
        let rigid = (m.transpose() * m - glam::Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|x| x.abs() < 1e-3)
            && m.determinant() > 0.0;
        if !rigid {
            return Err(self.err(
                n,
                format!("{ty} to_world must be a rotation (no scale, shear or mirroring)"),
            ));
        }
        Ok(m)
    }

    /// `value="x, y, z"` (or one number for all three) of element `n`.
    fn value_vec3(&self, n: Node, value: &str) -> Result<Vec3> {
        let v = self.floats(n, value)?;
        match v.len() {
            1 => Ok(Vec3::splat(v[0])),
            3 => Ok(Vec3::new(v[0], v[1], v[2])),
            _ => Err(self.err(n, "expected 1 or 3 numbers")),
        }
    }

    /// `<point x= y= z=/>` or `value="x, y, z"`.
    fn vec3(&self, n: Node) -> Result<Vec3> {
        if let Some(v) = n.attribute("value") {
            return self.value_vec3(n, v);
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

    /// The `name` attribute, with Mitsuba 0.6's camelCase (`toWorld`, `maxDepth`, `intIOR`)
    /// read as Mitsuba 3's snake_case.
    fn name<'n>(&self, n: Node<'n, '_>) -> Result<Cow<'n, str>> {
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
            return self.value_vec3(n, v);
        }
        let mut out = Vec3::splat(def);
        for (i, k) in ["x", "y", "z"].iter().enumerate() {
            if let Some(s) = n.attribute(*k) {
                out[i] = self.floats(n, s)?.first().copied().unwrap_or(def);
            }
        }
        Ok(out)
    }

    fn scene(&mut self, root: Node) -> Result<Scene> {
        self.check_root(root)?;
        for n in elements(root) {
            self.top_or_record(n);
        }
        if self.sensor.is_none() && self.errors.is_empty() {
            self.errors
                .push(self.err(root, "the scene has no <sensor>").to_string());
        }
        if !self.errors.is_empty() {
            return Err(Error::Problems(std::mem::take(&mut self.errors)));
        }
        let Some((camera, width, height, spp)) = self.sensor else {
            unreachable!("a missing sensor is recorded as an error above")
        };
        let settings = Settings {
            width,
            height,
            spp,
            max_depth: self.integrator.map_or(1024, |d| d.0),
            rr_depth: self.integrator.map_or(5, |d| d.1),
        };
        let mut builder = std::mem::take(&mut self.builder);
        if let Some(m) = self.camera_medium {
            builder.set_camera_medium(m);
        }
        builder.texture_bytes = self.images.bytes();
        builder.build(camera, settings)
    }

    fn check_root(&self, root: Node) -> Result<()> {
        if root.tag_name().name() != "scene" {
            return Err(self.err(
                root,
                format!(
                    "root element is <{}>, expected <scene>",
                    root.tag_name().name()
                ),
            ));
        }
        Ok(())
    }

    /// [`Ctx::top`], recording its error and going on with the next element (a failed
    /// top-level BSDF leaves its id, and the ids of the BSDFs nested in it that were not
    /// registered before the error, in `failed_bsdfs`).
    fn top_or_record(&mut self, n: Node) {
        if let Err(e) = self.top(n) {
            if n.tag_name().name() == "bsdf" {
                for b in n.descendants().filter(|d| d.tag_name().name() == "bsdf") {
                    if let Some(id) = b.attribute("id") {
                        if !self.bsdfs.contains_key(id) {
                            self.failed_bsdfs.insert(id.to_string());
                        }
                    }
                }
            }
            match e {
                // An include's own list of problems joins this one.
                Error::Problems(list) => self.errors.extend(list),
                e => self.errors.push(e.to_string()),
            }
        }
    }

    /// One top-level element of the scene (or of an included file).
    fn top(&mut self, n: Node) -> Result<()> {
        match n.tag_name().name() {
            "integrator" => self.integrator = Some(self.integrator(n)?),
            "sensor" => {
                if self.sensor.is_some() {
                    return Err(self.err(n, "more than one <sensor> is not supported"));
                }
                self.sensor = Some(self.sensor(n)?);
            }
            // An anonymous top-level object is valid Mitsuba (0.6 and 3): it is built, and the
            // ids of the objects nested in it are registered for later references (Mitsuba
            // 0.6 files often wrap an `id`'d twosided in an anonymous `bumpmap`).
            "bsdf" | "texture" => self.define(n)?,
            "shape" => self.shape(n)?,
            "emitter" => self.emitter(n)?,
            "medium" => {
                self.medium(n)?;
            }
            "include" => self.include(n)?,
            // Mitsuba 3: a folder where relative file names are also looked up.
            "path" => {
                let dir = self.base.join(self.attr(n, "value")?);
                if !self.search.contains(&dir) {
                    self.search.push(dir);
                }
            }
            // Consumed by the `$name` substitution before parsing.
            "default" => {
                self.attr(n, "name")?;
                self.attr(n, "value")?;
            }
            _ => self.ignore(n, "scene element")?,
        }
        Ok(())
    }

    /// `<include filename="..."/>`: the file's top-level elements join the scene; relative
    /// paths inside it resolve against its own folder first. A file that includes itself
    /// (directly or through others) is an error listing the chain.
    fn include(&mut self, n: Node) -> Result<()> {
        let f = self.attr(n, "filename")?;
        let (path, bytes) = self.read_rel(f)?;
        let key = normalize(&path);
        if self.includes.contains(&key) {
            let chain: Vec<String> = self
                .includes
                .iter()
                .chain(std::iter::once(&key))
                .map(|p| p.display().to_string())
                .collect();
            return Err(self.err(n, format!("include cycle: {}", chain.join(" -> "))));
        }
        if self.includes.len() > 32 {
            return Err(self.err(n, "includes nested more than 32 deep"));
        }
        let name = path.display().to_string();
        let text = String::from_utf8(bytes)
            .map_err(|_| self.err(n, format!("included file {name} is not UTF-8 text")))?;
        let text = substitute(&text, &name, &self.params)?;
        let doc = parse_doc(&text, &name)?;
        let saved_file = std::mem::replace(&mut self.file, name);
        let saved_base = std::mem::replace(
            &mut self.base,
            path.parent().map(Path::to_path_buf).unwrap_or_default(),
        );
        self.includes.push(key);
        let result = self.check_root(doc.root_element()).map(|()| {
            for c in elements(doc.root_element()) {
                self.top_or_record(c);
            }
        });
        self.includes.pop();
        self.file = saved_file;
        self.base = saved_base;
        result
    }

    /// `(max_depth, rr_depth)` of the `<integrator>`. `path` is read; every other type is
    /// rendered with `path` at its `max_depth` (`direct`: at 2, i.e. direct light only) with
    /// a warning, an error with `--strict`; a wrapper such as `aov` is read through its
    /// nested `<integrator>`.
    fn integrator(&mut self, n: Node) -> Result<(u32, u32)> {
        let ty = n.attribute("type").unwrap_or("");
        // The volumetric path tracers are `path` with media (host-demo renders media
        // whichever integrator the file names).
        let known = matches!(ty, "path" | "volpath" | "volpath_simple" | "volpathmis");
        let (mut depth, mut rr_depth) = (if ty == "direct" { 2 } else { 1024 }, 5);
        if !known {
            let instead = match ty {
                "direct" => "rendered with \"path\" at max_depth 2 (direct light)",
                _ => "rendered with \"path\" at its max_depth (its other properties are ignored)",
            };
            self.fallback(n, "integrator type", instead)?;
        }
        for p in elements(n) {
            let tag = p.tag_name().name();
            if tag == "integrator" {
                (depth, rr_depth) = self.integrator(p)?;
                continue;
            }
            match (tag, self.name(p)?.as_ref()) {
                ("integer", "max_depth") => {
                    let d = self.integer(p)?;
                    depth = if d < 0 { 1024 } else { d.min(1 << 20) as u32 };
                }
                // Russian roulette start depth (used with `--rr`; RR is off by default).
                ("integer", "rr_depth") => {
                    rr_depth = self.integer(p)?.clamp(1, 1 << 20) as u32;
                }
                ("boolean", "strict_normals") if known => self.warn(
                    p,
                    "strict_normals is ignored (light leaks through shading normals are \
                     rejected by a geometric side test instead)",
                ),
                ("boolean", "hide_emitters") if known && self.boolean(p)? => self.warn(
                    p,
                    "hide_emitters=true is not supported: emitters seen directly stay visible",
                ),
                ("boolean", "hide_emitters") => {}
                _ if known => self.ignore(p, "integrator property")?,
                _ => {}
            }
        }
        Ok((depth, rr_depth))
    }

    fn sensor(&mut self, n: Node) -> Result<(Camera, u32, u32, u32)> {
        let thin_lens = match n.attribute("type") {
            Some("perspective") => false,
            Some("thinlens") => true,
            _ => {
                return Err(self.unsupported(n, "sensor type (perspective or thinlens)"));
            }
        };
        let (mut aperture, mut focus) = (0.0f32, 0.0f32);
        let (mut fov, mut axis, mut to_world) = (None, "x".to_string(), Mat4::IDENTITY);
        let (mut w, mut h, mut spp) = (768u32, 576u32, 4u32);
        for p in elements(n) {
            let tag = p.tag_name().name();
            if matches!(tag, "medium" | "ref") {
                // The medium the camera sits in.
                self.camera_medium = Some(self.medium_or_ref(p)?);
                continue;
            }
            let pname = match tag {
                "sampler" | "film" => Cow::Borrowed(""),
                _ => self.name(p)?,
            };
            match (tag, pname.as_ref()) {
                ("float", "fov") => fov = Some(self.float(p)?),
                ("float", "aperture_radius") if thin_lens => aperture = self.float(p)?,
                ("float", "focus_distance") if thin_lens => focus = self.float(p)?,
                // Clipping planes do not change the image of a closed-form pinhole for these scenes.
                ("float", "near_clip" | "far_clip") => {}
                // Mitsuba's projective cameras all read it; a pinhole's image does not depend on it.
                ("float", "focus_distance") => {}
                ("string", "fov_axis") => axis = self.attr(p, "value")?.to_string(),
                ("transform", "to_world") => to_world = self.transform(p)?,
                ("sampler", _) => {
                    let ty = p.attribute("type").unwrap_or("");
                    match ty {
                        "independent" => {}
                        "stratified" | "multijitter" | "orthogonal" | "ldsampler" | "halton"
                        | "hammersley" | "sobol" | "correlated" | "ldsampler_" => self.warn(
                            p,
                            format!("sampler \"{ty}\" is replaced by \"independent\" (same expected image, different noise)"),
                        ),
                        _ => self.fallback(
                            p,
                            "sampler type",
                            "replaced by \"independent\" (same expected image, different noise)",
                        )?,
                    }
                    for q in elements(p) {
                        match (q.tag_name().name(), self.name(q)?.as_ref()) {
                            ("integer", "sample_count") => spp = self.positive(q)?,
                            ("integer", "seed") => {}
                            ("integer", "dimension" | "scramble")
                            | ("boolean", "jitter" | "randomize")
                                if ty != "independent" => {}
                            _ => self.ignore(q, "sampler property")?,
                        }
                    }
                }
                ("film", _) => {
                    let ty = p.attribute("type").unwrap_or("");
                    match ty {
                        "hdrfilm" => {}
                        "ldrfilm" => self.warn(
                            p,
                            "ldrfilm: the image is written as EXR plus an sRGB PNG preview; its tonemapping parameters are ignored",
                        ),
                        _ => self.fallback(p, "film type", "written as hdrfilm (EXR + PNG)")?,
                    }
                    for q in elements(p) {
                        let qtag = q.tag_name().name();
                        if qtag == "rfilter" {
                            match q.attribute("type").unwrap_or("") {
                                "box" => {}
                                f @ ("gaussian" | "tent" | "mitchell" | "catmullrom"
                                | "lanczos") => {
                                    let f = f.to_string();
                                    self.warn(q, format!("reconstruction filter \"{f}\" is replaced by \"box\" (slightly sharper image)"));
                                }
                                _ => self.fallback(
                                    q,
                                    "reconstruction filter",
                                    "replaced by \"box\"",
                                )?,
                            }
                            continue;
                        }
                        match (qtag, self.name(q)?.as_ref()) {
                            ("integer", "width") => w = self.positive(q)?,
                            ("integer", "height") => h = self.positive(q)?,
                            // Output-format options: the output is always EXR + PNG.
                            ("string", "file_format" | "pixel_format" | "component_format")
                            | ("boolean", "banner" | "high_quality_edges" | "attach_log") => {}
                            (
                                "string" | "float" | "boolean",
                                "tonemap_method" | "gamma" | "exposure" | "key" | "burn",
                            ) if ty == "ldrfilm" => {}
                            _ => self.ignore(q, "film property")?,
                        }
                    }
                }
                _ => self.ignore(p, "sensor property")?,
            }
        }
        check_invertible(&to_world).map_err(|e| {
            self.err(
                n,
                format!("sensor to_world is singular, the camera has no valid rays: {e}"),
            )
        })?;
        let fov = fov.ok_or_else(|| self.err(n, "perspective sensor needs a \"fov\" float"))?;
        if !(fov > 0.0 && fov < 180.0) {
            return Err(self.err(n, format!("fov {fov} must be in (0, 180) degrees")));
        }
        let mut cam =
            Camera::new(to_world, fov, &axis, w, h).map_err(|e| self.err(n, e.to_string()))?;
        if thin_lens {
            if !(aperture.is_finite() && aperture >= 0.0) {
                return Err(self.err(n, format!("aperture_radius {aperture} must be >= 0")));
            }
            if aperture > 0.0 {
                if !(focus.is_finite() && focus > 0.0) {
                    return Err(self.err(
                        n,
                        format!("thinlens needs a positive focus_distance (got {focus})"),
                    ));
                }
                cam = cam.with_thin_lens(aperture, focus);
            }
        }
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

    /// Microfacet roughness and distribution properties shared by the rough BSDFs; returns true
    /// if the property was one of them. A textured `alpha` goes to `alpha_tex`.
    fn rough_property(
        &mut self,
        p: Node,
        distribution: &mut String,
        alpha: &mut f32,
        alpha_tex: &mut Option<u32>,
    ) -> Result<bool> {
        match (p.tag_name().name(), self.name(p)?.as_ref()) {
            ("string", "distribution") => *distribution = self.attr(p, "value")?.to_string(),
            ("float", "alpha") => *alpha = self.float(p)?,
            ("float", "alpha_u") => self.aniso[0] = Some(self.float(p)?),
            ("float", "alpha_v") => self.aniso[1] = Some(self.float(p)?),
            ("texture" | "ref", "alpha") => {
                *alpha_tex = Some(self.texture_param(p)?);
            }
            // Visible-normal sampling is what we do anyway; `false` would only change variance.
            ("boolean", "sample_visible") => {}
            _ => return Ok(false),
        }
        Ok(true)
    }

    fn check_rough(
        &mut self,
        n: Node,
        distribution: &str,
        alpha: f32,
    ) -> Result<(Microfacet, f32)> {
        let ty = n.attribute("type").unwrap_or("");
        let alpha = match std::mem::take(&mut self.aniso) {
            [None, None] => alpha,
            [u, v] => {
                let (u, v) = (u.unwrap_or(alpha), v.unwrap_or(alpha));
                let iso = (u * v).sqrt();
                self.warn(
                    n,
                    format!("{ty}: anisotropic roughness alpha_u {u}, alpha_v {v} is approximated by the isotropic alpha {iso} = sqrt(alpha_u alpha_v)"),
                );
                iso
            }
        };
        // Mitsuba 0.6 compares the name lower-cased.
        let name = distribution.to_ascii_lowercase();
        let parsed = match name.as_str() {
            // Mitsuba 0.6's Phong distribution (`as`: its anisotropic Ashikhmin–Shirley form)
            // with the exponent `n = 2/α² − 2` it derives from alpha (Walter et al. 2007,
            // section 5.2): Walter et al. chose that relation so that Phong's
            // `(n+2)/(2π) cosⁿθ` approximates Beckmann's `exp(−tan²θ/α²)/(π α² cos⁴θ)` at the
            // same alpha, and Mitsuba 0.6 uses Beckmann's masking for both. The renderer's
            // microfacet BSDFs are sampled by visible normals, which Phong has no sampler
            // for, so the Beckmann distribution at that alpha stands in for it.
            "phong" | "as" => {
                self.warn(
                    n,
                    format!("{ty}: distribution \"{distribution}\" (Mitsuba 0.6's Phong microfacets, exponent 2/alpha^2 - 2) is approximated by \"beckmann\" at the same alpha (Walter et al. 2007's equivalence)"),
                );
                Some(Microfacet::Beckmann)
            }
            other => Microfacet::parse(other),
        };
        let Some(distribution) = parsed else {
            return Err(self.err(
                n,
                format!("{ty} distribution \"{distribution}\" is not supported (\"beckmann\", \"ggx\", or \"phong\" approximated by \"beckmann\")"),
            ));
        };
        if !(alpha > 0.0 && alpha.is_finite()) {
            return Err(self.err(n, format!("alpha {alpha} must be positive")));
        }
        Ok((distribution, alpha.max(1e-4)))
    }

    /// A colour parameter: a constant, an inline `<texture>` or a `<ref>` to a texture id.
    fn param(&mut self, p: Node) -> Result<Param> {
        match p.tag_name().name() {
            "texture" | "ref" => Ok(Param::Tex(self.texture_param(p)?)),
            _ => Ok(Param::Const(self.color(p)?)),
        }
    }

    /// A scalar parameter in `[0, 1]` (`float` or texture), as a [`Param`].
    fn unit_param(&mut self, p: Node) -> Result<Param> {
        match p.tag_name().name() {
            "float" => {
                let v = self.float(p)?;
                if !(0.0..=1.0).contains(&v) {
                    return Err(self.err(p, format!("value {v} must be in [0, 1]")));
                }
                Ok(Param::Const(Vec3::splat(v)))
            }
            _ => self.param(p),
        }
    }

    /// The texture index of an inline `<texture>` or of a `<ref id=...>` to a texture.
    fn texture_param(&mut self, p: Node) -> Result<u32> {
        if p.tag_name().name() == "ref" {
            let id = self.attr(p, "id")?;
            if let Some(&t) = self.tex_ids.get(id) {
                return Ok(t);
            }
            let def =
                self.tex_defs.get(id).cloned().ok_or_else(|| {
                    self.err(p, format!("reference to unknown texture id \"{id}\""))
                })?;
            let t = self.instantiate(p, def)?;
            self.tex_ids.insert(id.to_string(), t);
            return Ok(t);
        }
        let def = self.texture_def(p)?;
        let t = self.instantiate(p, def)?;
        if let Some(id) = p.attribute("id") {
            // A nested texture with an id can be referenced later, as in Mitsuba.
            self.tex_ids.insert(id.to_string(), t);
        }
        Ok(t)
    }

    fn instantiate(&mut self, p: Node, def: TexDef) -> Result<u32> {
        let t = match def {
            TexDef::Checker(t) => t,
            TexDef::Bitmap {
                path,
                raw,
                filter,
                wrap,
                uv,
                at,
            } => {
                let image = self
                    .images
                    .get(&path, raw, self.read)
                    .map_err(|e| self.err(p, format!("texture defined at {at}: {e}")))?;
                Texture::Bitmap {
                    image,
                    filter,
                    wrap,
                    uv,
                }
            }
        };
        Ok(self.builder.texture(t))
    }

    /// Parses a `<texture>` element (`bitmap` or `checkerboard`); images are not decoded yet.
    fn texture_def(&mut self, n: Node) -> Result<TexDef> {
        let ty = n.attribute("type").unwrap_or("");
        if !matches!(ty, "bitmap" | "checkerboard") {
            self.fallback(
                n,
                "texture type (bitmap or checkerboard)",
                "replaced by a constant 0.5 grey",
            )?;
            self.register_nested_ids(n)?;
            let grey = Vec3::splat(0.5);
            return Ok(TexDef::Checker(Texture::Checkerboard {
                color0: grey,
                color1: grey,
                uv: UvMap::default(),
            }));
        }
        let mut uv = UvMap::default();
        let (mut off, mut scale) = (Vec2::ZERO, Vec2::ONE);
        let mut has_06 = false;
        let (mut filename, mut raw) = (None, false);
        let (mut filter, mut wrap) = (Filter::Bilinear, Wrap::Repeat);
        let (mut c0, mut c1) = (Vec3::splat(0.4), Vec3::splat(0.2));
        for p in elements(n) {
            let tag = p.tag_name().name();
            let pname = self.name(p)?;
            match (tag, pname.as_ref(), ty) {
                ("transform", "to_uv", _) => {
                    let m = self.transform(p)?;
                    uv = UvMap {
                        m: glam::Mat2::from_cols(
                            m.x_axis.truncate().truncate(),
                            m.y_axis.truncate().truncate(),
                        ),
                        t: m.w_axis.truncate().truncate(),
                    };
                }
                ("float", "uoffset", _) => (off.x, has_06) = (self.float(p)?, true),
                ("float", "voffset", _) => (off.y, has_06) = (self.float(p)?, true),
                ("float", "uscale", _) => (scale.x, has_06) = (self.float(p)?, true),
                ("float", "vscale", _) => (scale.y, has_06) = (self.float(p)?, true),
                ("string", "filename", "bitmap") => {
                    filename = Some(self.attr(p, "value")?.to_string())
                }
                ("boolean", "raw", "bitmap") => raw = self.boolean(p)?,
                ("string", "filter_type", "bitmap") => {
                    filter = match self.attr(p, "value")? {
                        "bilinear" => Filter::Bilinear,
                        "nearest" => Filter::Nearest,
                        // Mitsuba 0.6 filters: EWA / trilinear mip-mapping reduce aliasing only.
                        v @ ("ewa" | "trilinear") => {
                            let v = v.to_string();
                            self.warn(p, format!("filter_type \"{v}\" is approximated by \"bilinear\" (no mip-mapping)"));
                            Filter::Bilinear
                        }
                        v => {
                            return Err(self.err(
                                p,
                                format!("unknown filter_type \"{v}\" (bilinear or nearest)"),
                            ))
                        }
                    }
                }
                ("string", "wrap_mode" | "wrap_mode_u" | "wrap_mode_v", "bitmap") => {
                    wrap = match self.attr(p, "value")? {
                        "repeat" => Wrap::Repeat,
                        "mirror" => Wrap::Mirror,
                        "clamp" => Wrap::Clamp,
                        v => {
                            return Err(self.err(
                                p,
                                format!("unknown wrap_mode \"{v}\" (repeat, mirror or clamp)"),
                            ))
                        }
                    }
                }
                // Mitsuba 0.6 bitmap options that do not change linear RGB textures.
                ("string", "cache" | "channel", "bitmap")
                | ("float", "max_anisotropy", "bitmap") => {}
                ("float", "gamma", "bitmap") => {
                    let g = self.float(p)?;
                    self.warn(p, format!("bitmap gamma {g} is ignored (8-bit images are sRGB-decoded unless raw)"));
                }
                (_, "color0", "checkerboard") => c0 = self.color(p)?,
                (_, "color1", "checkerboard") => c1 = self.color(p)?,
                _ => self.ignore(p, &format!("property of texture \"{ty}\""))?,
            }
        }
        if has_06 {
            uv = UvMap {
                m: uv.m * glam::Mat2::from_diagonal(scale),
                t: uv.t + off,
            };
        }
        let pos = n.document().text_pos_at(n.range().start);
        let at = format!("{}:{}", self.file, pos.row);
        match ty {
            "bitmap" => {
                let f = filename
                    .ok_or_else(|| self.err(n, "bitmap texture needs a \"filename\" string"))?;
                Ok(TexDef::Bitmap {
                    path: self.resolve_rel(&f),
                    raw,
                    filter,
                    wrap,
                    uv,
                    at,
                })
            }
            "checkerboard" => Ok(TexDef::Checker(Texture::Checkerboard {
                color0: c0,
                color1: c1,
                uv,
            })),
            _ => unreachable!("unknown texture types return early"),
        }
    }

    /// Adds `m` with textured parameters where `tex` has any.
    fn add_material(&mut self, m: Material, tex: MaterialTextures) -> u32 {
        self.builder.textured_material(m, tex)
    }

    /// A colour [`Self::param`] split into the constant stored in the material (0.5 grey for a
    /// texture: it only serves as a placeholder) and the texture `slot`.
    fn color_param(&mut self, p: Node, slot: &mut Option<u32>) -> Result<Vec3> {
        Ok(match self.param(p)? {
            Param::Const(c) => c,
            Param::Tex(t) => {
                *slot = Some(t);
                Vec3::splat(0.5)
            }
        })
    }

    /// True if material `idx` (looking through blends) is one-sided and no twosided itself.
    fn wrappable(&self, idx: u32) -> bool {
        let mats = self.builder.materials();
        let mut stack = vec![idx];
        while let Some(i) = stack.pop() {
            match mats[i as usize] {
                Material::TwoSided { .. } => return false,
                Material::Blend { a, b, .. } => stack.extend([a, b]),
                m if !m.one_sided() => return false,
                _ => {}
            }
        }
        true
    }

    /// The children of a plugin the loader replaces (an unknown BSDF or texture type) that
    /// Mitsuba would build and register by id: nested `<bsdf>`s whose subtree carries an `id`
    /// are read (registering them and their own nested ids, see [`Ctx::bsdf`]), nested
    /// `<texture>`s with an `id` are defined for later `<ref>`s (and those without one are
    /// searched for nested ids the same way). Everything else of the replaced plugin is left
    /// to its warning.
    fn register_nested_ids(&mut self, n: Node) -> Result<()> {
        for c in elements(n) {
            if !c.descendants().any(|d| d.attribute("id").is_some()) {
                continue;
            }
            self.define(c)?;
        }
        Ok(())
    }

    /// A `<bsdf>` (built, its id and its nested ids registered, see [`Ctx::bsdf`]) or a
    /// `<texture>` (defined under its id, if it has one, for later `<ref>`s); other elements
    /// are left alone.
    fn define(&mut self, n: Node) -> Result<()> {
        match n.tag_name().name() {
            "bsdf" => {
                self.bsdf(n)?;
            }
            "texture" => {
                let def = self.texture_def(n)?;
                if let Some(id) = n.attribute("id") {
                    self.tex_defs.insert(id.to_string(), def);
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// A nested `<bsdf>` or `<ref>` of a wrapper BSDF; `None` (with a warning, an error
    /// with `--strict`) for anything else.
    fn nested_bsdf(&mut self, p: Node, what: &str) -> Result<Option<u32>> {
        match p.tag_name().name() {
            "bsdf" => self.bsdf(p).map(Some),
            "ref" => self.bsdf_ref(p).map(Some),
            _ => self.ignore(p, what).map(|()| None),
        }
    }

    /// Parses a `<bsdf>` (nested ones of wrappers first), adds it to the scene and returns
    /// its material index. An `id` registers it for later `<ref>`s, nested or not (as
    /// Mitsuba does: a BSDF inside a `twosided` or `bumpmap` can be referenced by id).
    fn bsdf(&mut self, n: Node) -> Result<u32> {
        let idx = self.bsdf_body(n)?;
        if let Some(id) = n.attribute("id") {
            self.bsdfs.insert(id.to_string(), idx);
        }
        Ok(idx)
    }

    /// Reads a `<bsdf>` of any type (one helper per family of plugin names), adds its
    /// material and returns the index; `mask` and the bump maps return theirs directly.
    fn bsdf_body(&mut self, n: Node) -> Result<u32> {
        self.aniso = [None, None];
        let ty = n.attribute("type").unwrap_or("");
        let mut tex = MaterialTextures::default();
        let m = match ty {
            "diffuse" => self.diffuse_bsdf(n, &mut tex)?,
            "roughdiffuse" => self.roughdiffuse_bsdf(n, &mut tex)?,
            "conductor" | "roughconductor" => self.conductor_bsdf(n, ty, &mut tex)?,
            "dielectric" | "roughdielectric" | "thindielectric" => {
                self.dielectric_bsdf(n, ty, &mut tex)?
            }
            "plastic" | "roughplastic" => self.plastic_bsdf(n, ty, &mut tex)?,
            "twosided" => self.twosided_bsdf(n)?,
            "blendbsdf" => self.blend_bsdf(n, &mut tex)?,
            "mask" => return self.mask_bsdf(n),
            "bumpmap" | "normalmap" => return self.bump_bsdf(n, ty),
            "phong" | "ward" => self.phong_ward_bsdf(n, ty, &mut tex)?,
            "null" => Material::Null,
            _ => self.unknown_bsdf(n)?,
        };
        Ok(self.add_material(m, tex))
    }

    /// `diffuse`: a constant or textured `reflectance` (default 0.5).
    fn diffuse_bsdf(&mut self, n: Node, tex: &mut MaterialTextures) -> Result<Material> {
        let mut reflectance = Vec3::splat(0.5);
        for p in elements(n) {
            match self.name(p)?.as_ref() {
                "reflectance" => reflectance = self.color_param(p, &mut tex.diffuse)?,
                _ => self.ignore(p, "diffuse property")?,
            }
        }
        Ok(Material::Diffuse { reflectance })
    }

    /// Mitsuba 0.6 `roughdiffuse` (Oren–Nayar, see [`crate::scene::bsdf::oren_nayar`]):
    /// `reflectance` (or `diffuseReflectance`) and `alpha` constants or textures,
    /// `useFastApprox`; its defaults 0.5, 0.2 and false.
    fn roughdiffuse_bsdf(&mut self, n: Node, tex: &mut MaterialTextures) -> Result<Material> {
        let (mut reflectance, mut alpha, mut fast) = (Vec3::splat(0.5), 0.2f32, false);
        let mut conserve = true;
        for p in elements(n) {
            match (p.tag_name().name(), self.name(p)?.as_ref()) {
                (_, "reflectance" | "diffuse_reflectance") => {
                    reflectance = self.color_param(p, &mut tex.diffuse)?
                }
                ("float", "alpha") => alpha = self.float(p)?,
                ("texture" | "ref", "alpha") => tex.scalar = Some(self.texture_param(p)?),
                ("boolean", "use_fast_approx") => fast = self.boolean(p)?,
                ("boolean", "ensure_energy_conservation") => conserve = self.boolean(p)?,
                _ => self.ignore(p, "roughdiffuse property")?,
            }
        }
        if !(alpha.is_finite() && alpha >= 0.0) {
            return Err(self.err(
                n,
                format!("roughdiffuse alpha {alpha} must be finite and >= 0"),
            ));
        }
        // Mitsuba 0.6's `ensureEnergyConservation(reflectance, 1)`: a reflectance
        // above 1 in some channel is scaled by 0.99 / max.
        let max = reflectance.max_element();
        if conserve && tex.diffuse.is_none() && max > 1.0 {
            let scale = 0.99 / max;
            self.warn(n, format!("roughdiffuse: reflectance reaches {max} (> 1, not energy conserving); scaled by {scale} as Mitsuba 0.6 does"));
            reflectance *= scale;
        }
        Ok(Material::RoughDiffuse {
            reflectance,
            alpha,
            fast,
        })
    }

    /// `conductor` and `roughconductor`: a named material or `eta`, `k`, Mitsuba 0.6's `ext_eta`,
    /// `specular_reflectance`, and the rough one's microfacet properties.
    fn conductor_bsdf(
        &mut self,
        n: Node,
        ty: &str,
        tex: &mut MaterialTextures,
    ) -> Result<Material> {
        let (mut alpha, mut eta, mut k) = (0.1f32, Vec3::ZERO, Vec3::ONE);
        let (mut ext_eta, mut specular) = (1.0f32, Vec3::ONE);
        let mut distribution = "beckmann".to_string();
        for p in elements(n) {
            if ty == "roughconductor"
                && self.rough_property(p, &mut distribution, &mut alpha, &mut tex.scalar)?
            {
                continue;
            }
            match (p.tag_name().name(), self.name(p)?.as_ref()) {
                ("string", "material") => {
                    let name = self.attr(p, "value")?;
                    let (e, kk) = named_conductor(name).ok_or_else(|| {
                        self.err(p, format!("unknown conductor material \"{name}\" (Mitsuba's names: Ag, Al, Au, Cu, Cr, ...; see host-demo/src/conductors.rs)"))
                    })?;
                    (eta, k) = (Vec3::from(e), Vec3::from(kk));
                }
                (_, "eta") => eta = self.unbounded_color(p)?,
                (_, "k") => k = self.unbounded_color(p)?,
                // Mitsuba 0.6: the exterior medium's real IOR (a float or a name).
                (_, "ext_eta") => ext_eta = self.ior(p)?,
                (_, "specular_reflectance") => specular = self.color_param(p, &mut tex.specular)?,
                // Research forks of 0.6 put a roughness on smooth conductors; 0.6
                // itself ignores it.
                (_, "alpha" | "alpha_u" | "alpha_v" | "distribution") if ty == "conductor" => {
                    self.warn(p, "a roughness on a smooth conductor is ignored (as Mitsuba 0.6 does); use roughconductor")
                }
                _ => self.ignore(p, &format!("{ty} property"))?,
            }
        }
        // 0.6's `extEta`: the Fresnel term sees the IOR relative to the exterior.
        let (eta, k) = (eta / ext_eta, k / ext_eta);
        if ty == "conductor" {
            return Ok(Material::Conductor { eta, k, specular });
        }
        let (distribution, alpha) = self.check_rough(n, &distribution, alpha)?;
        Ok(Material::RoughConductor {
            distribution,
            alpha,
            eta,
            k,
            specular,
        })
    }

    /// `dielectric`, `roughdielectric` and `thindielectric`: the two IORs, the reflectance and
    /// transmittance multipliers, and the rough one's microfacet properties.
    fn dielectric_bsdf(
        &mut self,
        n: Node,
        ty: &str,
        tex: &mut MaterialTextures,
    ) -> Result<Material> {
        let (mut int_ior, mut ext_ior, mut alpha) = (1.5046f32, 1.000_277f32, 0.1f32);
        let (mut reflectance, mut transmittance) = (Vec3::ONE, Vec3::ONE);
        let mut distribution = "beckmann".to_string();
        for p in elements(n) {
            if ty == "roughdielectric"
                && self.rough_property(p, &mut distribution, &mut alpha, &mut tex.scalar)?
            {
                continue;
            }
            match self.name(p)?.as_ref() {
                "int_ior" => int_ior = self.ior(p)?,
                "ext_ior" => ext_ior = self.ior(p)?,
                "specular_reflectance" => reflectance = self.color_param(p, &mut tex.specular)?,
                "specular_transmittance" => transmittance = self.color_param(p, &mut tex.transmittance)?,
                "alpha" | "alpha_u" | "alpha_v" | "distribution" if ty != "roughdielectric" => {
                    self.warn(p, format!("a roughness on {ty} is ignored (as Mitsuba 0.6 does); use roughdielectric"))
                }
                _ => self.ignore(p, &format!("{ty} property"))?,
            }
        }
        if int_ior == ext_ior {
            return Err(self.err(n, "int_ior and ext_ior must differ"));
        }
        let eta = int_ior / ext_ior;
        Ok(match ty {
            "dielectric" => Material::Dielectric {
                eta,
                reflectance,
                transmittance,
            },
            "thindielectric" => Material::ThinDielectric {
                eta,
                reflectance,
                transmittance,
            },
            _ => {
                let (distribution, alpha) = self.check_rough(n, &distribution, alpha)?;
                Material::RoughDielectric {
                    distribution,
                    alpha,
                    eta,
                    reflectance,
                    transmittance,
                }
            }
        })
    }

    /// `plastic` and `roughplastic`: the IORs, the diffuse and specular reflectances,
    /// `nonlinear`, and the rough one's microfacet properties (a constant alpha only).
    fn plastic_bsdf(&mut self, n: Node, ty: &str, tex: &mut MaterialTextures) -> Result<Material> {
        let (mut int_ior, mut ext_ior, mut alpha) = (1.49f32, 1.000_277f32, 0.1f32);
        let (mut diffuse, mut specular) = (Vec3::splat(0.5), Vec3::ONE);
        let mut nonlinear = false;
        let mut distribution = "beckmann".to_string();
        let mut alpha_tex = None;
        for p in elements(n) {
            if ty == "roughplastic"
                && self.rough_property(p, &mut distribution, &mut alpha, &mut alpha_tex)?
            {
                if alpha_tex.is_some() {
                    return Err(self.err(p, "a textured alpha on roughplastic is not supported (its coating tables are precomputed per alpha); use a float"));
                }
                continue;
            }
            match (p.tag_name().name(), self.name(p)?.as_ref()) {
                (_, "int_ior") => int_ior = self.ior(p)?,
                (_, "ext_ior") => ext_ior = self.ior(p)?,
                (_, "diffuse_reflectance") => diffuse = self.color_param(p, &mut tex.diffuse)?,
                (_, "specular_reflectance") => specular = self.color_param(p, &mut tex.specular)?,
                ("boolean", "nonlinear") => nonlinear = self.boolean(p)?,
                _ => self.ignore(p, &format!("{ty} property"))?,
            }
        }
        if int_ior == ext_ior {
            return Err(self.err(n, "int_ior and ext_ior must differ"));
        }
        let coating = Coating::smooth(diffuse, specular, int_ior / ext_ior, nonlinear);
        if ty == "plastic" {
            return Ok(Material::Plastic(coating));
        }
        let (distribution, alpha) = self.check_rough(n, &distribution, alpha)?;
        Ok(Material::RoughPlastic(
            coating.roughened(distribution, alpha),
        ))
    }

    /// `twosided`: one nested BSDF for both sides, or front and back; only opaque one-sided
    /// BSDFs can be wrapped.
    fn twosided_bsdf(&mut self, n: Node) -> Result<Material> {
        let mut sides = Vec::new();
        for p in elements(n) {
            let Some(idx) = self.nested_bsdf(p, "twosided property")? else {
                continue;
            };
            if !self.wrappable(idx) {
                return Err(self.err(p, "twosided can only wrap opaque, one-sided BSDFs (not dielectrics or another twosided)"));
            }
            sides.push(idx);
        }
        match sides.as_slice() {
            [f] => Ok(Material::TwoSided {
                front: *f,
                back: *f,
            }),
            [f, b] => Ok(Material::TwoSided {
                front: *f,
                back: *b,
            }),
            _ => Err(self.err(n, "twosided needs one or two nested BSDFs")),
        }
    }

    /// `blendbsdf`: exactly two nested BSDFs and a constant or textured `weight`.
    fn blend_bsdf(&mut self, n: Node, tex: &mut MaterialTextures) -> Result<Material> {
        let mut parts = Vec::new();
        let mut weight = Param::Const(Vec3::splat(0.5));
        for p in elements(n) {
            match (
                p.tag_name().name(),
                p.attribute("name").map(prop_name).as_deref(),
            ) {
                ("bsdf", _) | ("ref", None) => {
                    parts.extend(self.nested_bsdf(p, "blendbsdf property")?)
                }
                (_, Some("weight")) => weight = self.unit_param(p)?,
                _ => self.ignore(p, "blendbsdf property")?,
            }
        }
        let [a, b] = parts[..] else {
            return Err(self.err(
                n,
                format!(
                    "blendbsdf needs exactly two nested BSDFs (found {})",
                    parts.len()
                ),
            ));
        };
        let w = match weight {
            Param::Const(c) => c.x,
            Param::Tex(t) => {
                tex.scalar = Some(t);
                0.5
            }
        };
        Ok(Material::Blend { a, b, weight: w })
    }

    /// `mask`: a copy of the nested BSDF's material that carries the opacity (its index).
    fn mask_bsdf(&mut self, n: Node) -> Result<u32> {
        let mut nested = None;
        let mut opacity = Param::Const(Vec3::splat(0.5));
        for p in elements(n) {
            match (
                p.tag_name().name(),
                p.attribute("name").map(prop_name).as_deref(),
            ) {
                ("bsdf", _) | ("ref", None) => nested = self.nested_bsdf(p, "mask property")?,
                (_, Some("opacity")) => opacity = self.unit_param(p)?,
                _ => self.ignore(p, "mask property")?,
            }
        }
        let inner = nested.ok_or_else(|| self.err(n, "mask needs a nested BSDF"))?;
        if let Param::Const(c) = opacity {
            if c.x > 0.0 && c.x < 1.0 {
                self.warn(n, format!("mask opacity {} is approximated as a cut-out: {} (opacity < 0.5 is fully transparent, otherwise opaque)", c.x, if c.x < 0.5 { "fully transparent" } else { "opaque" }));
            }
        }
        // A copy of the nested material that carries the opacity.
        let m = self.builder.materials()[inner as usize];
        let t = self.builder.material_textures()[inner as usize];
        let idx = self.add_material(m, t);
        self.mask_opacity.insert(idx, opacity);
        Ok(idx)
    }

    /// `bumpmap` and `normalmap`: the nested BSDF's own index (the perturbation is ignored,
    /// with a warning); a texture with an id stays available to later references.
    fn bump_bsdf(&mut self, n: Node, ty: &str) -> Result<u32> {
        let mut nested = None;
        for p in elements(n) {
            match p.tag_name().name() {
                "bsdf" | "ref"
                    if p.attribute("name").is_none() || p.tag_name().name() == "bsdf" =>
                {
                    nested = self.nested_bsdf(p, &format!("{ty} property"))?
                }
                // The bump / normal texture itself and its scale are not used; a
                // texture with an id stays available to later references.
                "texture" => {
                    if let Some(id) = p.attribute("id") {
                        let def = self.texture_def(p)?;
                        self.tex_defs.insert(id.to_string(), def);
                    } else {
                        self.register_nested_ids(p)?;
                    }
                }
                "ref" | "float" => {}
                _ => self.ignore(p, &format!("{ty} property"))?,
            }
        }
        let inner = nested.ok_or_else(|| self.err(n, format!("{ty} needs a nested BSDF")))?;
        self.warn(
            n,
            format!(
                "{ty} is ignored: the nested BSDF is rendered with the unperturbed shading normal"
            ),
        );
        Ok(inner)
    }

    /// Mitsuba 0.6 `phong` / `ward`, with their defaults; `ensureEnergyConservation` (on by
    /// default) scales kd and ks by 0.99 / max_c(kd + ks) where that is > 1.
    fn phong_ward_bsdf(
        &mut self,
        n: Node,
        ty: &str,
        tex: &mut MaterialTextures,
    ) -> Result<Material> {
        let (mut diffuse, mut specular) = (Vec3::splat(0.5), Vec3::splat(0.2));
        let (mut exponent, mut variant) = (30.0f32, crate::scene::bsdf::WardVariant::Balanced);
        let (mut alpha, mut alpha_u, mut alpha_v) = (0.1f32, None, None);
        let mut conserve = true;
        for p in elements(n) {
            match (p.tag_name().name(), self.name(p)?.as_ref()) {
                (_, "diffuse_reflectance") => diffuse = self.color_param(p, &mut tex.diffuse)?,
                (_, "specular_reflectance") => specular = self.color_param(p, &mut tex.specular)?,
                ("boolean", "ensure_energy_conservation") => conserve = self.boolean(p)?,
                ("float", "exponent") if ty == "phong" => exponent = self.float(p)?,
                ("string", "variant") if ty == "ward" => {
                    let v = self.attr(p, "value")?;
                    variant = crate::scene::bsdf::WardVariant::parse(v).ok_or_else(|| self.err(p, format!("ward variant \"{v}\" is not supported (\"ward\", \"ward-duer\" or \"balanced\")")))?;
                }
                ("float", "alpha") if ty == "ward" => alpha = self.float(p)?,
                ("float", "alpha_u") if ty == "ward" => alpha_u = Some(self.float(p)?),
                ("float", "alpha_v") if ty == "ward" => alpha_v = Some(self.float(p)?),
                ("texture" | "ref", name @ ("exponent" | "alpha" | "alpha_u" | "alpha_v")) => {
                    return Err(self.err(
                        p,
                        format!("a textured {name} on {ty} is not supported; use a float"),
                    ));
                }
                _ => self.ignore(p, &format!("{ty} property"))?,
            }
        }
        let tex_max = |t: Option<u32>, c: Vec3| {
            t.map_or(c, |t| self.builder.textures()[t as usize].max_rgb())
        };
        let (kd_max, ks_max) = (
            tex_max(tex.diffuse, diffuse),
            tex_max(tex.specular, specular),
        );
        let scale = if conserve {
            crate::scene::bsdf::energy_scale(kd_max, ks_max)
        } else {
            1.0
        };
        if !conserve && (kd_max + ks_max).max_element() > 1.0 {
            self.warn(n, format!("{ty}: diffuse_reflectance + specular_reflectance reach {} in a channel (> 1, not energy conserving; kept, as ensure_energy_conservation=false asks)", (kd_max + ks_max).max_element()));
        }
        if scale < 1.0 {
            self.warn(n, format!("{ty}: diffuse_reflectance + specular_reflectance reach {} in a channel (> 1, not energy conserving); both are scaled by {scale} as Mitsuba 0.6 does (set ensure_energy_conservation=false to keep them)", (kd_max + ks_max).max_element()));
        }
        if ty == "phong" {
            if !(exponent.is_finite() && exponent >= 0.0) {
                return Err(self.err(
                    n,
                    format!("phong exponent {exponent} must be finite and >= 0"),
                ));
            }
            return Ok(Material::Phong {
                exponent,
                diffuse,
                specular,
                scale,
            });
        }
        let (alpha_u, alpha_v) = (alpha_u.unwrap_or(alpha), alpha_v.unwrap_or(alpha));
        for a in [alpha_u, alpha_v] {
            if !(a.is_finite() && a > 0.0) {
                return Err(self.err(n, format!("ward alpha {a} must be finite and positive")));
            }
        }
        if alpha_u != alpha_v {
            self.warn(n, format!("ward: anisotropic alphas ({alpha_u}, {alpha_v}) are oriented along the renderer's tangent frame built from the shading normal, not along dpdu as in Mitsuba 0.6 (the highlight's orientation may differ)"));
        }
        Ok(Material::Ward {
            variant,
            alpha_u,
            alpha_v,
            diffuse,
            specular,
            scale,
        })
    }

    /// An unknown BSDF type: a grey diffuse in its place (an error with `--strict`), its nested
    /// ids registered.
    fn unknown_bsdf(&mut self, n: Node) -> Result<Material> {
        self.fallback(
            n,
            "bsdf type",
            "rendered as a grey diffuse (reflectance 0.5)",
        )?;
        self.register_nested_ids(n)?;
        Ok(Material::Diffuse {
            reflectance: Vec3::splat(0.5),
        })
    }

    /// A top-level `<emitter>`: `point`, `constant` or `envmap` (area emitters live in shapes).
    fn emitter(&mut self, n: Node) -> Result<()> {
        let ty = n.attribute("type").unwrap_or("");
        if matches!(ty, "sunsky" | "sun" | "sky") {
            return self.sunsky_emitter(n, ty);
        }
        if !matches!(ty, "point" | "constant" | "envmap") {
            return self.fallback(n, "emitter type", "skipped (it emits no light)");
        }
        let mut to_world = None;
        let mut value = Vec3::ONE;
        let mut position = None;
        let (mut filename, mut scale) = (None, 1.0f32);
        for p in elements(n) {
            let pname = prop_name(p.attribute("name").unwrap_or(""));
            match (p.tag_name().name(), pname.as_ref(), ty) {
                ("transform", "to_world", "point" | "envmap") => {
                    to_world = Some(self.transform(p)?)
                }
                ("point", "position", "point") => position = Some(self.vec3(p)?),
                (_, "intensity", "point") | (_, "radiance", "constant") => {
                    value = self.unbounded_color(p)?
                }
                ("string", "filename", "envmap") => {
                    filename = Some(self.attr(p, "value")?.to_string())
                }
                ("float", "scale", "envmap") => scale = self.float(p)?,
                ("string", "filter_type", "envmap") if p.attribute("value") == Some("bilinear") => {
                }
                ("boolean", "mis_compensation", "envmap")
                    if p.attribute("value") == Some("false") => {}
                _ => self.ignore(p, &format!("property of emitter \"{ty}\""))?,
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
                let path = self.resolve_rel(&f);
                let img = read_exr(&path)?;
                let map = EnvMap::new(img.width, img.height, &img.pixels, scale)
                    .map_err(|e| self.err(n, format!("envmap {}: {e}", path.display())))?;
                let m = self.rotation(n, ty, to_world.unwrap_or(Mat4::IDENTITY))?;
                Environment::Map {
                    map: Box::new(map),
                    to_world: m,
                }
            }
            _ => unreachable!("unknown emitter types return early"),
        };
        if !self.builder.environment(env) {
            return Err(self.err(
                n,
                "only one environment emitter (constant or envmap) is supported",
            ));
        }
        Ok(())
    }

    /// Mitsuba's daylight emitters `sunsky`, `sun` (sun only) and `sky` (sky only), baked
    /// into an importance-sampled envmap by [`crate::scene::sunsky`] (Mitsuba 0.6 names, and Mitsuba
    /// 3's `sun_aperture`; a scene whose `version` is not `0.x` uses Mitsuba 3's z-up frame).
    fn sunsky_emitter(&mut self, n: Node, ty: &str) -> Result<()> {
        use crate::scene::sunsky::{Convention, SunSkyParams};
        let version = n.document().root_element().attribute("version");
        let conv = match version {
            Some(v) if !v.starts_with('0') && ty == "sunsky" => Convention::Mitsuba3,
            _ => Convention::Mitsuba06,
        };
        let mut sp = SunSkyParams::new(conv);
        (sp.sun, sp.sky) = (ty != "sky", ty != "sun");
        let (mut scale, mut sun_scale, mut sky_scale, mut radius) = (None, None, None, None);
        let mut when_where = None;
        for p in elements(n) {
            let pname = prop_name(p.attribute("name").unwrap_or(""));
            let f = |s: &Self| s.float(p).map(f64::from);
            match (p.tag_name().name(), pname.as_ref()) {
                ("transform", "to_world") => {
                    sp.to_world = self.rotation(p, ty, self.transform(p)?)?
                }
                (_, "sun_direction") => sp.sun_direction = Some(self.vec3(p)?),
                (_, "turbidity") => sp.turbidity = f(self)?,
                (_, "albedo") => sp.albedo = self.color(p)?.as_dvec3().to_array(),
                (_, "stretch") => sp.stretch = f(self)?,
                (_, "scale") => scale = Some(f(self)?),
                (_, "sun_scale") => sun_scale = Some(f(self)?),
                (_, "sky_scale") => sky_scale = Some(f(self)?),
                (_, "sun_radius_scale") => {
                    radius = Some(f(self)? * crate::scene::sunsky::SUN_RADIUS_DEG)
                }
                (_, "sun_aperture") => radius = Some(f(self)? / 2.0),
                (_, "extend") => sp.extend = self.boolean(p)?,
                (_, "resolution") => {
                    sp.resolution = usize::try_from(self.integer(p)?)
                        .map_err(|_| self.err(p, "resolution must be positive"))?
                }
                (_, k @ ("year" | "month" | "day")) => {
                    let v = self.integer(p)?;
                    *match k {
                        "year" => &mut sp.year,
                        "month" => &mut sp.month,
                        _ => &mut sp.day,
                    } = v;
                    when_where = Some(p);
                }
                (_, k @ ("hour" | "minute" | "second" | "latitude" | "longitude" | "timezone")) => {
                    let v = f(self)?;
                    *match k {
                        "hour" => &mut sp.hour,
                        "minute" => &mut sp.minute,
                        "second" => &mut sp.second,
                        "latitude" => &mut sp.latitude,
                        "longitude" => &mut sp.longitude,
                        _ => &mut sp.timezone,
                    } = v;
                    when_where = Some(p);
                }
                _ => self.ignore(p, &format!("property of emitter \"{ty}\""))?,
            }
        }
        if let (Some(p), Some(_)) = (when_where, sp.sun_direction) {
            return Err(self.err(
                p,
                format!("{ty}: give sun_direction or the time and place, not both"),
            ));
        }
        sp.sun_scale = sun_scale.or(scale).unwrap_or(1.0);
        sp.sky_scale = sky_scale.or(scale).unwrap_or(1.0);
        sp.sun_radius_deg = radius.unwrap_or(sp.sun_radius_deg);
        sp.validate()
            .map_err(|e| self.err(n, format!("{ty}: {e}")))?;
        for w in sp.warnings() {
            self.warn(n, format!("{ty}: {w}"));
        }
        let (w, h, rgb) = crate::scene::sunsky::bake(&sp);
        if rgb.iter().flatten().all(|v| *v == 0.0) {
            self.warn(
                n,
                format!("{ty}: nothing is above the horizon; the emitter is left out"),
            );
            return Ok(());
        }
        let map = EnvMap::new(w, h, &rgb, 1.0).map_err(|e| self.err(n, format!("{ty}: {e}")))?;
        let env = Environment::Map {
            map: Box::new(map),
            to_world: sp.map_to_world(),
        };
        if !self.builder.environment(env) {
            return Err(self.err(
                n,
                "only one environment emitter (constant, envmap or sunsky) is supported",
            ));
        }
        Ok(())
    }

    fn bsdf_ref(&mut self, p: Node) -> Result<u32> {
        let id = self.attr(p, "id")?;
        if let Some(&m) = self.bsdfs.get(id) {
            return Ok(m);
        }
        if self.failed_bsdfs.contains(id) {
            // Its own error is reported already; render the shape with the default.
            return Ok(self.default_material());
        }
        Err(self.err(p, format!("reference to unknown bsdf id \"{id}\"")))
    }

    /// The `null` material of Mitsuba 0.6's medium boundaries without a BSDF (created on
    /// first use).
    fn null_material(&mut self) -> u32 {
        if let Some(m) = self.null_material {
            return m;
        }
        let m = self.builder.material(Material::Null);
        self.null_material = Some(m);
        m
    }

    /// The black diffuse material of area emitters without a BSDF (created on first use).
    fn black_material(&mut self) -> u32 {
        if let Some(m) = self.black_material {
            return m;
        }
        let m = self.builder.material(Material::Diffuse {
            reflectance: Vec3::ZERO,
        });
        self.black_material = Some(m);
        m
    }

    /// The grey diffuse material of shapes without a BSDF (created on first use).
    fn default_material(&mut self) -> u32 {
        if let Some(m) = self.default_material {
            return m;
        }
        let m = self.builder.material(Material::Diffuse {
            reflectance: Vec3::splat(0.5),
        });
        self.default_material = Some(m);
        m
    }

    /// A top-level `<shape>`: `shapegroup` (kept for instances), `instance` (the group's
    /// shapes transformed and added, i.e. instances are flattened into world-space
    /// primitives), or a plain shape.
    fn shape(&mut self, n: Node) -> Result<()> {
        match n.attribute("type").unwrap_or("") {
            "shapegroup" => {
                let id = self.attr(n, "id")?.to_string();
                let mut shapes = Vec::new();
                for c in elements(n) {
                    if c.tag_name().name() != "shape" {
                        self.ignore(c, "shapegroup element (only <shape>)")?;
                        continue;
                    }
                    if matches!(c.attribute("type"), Some("shapegroup" | "instance")) {
                        return Err(self.err(
                            c,
                            "nested shapegroups / instances inside a shapegroup are not supported",
                        ));
                    }
                    let d = self.shape_data(c)?;
                    if d.emission.is_some() {
                        return Err(self.err(c, "area emitters inside a shapegroup are not supported (Mitsuba does not instance emitters either)"));
                    }
                    shapes.push(d);
                }
                self.groups.insert(id, shapes);
                Ok(())
            }
            "instance" => {
                let (mut group, mut to_world) = (None, Mat4::IDENTITY);
                for p in elements(n) {
                    match (
                        p.tag_name().name(),
                        p.attribute("name").map(prop_name).as_deref(),
                    ) {
                        ("ref", _) => {
                            let id = self.attr(p, "id")?;
                            let g = self.groups.get(id).ok_or_else(|| {
                                self.err(p, format!("reference to unknown shapegroup id \"{id}\""))
                            })?;
                            group = Some(g.clone());
                        }
                        ("transform", Some("to_world")) => to_world = self.transform(p)?,
                        _ => self.ignore(p, "instance property")?,
                    }
                }
                let group = group.ok_or_else(|| {
                    self.err(n, "instance needs a <ref id=\"...\"/> to a shapegroup")
                })?;
                for mut d in group {
                    for pr in &mut d.prims {
                        *pr = pr.transformed(&to_world).map_err(|e| self.err(n, e))?;
                    }
                    self.add_shape(d);
                }
                Ok(())
            }
            _ => {
                let d = self.shape_data(n)?;
                self.add_shape(d);
                Ok(())
            }
        }
    }

    fn add_shape(&mut self, d: ShapeData) {
        self.builder
            .shape_with(d.prims, d.uvs, d.material, d.emission, d.opacity);
        if let Some(m) = d.media {
            self.builder.set_last_shape_media(m);
        }
    }

    /// Opacity of a shape with material `m` (a mask, or a twosided around a mask).
    fn opacity_of(&self, m: u32) -> Option<Param> {
        if let Some(&o) = self.mask_opacity.get(&m) {
            return Some(o);
        }
        match self.builder.materials()[m as usize] {
            Material::TwoSided { front, .. } => self.mask_opacity.get(&front).copied(),
            _ => None,
        }
    }

    /// Reads a `<shape>` of a known type: its properties, then its geometry, flipped with
    /// `flip_normals`; an unknown type is skipped (an error with `--strict`).
    fn shape_data(&mut self, n: Node) -> Result<ShapeData> {
        let ty = n.attribute("type").unwrap_or("");
        const KNOWN: [&str; 7] = [
            "obj",
            "ply",
            "serialized",
            "sphere",
            "rectangle",
            "cube",
            "disk",
        ];
        if !KNOWN.contains(&ty) {
            self.fallback(n, "shape type", "skipped")?;
            return Ok(ShapeData {
                prims: Vec::new(),
                uvs: None,
                material: self.default_material(),
                emission: None,
                opacity: None,
                media: None,
            });
        }
        let props = self.shape_props(n, ty)?;
        let to_world = props.to_world;
        let (mut prims, mut uvs) = match ty {
            "obj" | "ply" | "serialized" => self.mesh_prims(n, ty, &props)?,
            "sphere" => (self.sphere_prims(n, &props)?, None),
            "rectangle" => {
                let (prims, uvs) = rectangle_prims(to_world);
                (prims, Some(uvs))
            }
            "cube" => (cube_prims(to_world), None),
            "disk" => (self.disk_prims(n, to_world)?, None),
            _ => unreachable!("unknown shape types return early"),
        };
        if props.flip {
            flip_shape(&mut prims, &mut uvs);
        }
        let media =
            (props.interior.is_some() || props.exterior.is_some()).then(|| MediumInterface {
                interior: props.interior.unwrap_or(NO_MEDIUM),
                exterior: props.exterior.unwrap_or(NO_MEDIUM),
            });
        let legacy = n
            .document()
            .root_element()
            .attribute("version")
            .is_some_and(|v| v.starts_with('0'));
        let material = match props.material {
            Some(m) => m,
            // Mitsuba 0.6: a shape that bounds a medium and has no BSDF is an index-matched
            // boundary (Mitsuba 3 gives it its default diffuse BSDF, as here).
            None if legacy && media.is_some() => self.null_material(),
            // Mitsuba (3 and 0.6) gives an area emitter without a BSDF a black diffuse one.
            None if props.emission.is_some() => self.black_material(),
            None => self.default_material(),
        };
        if props.emission.is_some()
            && matches!(self.builder.materials()[material as usize], Material::Null)
        {
            return Err(self.err(
                n,
                "an area emitter on a shape with a null BSDF is not supported",
            ));
        }
        let opacity = self.opacity_of(material);
        Ok(ShapeData {
            prims,
            uvs,
            material,
            emission: props.emission,
            opacity,
            media,
        })
    }

    /// The properties of a `<shape>` of type `ty` (nested BSDFs and area emitters read and
    /// added on the way); what does not apply to the type is ignored with a warning.
    fn shape_props(&mut self, n: Node, ty: &str) -> Result<ShapeProps> {
        let mut s = ShapeProps {
            to_world: Mat4::IDENTITY,
            flip: false,
            face_normals: false,
            material: None,
            emission: None,
            filename: None,
            shape_index: 0,
            center: Vec3::ZERO,
            radius: 1.0,
            interior: None,
            exterior: None,
        };
        for p in elements(n) {
            let tag = p.tag_name().name();
            let pname = prop_name(p.attribute("name").unwrap_or(""));
            match (tag, pname.as_ref(), ty) {
                ("transform", "to_world", _) => s.to_world = self.transform(p)?,
                ("boolean", "flip_normals", _) => s.flip = self.boolean(p)?,
                ("boolean", "face_normals", "obj" | "ply" | "serialized") => {
                    s.face_normals = self.boolean(p)?
                }
                ("string", "filename", "obj" | "ply" | "serialized") => {
                    s.filename = Some(self.attr(p, "value")?.to_string())
                }
                ("integer", "shape_index", "serialized") => {
                    let v = self.integer(p)?;
                    s.shape_index = u32::try_from(v)
                        .map_err(|_| self.err(p, format!("shape_index {v} must be >= 0")))?;
                }
                // Mitsuba 0.6 mesh options.
                ("boolean", "flip_tex_coords", "obj") => {
                    if !self.boolean(p)? {
                        self.warn(p, "flip_tex_coords=false is ignored (OBJ v coordinates are always flipped, as Mitsuba 3 does)");
                    }
                }
                ("float", "max_smooth_angle", "obj" | "ply" | "serialized") => {
                    self.warn(p, "max_smooth_angle is ignored (the file's vertex normals, or face normals, are used)");
                }
                ("boolean", "collapse", "obj") => {}
                ("point", "center", "sphere") => s.center = self.vec3(p)?,
                ("float", "radius", "sphere") => s.radius = self.float(p)?,
                ("ref" | "medium", "interior", _) => s.interior = Some(self.medium_or_ref(p)?),
                ("ref" | "medium", "exterior", _) => s.exterior = Some(self.medium_or_ref(p)?),
                ("ref", _, _) => s.material = Some(self.bsdf_ref(p)?),
                ("bsdf", _, _) => s.material = Some(self.bsdf(p)?),
                ("emitter", _, _) => {
                    if p.attribute("type") != Some("area") {
                        self.fallback(p, "emitter type inside a shape", "skipped")?;
                        continue;
                    }
                    let mut radiance = Vec3::ONE;
                    for q in elements(p) {
                        match q.attribute("name") {
                            Some("radiance") => radiance = self.unbounded_color(q)?,
                            _ => self.ignore(q, "area emitter property")?,
                        }
                    }
                    s.emission = Some(radiance);
                }
                _ => self.ignore(p, &format!("property of shape \"{ty}\""))?,
            }
        }
        Ok(s)
    }

    /// The triangles (and texture coordinates, if the file has them) of an `obj`, `ply` or
    /// `serialized` mesh, read relative to the scene and transformed to world space.
    #[allow(clippy::type_complexity)] // the pair `shape_data` matches on, as the other shapes
    fn mesh_prims(
        &mut self,
        n: Node,
        ty: &str,
        props: &ShapeProps,
    ) -> Result<(Vec<Prim>, Option<Vec<[Vec2; 3]>>)> {
        let f = props
            .filename
            .as_deref()
            .ok_or_else(|| self.err(n, format!("{ty} shape needs a \"filename\" string")))?;
        let (path, bytes) = self
            .read_rel(f)
            .map_err(|e| self.err(n, format!("{ty} shape: {e}")))?;
        let name = path.display().to_string();
        let mut face_normals = props.face_normals;
        let mut mesh = match ty {
            "obj" => {
                let text = String::from_utf8(bytes)
                    .map_err(|_| self.err(n, format!("{name} is not UTF-8 text")))?;
                parse_obj(&text, &name)?
            }
            "ply" => parse_ply(&bytes, &name)?,
            _ => {
                let m = parse_serialized(&bytes, props.shape_index, &name)?;
                face_normals |= m.face_normals;
                m.mesh
            }
        };
        mesh.transform(props.to_world);
        let uvs = mesh.triangle_uvs();
        Ok((mesh.primitives(face_normals), uvs))
    }

    /// A `sphere`: `center` and `radius` under `to_world`, which may scale it uniformly only.
    fn sphere_prims(&self, n: Node, props: &ShapeProps) -> Result<Vec<Prim>> {
        let m = props.to_world
            * Mat4::from_translation(props.center)
            * Mat4::from_scale(Vec3::splat(props.radius));
        let c = m.transform_point3(Vec3::ZERO);
        let axes = [
            m.x_axis.truncate().length(),
            m.y_axis.truncate().length(),
            m.z_axis.truncate().length(),
        ];
        if (axes[0] - axes[1]).abs() > 1e-4 * axes[0] || (axes[0] - axes[2]).abs() > 1e-4 * axes[0]
        {
            return Err(self.err(n, "sphere with a non-uniform scale is not supported"));
        }
        if axes[0].is_nan() || axes[0] <= 0.0 {
            return Err(self.err(n, "sphere radius must be positive"));
        }
        Ok(vec![Prim::Sphere {
            center: c,
            radius: axes[0],
            flip: false,
        }])
    }

    /// A `disk`: the unit disk of the local xy plane under `to_world`.
    fn disk_prims(&self, n: Node, to_world: Mat4) -> Result<Vec<Prim>> {
        let center = to_world.transform_point3(Vec3::ZERO);
        let (a, b) = (
            to_world.transform_vector3(Vec3::X),
            to_world.transform_vector3(Vec3::Y),
        );
        let area = a.cross(b).length();
        if area.is_nan() || area <= 0.0 {
            return Err(self.err(n, "disk to_world is degenerate"));
        }
        Ok(vec![Prim::Disk {
            center,
            a,
            b,
            n: normal_transform(to_world)(Vec3::Z),
        }])
    }
}

/// The properties of a `<shape>` its geometry is built from ([`Ctx::shape_props`]).
struct ShapeProps {
    to_world: Mat4,
    /// `flip_normals`.
    flip: bool,
    /// `face_normals` (meshes).
    face_normals: bool,
    /// The nested or referenced BSDF, if any.
    material: Option<u32>,
    /// The media inside and outside (`interior`, `exterior`), if given.
    interior: Option<u32>,
    exterior: Option<u32>,
    /// The radiance of a nested area emitter.
    emission: Option<Vec3>,
    /// The mesh file (meshes).
    filename: Option<String>,
    /// The mesh of a `serialized` file.
    shape_index: u32,
    /// Centre and radius of a `sphere`.
    center: Vec3,
    radius: f32,
}

/// Maps a local normal to world space under `to_world` (inverse transpose), normalised.
fn normal_transform(to_world: Mat4) -> impl Fn(Vec3) -> Vec3 {
    let nmat = Mat4::from_mat3(glam::Mat3::from_mat4(to_world).inverse().transpose());
    move |v| nmat.transform_vector3(v).normalize_or_zero()
}

/// A `rectangle`: two triangles of local `[-1, 1]²` under `to_world`, wound to face the
/// transformed normal, with Mitsuba's uv (local (x, y) in [-1, 1]² mapped to [0, 1]²).
fn rectangle_prims(to_world: Mat4) -> (Vec<Prim>, Vec<[Vec2; 3]>) {
    let c = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
        .map(|(x, y)| to_world.transform_point3(Vec3::new(x, y, 0.0)));
    let nz = normal_transform(to_world)(Vec3::Z);
    let mut tris = quad_triangles(c).map(|p| Prim::Tri { p, n: None }).to_vec();
    let mut uv = quad_triangles([Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y]).to_vec();
    if (c[1] - c[0]).cross(c[2] - c[0]).dot(nz) < 0.0 {
        for (t, u) in tris.iter_mut().zip(&mut uv) {
            if let Prim::Tri { p, .. } = t {
                p.swap(1, 2);
                u.swap(1, 2);
            }
        }
    }
    (tris, uv)
}

/// A `cube`: Mitsuba's `[-1, 1]³` under `to_world`, 12 triangles wound to face outwards.
fn cube_prims(to_world: Mat4) -> Vec<Prim> {
    let xf_n = normal_transform(to_world);
    let mut tris = Vec::with_capacity(12);
    for axis in 0..3 {
        for sign in [-1.0f32, 1.0] {
            let mut nl = Vec3::ZERO;
            nl[axis] = sign;
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let c = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].map(|(x, y)| {
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

/// `flip_normals`: reverses the winding (and the uvs with it) and the normals of every
/// primitive; spheres flip their orientation flag.
fn flip_shape(prims: &mut [Prim], uvs: &mut Option<Vec<[Vec2; 3]>>) {
    if let Some(uv) = uvs {
        for u in uv.iter_mut() {
            u.swap(1, 2);
        }
    }
    for pr in prims {
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

/// Checks that the linear part `A` of a camera's `to_world` is invertible, as Mitsuba needs
/// (it inverts the sensor transform): a singular `A` maps the view directions of a plane or a
/// line of pixels to the zero vector (no direction, NaN after normalising; obvhs's ray
/// constructor asserts finite inverse directions in debug builds, release renders black).
///
/// The test is scale-invariant: `|det A| ≤ 10⁻⁶ ‖a₀‖ ‖a₁‖ ‖a₂‖` (Hadamard's inequality bounds
/// `|det A|` by the product of the column norms, with equality for orthogonal columns), i.e. the
/// columns span a parallelepiped of less than 10⁻⁶ of its box: a zero column, two parallel
/// columns or three coplanar ones, whatever the scale of the camera.
fn check_invertible(m: &Mat4) -> std::result::Result<(), String> {
    let a = glam::Mat3::from_mat4(*m);
    let det = a.determinant();
    let box_volume = a.x_axis.length() * a.y_axis.length() * a.z_axis.length();
    let ok = det.is_finite()
        && box_volume.is_finite()
        && det.abs() > 1e-6 * box_volume
        && a.inverse().is_finite();
    if ok {
        Ok(())
    } else {
        Err(format!(
            "its 3x3 part (columns {}, {}, {}) has determinant {det} (not invertible)",
            a.x_axis, a.y_axis, a.z_axis
        ))
    }
}

/// Mitsuba 0.6 property names in Mitsuba 3's spelling: camelCase becomes snake_case as
/// Mitsuba 3's scene upgrade does (`toWorld` → `to_world`, `intIOR` → `int_ior`,
/// `sampleCount` → `sample_count`); snake_case names pass unchanged.
fn prop_name(s: &str) -> Cow<'_, str> {
    if !s.bytes().any(|c| c.is_ascii_uppercase()) {
        return Cow::Borrowed(s);
    }
    let mut out = String::with_capacity(s.len() + 4);
    let mut prev_lower = false;
    for c in s.chars() {
        if c.is_ascii_uppercase() {
            if prev_lower {
                out.push('_');
            }
            out.push(c.to_ascii_lowercase());
            prev_lower = false;
        } else {
            out.push(c);
            prev_lower = c.is_ascii_lowercase() || c.is_ascii_digit();
        }
    }
    Cow::Owned(out)
}

use crate::scene::texture::srgb_to_linear;

/// `<tag type=".." name=".." id="..">` with the attributes the element has, for messages.
fn describe(n: Node) -> String {
    let mut s = format!("<{}", n.tag_name().name());
    for a in ["type", "name", "id"] {
        if let Some(v) = n.attribute(a) {
            s.push_str(&format!(" {a}=\"{v}\""));
        }
    }
    s.push('>');
    s
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
