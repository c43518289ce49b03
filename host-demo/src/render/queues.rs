//! The wavefront's typed structure-of-arrays queues. Each stage reads one queue and fills the
//! next; a queue is cleared and refilled every bounce, so its storage is reused for the whole
//! render.
//!
//! Directions follow pbrt's convention (the library's, see the `guiding` crate docs): `wo`
//! points from the vertex towards the previous vertex (the viewer), `wi` is the sampled
//! continuation direction; both are unit vectors in world space pointing away from the surface.

use crate::scene::bsdf::Material;
use crate::scene::emitter::EmitterSample;
use glam::Vec3;

/// Declares a structure-of-arrays queue: the struct (one `Vec` per field, index-aligned) with
/// `clear` (every field, keeping its storage) and `len` / `is_empty` (of the first field).
macro_rules! soa_queue {
    (
        $(#[$meta:meta])*
        $vis:vis struct $name:ident {
            $(#[$first_meta:meta])*
            $first_vis:vis $first:ident: Vec<$first_ty:ty>,
            $(
                $(#[$field_meta:meta])*
                $field_vis:vis $field:ident: Vec<$field_ty:ty>,
            )*
        }
    ) => {
        $(#[$meta])*
        $vis struct $name {
            $(#[$first_meta])*
            $first_vis $first: Vec<$first_ty>,
            $(
                $(#[$field_meta])*
                $field_vis $field: Vec<$field_ty>,
            )*
        }

        #[allow(dead_code)] // not every queue is cleared or asked its length
        impl $name {
            /// Empties every field (keeping its storage).
            pub(crate) fn clear(&mut self) {
                self.$first.clear();
                $(self.$field.clear();)*
            }

            /// Number of entries.
            pub fn len(&self) -> usize {
                self.$first.len()
            }

            /// True if empty.
            pub fn is_empty(&self) -> bool {
                self.$first.is_empty()
            }
        }
    };
}

soa_queue! {
    /// Rays in flight: the camera rays of a sample, then each bounce's continuations.
    #[derive(Default)]
    pub struct RayQueue {
        /// Path slot (pixel within the block).
        pub slot: Vec<u32>,
        /// Ray origin (already offset off the surface).
        pub origin: Vec<Vec3>,
        /// Unit ray direction.
        pub dir: Vec<Vec3>,
        /// Path throughput carried by the ray.
        pub beta: Vec<Vec3>,
        /// Solid-angle density with which `dir` was sampled, for MIS at an emitter hit
        /// (`∞` after a delta scattering).
        pub pdf: Vec<f32>,
        /// The ray is a camera ray (emission seen directly: no MIS).
        pub from_camera: Vec<bool>,
        /// The ray continues the path the recorder follows in its slot (after a split, only
        /// the first copy's does).
        pub tracked: Vec<bool>,
        /// The medium the ray starts in ([`NO_MEDIUM`](crate::scene::medium::NO_MEDIUM):
        /// vacuum).
        pub medium: Vec<u32>,
    }
}

impl RayQueue {
    #[allow(clippy::too_many_arguments)] // one value per field of the queue
    pub(crate) fn push(
        &mut self,
        slot: u32,
        origin: Vec3,
        dir: Vec3,
        beta: Vec3,
        pdf: f32,
        tracked: bool,
        medium: u32,
    ) {
        self.slot.push(slot);
        self.origin.push(origin);
        self.dir.push(dir);
        self.beta.push(beta);
        self.pdf.push(pdf);
        self.from_camera.push(false);
        self.tracked.push(tracked);
        self.medium.push(medium);
    }
}

soa_queue! {
    /// The surviving path vertices of one bounce: the unit of work of NEE, of a strategy's batch
    /// (one batched guide decode) and of the continuation.
    ///
    /// A scattering point inside a medium is a vertex too: its material is a
    /// [`Material::Phase`], its `ng` is zero (no surface: no offset, no side test) and its
    /// `ns` is `wo` (the phase function's frame).
    #[derive(Default, Debug)]
    pub struct Vertices {
        /// Path slot (pixel within the block).
        pub slot: Vec<u32>,
        /// Hit position.
        pub position: Vec<Vec3>,
        /// Geometric normal (zero at a medium vertex).
        pub ng: Vec<Vec3>,
        /// Shading normal (flipped to the side of `wo` for two-sided materials; `wo` at a
        /// medium vertex).
        pub ns: Vec<Vec3>,
        /// Unit direction towards the previous vertex.
        pub wo: Vec<Vec3>,
        /// Path throughput up to this vertex (after Russian roulette).
        pub beta: Vec<Vec3>,
        /// The material with its textures evaluated at the hit (what NEE and sampling use).
        pub bsdf: Vec<Material>,
        /// The vertex is on the path the recorder follows in its slot (a split vertex's first
        /// copy; see [`RayQueue::tracked`]).
        pub tracked: Vec<bool>,
        /// The media a ray leaving the vertex starts in: `[0]` on the side of `ng`, `[1]`
        /// against it ([`Vertices::medium_toward`]); both the same unless the surface bounds
        /// media.
        pub media: Vec<[u32; 2]>,
    }
}

impl Vertices {
    /// The medium a ray leaving vertex `i` in direction `dir` starts in.
    #[inline]
    pub fn medium_toward(&self, i: usize, dir: Vec3) -> u32 {
        let m = self.media[i];
        if dir.dot(self.ng[i]) >= 0.0 {
            m[0]
        } else {
            m[1]
        }
    }
}

soa_queue! {
    /// Light samples drawn by NEE, waiting for their MIS weights: the strategy fills
    /// `sampling_pdf`, the density with which *it* would have sampled the light's direction.
    #[derive(Default)]
    pub struct LightSamples {
        /// Index into the bounce's [`Vertices`].
        pub vertex: Vec<u32>,
        /// The emitter sample (direction `es.wo` from the vertex towards the light).
        pub light: Vec<EmitterSample>,
        /// `f · |cos|` of the BSDF for the light's direction.
        pub bsdf_cos: Vec<Vec3>,
        /// BSDF-sampling density of the light's direction.
        pub bsdf_pdf: Vec<f32>,
        /// The strategy's sampling density of the light's direction (its MIS partner).
        pub sampling_pdf: Vec<f32>,
    }
}

soa_queue! {
    /// Shadow rays of the NEE stage.
    #[derive(Default)]
    pub struct ShadowQueue {
        /// Index into the bounce's [`Vertices`].
        pub vertex: Vec<u32>,
        /// Ray origin.
        pub origin: Vec<Vec3>,
        /// Unit direction.
        pub dir: Vec<Vec3>,
        /// Distance to the light (just short of it; `∞` for the environment).
        pub tmax: Vec<f32>,
        /// The MIS-weighted light contribution `f · L · w / p_light`, without the path throughput.
        pub local: Vec<Vec3>,
        /// The medium the shadow ray starts in.
        pub medium: Vec<u32>,
    }
}

soa_queue! {
    /// One sampled continuation per vertex (index-aligned with [`Vertices`]), written by a
    /// strategy.
    #[derive(Default)]
    pub struct Continuations {
        /// Unit continuation direction `wi` (zero: the path ends here).
        pub wi: Vec<Vec3>,
        /// Continuation weight `f · |cos| / p`.
        pub weight: Vec<Vec3>,
        /// The density `p` with which `wi` was sampled (`∞` for a delta lobe).
        pub pdf: Vec<f32>,
        /// BSDF-sampling density of `wi` (training records).
        pub bsdf_pdf: Vec<f32>,
        /// `f · |cos|` for `wi` (training records of the vertices the strategy guides).
        pub bsdf_cos: Vec<Vec3>,
    }
}

impl Continuations {
    /// Resets to `n` ended paths.
    pub(crate) fn reset(&mut self, n: usize) {
        self.clear();
        self.wi.resize(n, Vec3::ZERO);
        self.weight.resize(n, Vec3::ZERO);
        self.pdf.resize(n, 0.0);
        self.bsdf_pdf.resize(n, 0.0);
        self.bsdf_cos.resize(n, Vec3::ZERO);
    }

    /// Writes the continuation of vertex `i`.
    #[inline]
    pub fn set(&mut self, i: usize, wi: Vec3, weight: Vec3, pdf: f32) {
        self.wi[i] = wi;
        self.weight[i] = weight;
        self.pdf[i] = pdf;
    }
}

soa_queue! {
    /// Guide samples to draw in one batched call: which decoded distribution, its random
    /// numbers, the vertex the sample continues, and (after the call) the samples.
    #[derive(Default)]
    pub(crate) struct GuideSampleQueue {
        /// Index of the decoded distribution (the vertex's guidable index).
        pub query: Vec<u32>,
        /// The sample's two random numbers.
        pub u: Vec<glam::Vec2>,
        /// The vertex (index in [`Vertices`]) the sample continues.
        pub vertex: Vec<u32>,
        /// The samples, index-aligned with `query`.
        pub out: Vec<guiding::DirectionSample>,
    }
}

impl GuideSampleQueue {
    /// Queues a sample of distribution `query` with `u` for `vertex`.
    #[inline]
    pub(crate) fn push(&mut self, query: u32, u: glam::Vec2, vertex: u32) {
        self.query.push(query);
        self.u.push(u);
        self.vertex.push(vertex);
    }
}

soa_queue! {
    /// Guide densities to evaluate in one batched call: which decoded distribution, the
    /// direction, the entry the density answers (a vertex or a light sample), and (after the
    /// call) the densities.
    #[derive(Default)]
    pub(crate) struct GuidePdfQueue {
        /// Index of the decoded distribution (the vertex's guidable index).
        pub query: Vec<u32>,
        /// Unit direction whose density is asked.
        pub dir: Vec<Vec3>,
        /// The entry (vertex or light sample) the density answers.
        pub entry: Vec<u32>,
        /// The densities, index-aligned with `query`.
        pub out: Vec<f32>,
    }
}

impl GuidePdfQueue {
    /// Queues the density of distribution `query` at `dir` for `entry`.
    #[inline]
    pub(crate) fn push(&mut self, query: u32, dir: Vec3, entry: u32) {
        self.query.push(query);
        self.dir.push(dir);
        self.entry.push(entry);
    }
}
