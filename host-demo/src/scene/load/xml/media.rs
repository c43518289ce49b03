//! `<medium>` and `<phase>`: homogeneous participating media as Mitsuba 3 and 0.6 write them.
//!
//! | construct | Mitsuba 3 | Mitsuba 0.6 |
//! |---|---|---|
//! | extinction | `sigma_t` (float or rgb) and `albedo`, times `scale` | `sigmaS` and `sigmaA`, or `sigmaT` and `albedo`, times `scale` (or `densityMultiplier`) |
//! | heterogeneous | `sigma_t` a `gridvolume` (a `.vol` file on the unit cube under its `to_world`, or its own box with `use_grid_bbox`), `albedo` a colour or `constvolume`, times `scale` | `density` a `gridvolume` (on the file's box, then `toWorld`), `albedo` a `constvolume`, times `scale` |
//! | phase | nested `<phase type="isotropic">` or `"hg"` with `g` | the same |
//! | on a shape | `<ref name="interior" id="..."/>`, or a nested `<medium name="exterior">` | the same |
//! | on the sensor | a nested `<medium>` or `<ref>` | the same |
//!
//! A grid `albedo`, a chromatic extinction with a grid, multi-channel `.vol` files and other
//! medium types are refused with the file and line; other phase functions fall back to
//! isotropic with a warning (an error with `--strict`).

use super::{check_invertible, elements, prop_name, Ctx};
use crate::error::Result;
use crate::scene::grid::DensityGrid;
use crate::scene::medium::Medium;
use glam::{Mat4, Vec3};
use roxmltree::Node;

/// A `<volume>`: a constant or a density grid.
enum Volume {
    Constant(Vec3),
    Grid(DensityGrid),
}

impl Ctx<'_> {
    /// A `<medium>` (top level, or nested in a shape or the sensor): added to the scene,
    /// registered under its `id` if it has one; returns its index.
    pub(super) fn medium(&mut self, n: Node) -> Result<u32> {
        let ty = n.attribute("type").unwrap_or("");
        if !matches!(ty, "homogeneous" | "heterogeneous") {
            return Err(self.unsupported(n, "medium type (homogeneous or heterogeneous)"));
        }
        let mut grid = None;
        let (mut sigma_t, mut albedo, mut scale, mut g) = (None, None, 1.0f32, 0.0f32);
        let (mut sigma_s, mut sigma_a) = (None, None);
        for p in elements(n) {
            let tag = p.tag_name().name();
            if tag == "phase" {
                g = self.phase(p)?;
                continue;
            }
            let name = prop_name(p.attribute("name").unwrap_or(""));
            if tag == "volume" {
                match (self.volume(p)?, name.as_ref()) {
                    (Volume::Constant(c), "sigma_t" | "density") => sigma_t = Some(c),
                    (Volume::Constant(c), "albedo") => albedo = Some(c),
                    (Volume::Grid(gr), "sigma_t" | "density") => {
                        sigma_t = Some(Vec3::ONE);
                        grid = Some(gr);
                    }
                    (Volume::Grid(_), "albedo") => {
                        return Err(self.unsupported(p, "grid albedo (give a constant albedo)"))
                    }
                    _ => self.ignore(p, "medium volume")?,
                }
                continue;
            }
            match (tag, name.as_ref()) {
                ("string", "method") if ty == "heterogeneous" => {}
                ("float", "step_size") if ty == "heterogeneous" => {}
                (_, "sigma_t" | "sigmaT") => sigma_t = Some(self.coefficient(p)?),
                (_, "albedo") => albedo = Some(self.coefficient(p)?),
                (_, "sigmaS" | "sigma_s") => sigma_s = Some(self.coefficient(p)?),
                (_, "sigmaA" | "sigma_a") => sigma_a = Some(self.coefficient(p)?),
                ("float", "scale" | "densityMultiplier") => scale = self.float(p)?,
                // Mitsuba 3: whether an emissive medium's emission is sampled (no emissive
                // media here).
                ("boolean", "sample_emitted") => {}
                ("string", "material") => {
                    return Err(self.unsupported(
                        p,
                        "named medium material (give sigmaS / sigmaA or sigma_t / albedo)",
                    ))
                }
                _ => self.ignore(p, "medium property")?,
            }
        }
        let (sigma_t, albedo) = match (sigma_s, sigma_a) {
            (None, None) => (
                sigma_t.unwrap_or(Vec3::ONE),
                albedo.unwrap_or(Vec3::splat(0.75)),
            ),
            (s, a) if sigma_t.is_none() && albedo.is_none() => {
                let (s, a) = (s.unwrap_or(Vec3::ZERO), a.unwrap_or(Vec3::ZERO));
                let t = s + a;
                let albedo = Vec3::select(t.cmpgt(Vec3::ZERO), s / t, Vec3::ZERO);
                (t, albedo)
            }
            _ => {
                return Err(self.err(
                    n,
                    "give either sigma_t and albedo, or sigmaS and sigmaA, not both",
                ))
            }
        };
        let mut m = Medium::new(sigma_t, albedo, scale, g).map_err(|e| self.err(n, e))?;
        if let Some(gr) = grid {
            m = m.with_density(gr).map_err(|e| self.err(n, e))?;
        } else if ty == "heterogeneous" {
            return Err(self.err(
                n,
                "a heterogeneous medium needs a gridvolume sigma_t (density)",
            ));
        }
        let index = self.builder.medium(m);
        if let Some(id) = n.attribute("id") {
            self.media.insert(id.to_string(), index);
        }
        Ok(index)
    }

    /// A `<ref id="..."/>` to a medium.
    pub(super) fn medium_ref(&self, p: Node) -> Result<u32> {
        let id = self.attr(p, "id")?;
        self.media
            .get(id)
            .copied()
            .ok_or_else(|| self.err(p, format!("reference to unknown medium id \"{id}\"")))
    }

    /// A nested `<medium>` or `<ref>` naming a medium.
    pub(super) fn medium_or_ref(&mut self, p: Node) -> Result<u32> {
        if p.tag_name().name() == "ref" {
            self.medium_ref(p)
        } else {
            self.medium(p)
        }
    }

    /// A `<volume>`: `constvolume` (its `value`) or `gridvolume` (a `.vol` file placed as
    /// the module docs say).
    fn volume(&mut self, n: Node) -> Result<Volume> {
        match n.attribute("type").unwrap_or("") {
            "constvolume" => {
                let mut value = Vec3::ONE;
                for p in elements(n) {
                    match p.attribute("name") {
                        Some("value") => value = self.unbounded_color(p)?,
                        _ => self.ignore(p, "constvolume property")?,
                    }
                }
                Ok(Volume::Constant(value))
            }
            "gridvolume" => {
                let legacy = n
                    .document()
                    .root_element()
                    .attribute("version")
                    .is_some_and(|v| v.starts_with('0'));
                let (mut file, mut to_world, mut own_box) = (None, Mat4::IDENTITY, legacy);
                for p in elements(n) {
                    let name = prop_name(p.attribute("name").unwrap_or(""));
                    match (p.tag_name().name(), name.as_ref()) {
                        ("string", "filename") => file = Some(self.attr(p, "value")?.to_string()),
                        ("transform", "to_world") => to_world = self.transform(p)?,
                        ("boolean", "use_grid_bbox") => own_box = self.boolean(p)?,
                        // Trilinear is Mitsuba's default and the only filter here.
                        ("string", "filter_type") if self.attr(p, "value")? == "trilinear" => {}
                        // Mitsuba 3: the grid's values as stored (no sRGB decoding of a
                        // one-channel density either way).
                        ("boolean", "raw") => {}
                        _ => self.ignore(p, "gridvolume property")?,
                    }
                }
                let file = file.ok_or_else(|| self.err(n, "gridvolume needs a filename"))?;
                let (path, bytes) = self
                    .read_rel(&file)
                    .map_err(|e| self.err(n, format!("gridvolume: {e}")))?;
                let (mut grid, [lo, hi]) = DensityGrid::from_vol(&bytes)
                    .map_err(|e| self.err(n, format!("{}: {e}", path.display())))?;
                let placement = if own_box {
                    if !(lo.is_finite() && hi.is_finite() && hi.cmpgt(lo).all()) {
                        return Err(self.err(
                            n,
                            format!("{}: empty or invalid box {lo} .. {hi}", path.display()),
                        ));
                    }
                    to_world * Mat4::from_translation(lo) * Mat4::from_scale(hi - lo)
                } else {
                    to_world
                };
                check_invertible(&placement)
                    .map_err(|e| self.err(n, format!("gridvolume placement: {e}")))?;
                grid.to_local = placement.inverse();
                Ok(Volume::Grid(grid))
            }
            _ => Err(self.unsupported(n, "volume type (constvolume or gridvolume)")),
        }
    }

    /// A medium coefficient: a float or a colour (unbounded: extinctions exceed 1).
    fn coefficient(&mut self, p: Node) -> Result<Vec3> {
        match p.tag_name().name() {
            "volume" | "texture" => Err(self.unsupported(
                p,
                "textured medium coefficient (only constant floats and colours)",
            )),
            _ => self.unbounded_color(p),
        }
    }

    /// A `<phase>`: its Henyey–Greenstein `g` (0 for `isotropic`).
    fn phase(&mut self, n: Node) -> Result<f32> {
        let ty = n.attribute("type").unwrap_or("");
        let mut g = 0.0;
        match ty {
            "isotropic" => {}
            "hg" => {
                for p in elements(n) {
                    match (p.tag_name().name(), p.attribute("name")) {
                        ("float", Some("g")) => g = self.float(p)?,
                        _ => self.ignore(p, "hg phase property")?,
                    }
                }
            }
            _ => self.fallback(n, "phase function type", "rendered as \"isotropic\"")?,
        }
        if !(g > -1.0 && g < 1.0) {
            return Err(self.err(n, format!("hg needs -1 < g < 1 (got {g})")));
        }
        Ok(g)
    }
}
