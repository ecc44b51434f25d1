//! The per-frame enhancement pipeline (Bermano et al. 2014 §5) over a precomputed database
//! (§4).

use nalgebra::{DMatrix, DVector, Matrix3, Point3};
use rayon::prelude::*;

use super::EnhanceError;
use super::deformation_gradient::{
    POLAR_CODE_LEN, decode_polar, encode_polar, rest_frame_inverses, triangle_frame,
};
use super::frequency::{LowPass, LowPassParams};
use super::poisson::{PoissonParams, PoissonSolver};
use super::regions::{RegionWeights, VoluntaryRegions, seed_and_grow_patches};
use crate::align::horn_alignment;
use crate::dataset::Dataset;
use crate::mesh::{Mesh, triangle_areas};
use crate::numeric::convex_weights;

/// Tuning of [`Enhancer`]. Every field has a default; `validate` checks them all.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct EnhanceParams {
    /// Frequency separation f(·) (§4.2, Eq. 1).
    pub low_pass: LowPassParams,
    /// Reconstruction (§5.5).
    pub poisson: PoissonParams,
    /// Target vertices per patch of the compressed shape space (§4.2). Default 100, the
    /// paper's value.
    pub patch_vertices: usize,
    /// Seed of the random seed-and-grow patches. Default 0.
    pub patch_seed: u64,
    /// Width σ of the Gaussian decay of the region weights with geodesic distance (§5.3),
    /// mm. Default 15 mm: a region couples to its neighbourhood over about a brow's width.
    pub region_sigma_mm: f64,
    /// For regions derived from motion ([`VoluntaryRegions::from_motion`]): the quantile of
    /// vertex motion above which a vertex is a region core. Default 0.8.
    pub motion_quantile: f64,
    /// Ridge added to the Gram matrices' diagonal, relative to their mean diagonal, to keep
    /// the QP strictly convex when database shapes coincide in a region. Default 1e-9.
    pub qp_ridge: f64,
    /// Replace the reconstruction's low band by the input's: output `f(a) + (x − f(x))`
    /// with x the reconstruction (one more back-substitution). Default true; see the
    /// deviations on [`Enhancer`].
    pub keep_input_low_band: bool,
}

impl Default for EnhanceParams {
    fn default() -> Self {
        Self {
            low_pass: LowPassParams::default(),
            poisson: PoissonParams::default(),
            patch_vertices: 100,
            patch_seed: 0,
            region_sigma_mm: 15.0,
            motion_quantile: 0.8,
            qp_ridge: 1e-9,
            keep_input_low_band: true,
        }
    }
}

impl EnhanceParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`EnhanceError::InvalidParam`] naming the first bad field.
    pub fn validate(&self) -> Result<(), EnhanceError> {
        self.low_pass.validate()?;
        self.poisson.validate()?;
        if self.patch_vertices == 0 {
            return Err(EnhanceError::invalid("patch_vertices", 0.0));
        }
        if !(self.region_sigma_mm.is_finite() && self.region_sigma_mm > 0.0) {
            return Err(EnhanceError::invalid(
                "region_sigma_mm",
                self.region_sigma_mm,
            ));
        }
        if !(0.0..1.0).contains(&self.motion_quantile) {
            return Err(EnhanceError::invalid(
                "motion_quantile",
                self.motion_quantile,
            ));
        }
        if !(self.qp_ridge.is_finite() && self.qp_ridge >= 0.0) {
            return Err(EnhanceError::invalid("qp_ridge", self.qp_ridge));
        }
        Ok(())
    }
}

/// One enhanced frame with what the matching chose.
#[derive(Debug, Clone, PartialEq)]
pub struct Enhanced {
    /// Enhanced vertex positions (#V, mm), in the input frame's own rigid placement.
    pub positions: Vec<Point3<f64>>,
    /// Convex weights over the database frames (neutral first, then the shapes) for each
    /// voluntary region, in [`REGION_NAMES`](super::REGION_NAMES) order.
    pub region_weights: [DVector<f64>; 4],
}

/// Wall time of each per-frame step of [`Enhancer::enhance_timed`], seconds.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EnhanceTimings {
    /// §5.1: the low-pass f(a) of the input (one back-substitution).
    pub low_pass_input: f64,
    /// §5.2: Horn alignment to f(d₀), low-frequency gradients, the compressed code ã.
    pub encode: f64,
    /// §5.3: the four convex QPs (Eq. 3).
    pub matching: f64,
    /// §5.4: blending the details (Eq. 4) and composing them with the input's gradients.
    pub blend: f64,
    /// §5.5: the Poisson right-hand side and back-substitution.
    pub reconstruct: f64,
    /// Rigid placement onto the input and, when kept, the input's low band (one more
    /// back-substitution).
    pub finish: f64,
}

impl EnhanceTimings {
    /// The sum of the steps, seconds.
    pub fn total(&self) -> f64 {
        self.low_pass_input
            + self.encode
            + self.matching
            + self.blend
            + self.reconstruct
            + self.finish
    }
}

/// Detail enhancement against a precomputed database (Bermano et al. 2014 §4-5).
///
/// [`Enhancer::new`] does, once: the low-pass f(d) of every database frame (the neutral and
/// every shape, §4.2); their high-frequency details d^h (per-triangle deformation gradients
/// from f(d) to d, polar-encoded, §4.2); their low-frequency gradients relative to f(d₀),
/// averaged over random ~100-vertex patches and polar-encoded, the compressed shape space D̃
/// (§4.2); the region weights ω_r (§4.3) and Gram matrices D̃ᵀ diag(ω_r) D̃ (§5.3, Eq. 3);
/// and the Poisson system on f(d₀), factored once (§5.5).
///
/// [`Enhancer::enhance`] then, per frame: low-passes the input (§5.1), aligns it rigidly to
/// f(d₀) by Horn's method and encodes it (§5.2), solves the four convex QPs (§5.3, Eq. 3),
/// blends the database details by Eq. (4), composes them with the input's low-frequency
/// gradients (§5.4), reconstructs by back-substitution and restores the input's rigid
/// placement (§5.5).
///
/// # Deviations
/// - Database frames are Horn-aligned to f(d₀) like the input before encoding (the paper
///   aligns only the input): a database shape with the jaw open is then encoded the same
///   way as an input with the jaw open, which keeps the matching consistent.
/// - The neutral d₀ is a database frame like the shapes, so a neutral input receives the
///   neutral's own skin detail.
/// - The final placement is one Horn alignment of the reconstruction onto the input a
///   itself (face vertices), which composes the paper's two steps (align to the database,
///   apply R_a⁻¹, T_a⁻¹) into one and uses the unfiltered input as the reference: the
///   low-pass shrinks a curved face toward its centres of curvature, so aligning to f(a)
///   would shift the result by that shrinkage (a few tenths of a millimetre).
/// - The Poisson solve's translation and boundary targets ([`PoissonSolver::solve`]'s
///   anchor) come from the aligned input a, not f(a), for the same reason.
/// - By default ([`EnhanceParams::keep_input_low_band`]) the output's low band is reset to
///   the input's, f(a) + (x − f(x)). Integrating blended gradients over the whole head lets
///   small gradient mismatches add up to a smooth drift of the low frequencies; in
///   production the low band is the animator's or the solver's intent and must not move,
///   only details are to be added. Off, the output is the paper's reconstruction.
/// - Details are stored in single precision (half the memory; 1e-7 relative is far below
///   the detail's own size).
/// - Vertex colours (§5.5, optional in the issue) are not blended.
pub struct Enhancer {
    triangles: Vec<[u32; 3]>,
    vertex_count: usize,
    frame_names: Vec<String>,
    low_pass: LowPass,
    poisson: PoissonSolver,
    smooth_neutral: Vec<Point3<f64>>,
    rest_inverses: Vec<Matrix3<f64>>,
    face_weights: Vec<f64>,
    triangle_patch: Vec<u32>,
    /// Area of each triangle over its patch's area (#T).
    patch_share: Vec<f64>,
    patch_count: usize,
    regions: RegionWeights,
    /// D̃: (9·#patches) × #frames.
    compressed: DMatrix<f64>,
    /// ω_r per row of D̃, per region.
    row_weights: [DVector<f64>; 4],
    /// D̃ᵀ diag(ω_r) D̃ per region.
    grams: [DMatrix<f64>; 4],
    /// d^h codes of the triangles whose details vary between database frames,
    /// frame-major and component-major: [(k · 9 + c) · #varying + j], so that blending
    /// reads only the frames the matching selected, as contiguous runs that the compiler
    /// vectorizes.
    details: Vec<f32>,
    /// Where each triangle's details are (#T).
    detail_slots: Vec<DetailSlot>,
    /// Number of triangles with varying details.
    varying_count: usize,
    /// The region blend weights of the triangles with varying details, in their order.
    varying_blend: Vec<[f64; 4]>,
    /// The one d^h code of each triangle whose details are the same (bit for bit, in
    /// single precision) in every database frame: skin the shapes do not move.
    shared_details: Vec<[f32; POLAR_CODE_LEN]>,
    qp_ridge: f64,
    keep_input_low_band: bool,
}

impl std::fmt::Debug for Enhancer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Enhancer")
            .field("vertices", &self.vertex_count)
            .field("triangles", &self.triangles.len())
            .field("frames", &self.frame_names.len())
            .field("patches", &self.patch_count)
            .finish_non_exhaustive()
    }
}

impl Enhancer {
    /// Precomputes the database with regions derived from its motion
    /// ([`VoluntaryRegions::from_motion`]).
    ///
    /// # Errors
    /// See [`Enhancer::with_regions`].
    pub fn new(dataset: &Dataset, params: &EnhanceParams) -> Result<Self, EnhanceError> {
        let regions = VoluntaryRegions::from_motion(dataset, params.motion_quantile);
        Self::with_regions(dataset, params, &regions)
    }

    /// Precomputes the database with the given voluntary regions.
    ///
    /// # Errors
    /// [`EnhanceError::InvalidParam`] for bad params; [`EnhanceError::Shape`] when a shape
    /// is not in the neutral's topology; [`EnhanceError::NonFinite`] for a non-finite
    /// shape; [`EnhanceError::Regions`], [`EnhanceError::Factorization`],
    /// [`EnhanceError::Alignment`] when the neutral mesh is degenerate.
    pub fn with_regions(
        dataset: &Dataset,
        params: &EnhanceParams,
        regions: &VoluntaryRegions,
    ) -> Result<Self, EnhanceError> {
        params.validate()?;
        let mesh: &Mesh = &dataset.neutral;
        let n = mesh.vertex_count();
        let triangles = mesh.triangles.clone();
        let t_count = triangles.len();
        let mut frames: Vec<(&str, &[Point3<f64>])> = vec![("neutral", &mesh.positions[..])];
        for s in &dataset.shapes {
            if s.positions.len() != n {
                return Err(EnhanceError::Shape {
                    what: "database shape vertices",
                    expected: n,
                    got: s.positions.len(),
                });
            }
            frames.push((&s.name, &s.positions[..]));
        }
        for (name, p) in &frames {
            if !p.iter().all(|q| q.coords.iter().all(|x| x.is_finite())) {
                return Err(EnhanceError::NonFinite(format!("database frame {name}")));
            }
        }
        let k_count = frames.len();
        let mut face_weights = vec![0.0; n];
        for v in dataset.face_vertex_indices() {
            face_weights[v] = 1.0;
        }
        let low_pass = LowPass::new(mesh, &mesh.positions, &params.low_pass)?;
        let smooth_neutral = low_pass.apply(&mesh.positions)?;
        let rest_inverses = rest_frame_inverses(&triangles, &smooth_neutral);
        let poisson = PoissonSolver::new(mesh, &smooth_neutral, &params.poisson)?;
        let smooth_mesh = mesh.with_positions(smooth_neutral.clone())?;
        let areas = triangle_areas(&smooth_mesh);
        let (triangle_patch, patch_count) =
            seed_and_grow_patches(mesh, params.patch_vertices, params.patch_seed);
        let mut patch_area = vec![0.0; patch_count];
        for (&p, &a) in triangle_patch.iter().zip(&areas) {
            patch_area[p as usize] += a;
        }
        let patch_share: Vec<f64> = triangle_patch
            .iter()
            .zip(&areas)
            .map(|(&p, &a)| {
                let total = patch_area[p as usize];
                if total > 0.0 { a / total } else { 0.0 }
            })
            .collect();
        let regions = RegionWeights::new(mesh, &smooth_neutral, regions, params.region_sigma_mm)?;
        let rows = POLAR_CODE_LEN * patch_count;
        let mut compressed = DMatrix::zeros(rows, k_count);
        let mut details = vec![0f32; t_count * k_count * POLAR_CODE_LEN];
        let partial = Self {
            triangles,
            vertex_count: n,
            frame_names: frames.iter().map(|(s, _)| s.to_string()).collect(),
            low_pass,
            poisson,
            smooth_neutral,
            rest_inverses,
            face_weights,
            triangle_patch,
            patch_share,
            patch_count,
            regions,
            compressed: DMatrix::zeros(0, 0),
            row_weights: Default::default(),
            grams: Default::default(),
            details: Vec::new(),
            detail_slots: Vec::new(),
            varying_count: 0,
            varying_blend: Vec::new(),
            shared_details: Vec::new(),
            qp_ridge: params.qp_ridge,
            keep_input_low_band: params.keep_input_low_band,
        };
        for (k, (_, positions)) in frames.iter().enumerate() {
            let low = partial.low_pass.apply(positions)?;
            // High-frequency details: gradients from f(d) to d (world frame, §4.2).
            let codes = detail_codes(&partial.triangles, &low, positions);
            for c in 0..POLAR_CODE_LEN {
                let row = &mut details[(k * POLAR_CODE_LEN + c) * t_count..][..t_count];
                for (d, code) in row.iter_mut().zip(&codes) {
                    *d = code[c] as f32;
                }
            }
            // Low-frequency gradients relative to f(d₀), compressed (§4.2).
            let (aligned, _) = partial.align_to_smooth_neutral(&low)?;
            let column = partial.compressed_code(&partial.low_gradients(&aligned));
            compressed.set_column(k, &column);
        }
        let mut row_weights: [DVector<f64>; 4] = Default::default();
        let mut grams: [DMatrix<f64>; 4] = Default::default();
        for r in 0..4 {
            let mut patch_omega = vec![0.0; patch_count];
            for (t, &p) in partial.triangle_patch.iter().enumerate() {
                patch_omega[p as usize] += partial.patch_share[t] * partial.regions.omega[r][t];
            }
            let w = DVector::from_fn(rows, |i, _| patch_omega[i / POLAR_CODE_LEN]);
            let weighted = DMatrix::from_fn(rows, k_count, |i, j| compressed[(i, j)] * w[i]);
            grams[r] = compressed.transpose() * weighted;
            row_weights[r] = w;
        }
        let (details, detail_slots, varying_count, shared_details) =
            split_shared_details(&details, t_count, k_count);
        let varying_blend = detail_slots
            .iter()
            .zip(&partial.regions.blend)
            .filter(|(slot, _)| matches!(slot, DetailSlot::Varying(_)))
            .map(|(_, b)| *b)
            .collect();
        Ok(Self {
            compressed,
            row_weights,
            grams,
            details,
            detail_slots,
            varying_count,
            varying_blend,
            shared_details,
            ..partial
        })
    }

    /// Number of database frames (the neutral plus the shapes).
    pub fn frame_count(&self) -> usize {
        self.frame_names.len()
    }

    /// Names of the database frames (`neutral`, then the shape names).
    pub fn frame_names(&self) -> &[String] {
        &self.frame_names
    }

    /// Number of patches of the compressed shape space.
    pub fn patch_count(&self) -> usize {
        self.patch_count
    }

    /// Number of triangles whose details d^h differ between database frames (the others
    /// have one detail shared by every frame, which any convex blend reproduces).
    pub fn varying_triangle_count(&self) -> usize {
        self.varying_count
    }

    /// Approximate heap memory of the precomputed data, bytes (excluding the two sparse
    /// factorizations, whose size `faer` does not report).
    pub fn memory_bytes(&self) -> usize {
        self.details.len() * 4
            + self.shared_details.len() * 4 * POLAR_CODE_LEN
            + self.detail_slots.len() * std::mem::size_of::<DetailSlot>()
            + self.compressed.len() * 8
            + self.grams.iter().map(|g| g.len() * 8).sum::<usize>()
            + self.row_weights.iter().map(|w| w.len() * 8).sum::<usize>()
            + self.triangles.len() * (12 + 72 + 4 + 8 + 4 * 8 * 2 + 72 + 24)
            + self.vertex_count * (24 * 2 + 8 * 3)
    }

    /// The low-pass filter f(·) of the database (Eq. 1), e.g. to make test inputs.
    pub fn low_pass(&self) -> &LowPass {
        &self.low_pass
    }

    /// Enhances one frame: `positions` (#V, mm, the database topology, any rigid
    /// placement). Returns the enhanced positions in the same placement.
    ///
    /// # Errors
    /// [`EnhanceError::Shape`] for a wrong vertex count, [`EnhanceError::NonFinite`] for
    /// non-finite input, [`EnhanceError::Alignment`] if it cannot be aligned.
    pub fn enhance(&self, positions: &[Point3<f64>]) -> Result<Vec<Point3<f64>>, EnhanceError> {
        Ok(self.enhance_detailed(positions)?.positions)
    }

    /// [`Enhancer::enhance`], also returning the per-region weights.
    ///
    /// # Errors
    /// As [`Enhancer::enhance`].
    pub fn enhance_detailed(&self, positions: &[Point3<f64>]) -> Result<Enhanced, EnhanceError> {
        self.enhance_timed(positions, &mut EnhanceTimings::default())
    }

    /// [`Enhancer::enhance_detailed`], also recording the wall time of each step in
    /// `timings` (for benchmarks).
    ///
    /// # Errors
    /// As [`Enhancer::enhance`].
    pub fn enhance_timed(
        &self,
        positions: &[Point3<f64>],
        timings: &mut EnhanceTimings,
    ) -> Result<Enhanced, EnhanceError> {
        if positions.len() != self.vertex_count {
            return Err(EnhanceError::Shape {
                what: "input frame vertices",
                expected: self.vertex_count,
                got: positions.len(),
            });
        }
        if !positions
            .iter()
            .all(|p| p.coords.iter().all(|x| x.is_finite()))
        {
            return Err(EnhanceError::NonFinite("input frame".to_string()));
        }
        let mut clock = std::time::Instant::now();
        let mut lap = |slot: &mut f64| {
            let now = std::time::Instant::now();
            *slot = (now - clock).as_secs_f64();
            clock = now;
        };
        // §5.1 frequency separation, §5.2 alignment and encoding.
        let low = self.low_pass.apply(positions)?;
        lap(&mut timings.low_pass_input);
        let (aligned, head_from_input) = self.align_to_smooth_neutral(&low)?;
        let low_grads = self.low_gradients(&aligned);
        let code = self.compressed_code(&low_grads);
        lap(&mut timings.encode);
        // §5.3 matching, Eq. (3) per region.
        let k_count = self.frame_count();
        let mut region_weights: [DVector<f64>; 4] = Default::default();
        for ((w, gram), rows) in region_weights
            .iter_mut()
            .zip(&self.grams)
            .zip(&self.row_weights)
        {
            let b = self.compressed.transpose() * code.component_mul(rows);
            *w = convex_weights(gram, &b, self.qp_ridge)
                .ok_or_else(|| EnhanceError::NonFinite("matching system".to_string()))?;
        }
        lap(&mut timings.matching);
        // §5.4 interpolation, Eq. (4), and composition with the input's low frequencies.
        let gradients = self.blend_details(&region_weights, &low_grads, k_count);
        lap(&mut timings.blend);
        // §5.5 reconstruction and rigid placement.
        let input_aligned: Vec<Point3<f64>> =
            positions.iter().map(|p| head_from_input * p).collect();
        let rebuilt = self.poisson.solve(&gradients, &input_aligned)?;
        lap(&mut timings.reconstruct);
        let out = self.place_on_input(&rebuilt, positions, &low)?;
        lap(&mut timings.finish);
        Ok(Enhanced {
            positions: out,
            region_weights,
        })
    }

    /// The rigid placement of a reconstruction onto the input `positions` (§5.5) and, when
    /// [`EnhanceParams::keep_input_low_band`] is on, the input's low band `low` = f(a).
    fn place_on_input(
        &self,
        rebuilt: &[Point3<f64>],
        positions: &[Point3<f64>],
        low: &[Point3<f64>],
    ) -> Result<Vec<Point3<f64>>, EnhanceError> {
        let back = horn_alignment(rebuilt, positions, &self.face_weights)?;
        let mut out: Vec<Point3<f64>> = rebuilt.iter().map(|p| back * p).collect();
        if self.keep_input_low_band {
            // f(a) + (x − f(x)): the input's low band, the reconstruction's high band.
            let out_low = self.low_pass.apply(&out)?;
            for ((o, ol), il) in out.iter_mut().zip(&out_low).zip(low) {
                *o = il + (*o - ol);
            }
        }
        Ok(out)
    }

    /// The enhancement of `positions` with the high-frequency details d^h of `reference`
    /// itself (the gradients from f(reference) to reference, §4.2) in place of the blend
    /// of Eq. (4): what composition with the input's low-frequency gradients (§5.4) and
    /// reconstruction (§5.5) make of an input when the database holds the exact detail.
    ///
    /// This is the ceiling of the validation of §7: with `reference` the true detailed
    /// shape, the error left is what the input's own low band (f(a) ≠ f(reference)) and
    /// the reconstruction cost, whatever the database and the matching.
    ///
    /// # Errors
    /// As [`Enhancer::enhance`], for either argument.
    pub fn enhance_with_reference_details(
        &self,
        positions: &[Point3<f64>],
        reference: &[Point3<f64>],
    ) -> Result<Vec<Point3<f64>>, EnhanceError> {
        for (what, x) in [("input frame", positions), ("reference frame", reference)] {
            if x.len() != self.vertex_count {
                return Err(EnhanceError::Shape {
                    what: "frame vertices",
                    expected: self.vertex_count,
                    got: x.len(),
                });
            }
            if !x.iter().all(|p| p.coords.iter().all(|c| c.is_finite())) {
                return Err(EnhanceError::NonFinite(what.to_string()));
            }
        }
        let reference_low = self.low_pass.apply(reference)?;
        let details = detail_codes(&self.triangles, &reference_low, reference);
        let low = self.low_pass.apply(positions)?;
        let (aligned, head_from_input) = self.align_to_smooth_neutral(&low)?;
        let gradients: Vec<Matrix3<f64>> = details
            .par_iter()
            .zip(self.low_gradients(&aligned).par_iter())
            .map(|(code, l)| decode_polar(code) * l)
            .collect();
        let input_aligned: Vec<Point3<f64>> =
            positions.iter().map(|p| head_from_input * p).collect();
        let rebuilt = self.poisson.solve(&gradients, &input_aligned)?;
        self.place_on_input(&rebuilt, positions, &low)
    }

    /// Eq. (4) and §5.4: per triangle, the blend of the database details d^h with the
    /// region weights, decoded and composed with the input's low-frequency gradient.
    ///
    /// The triangles with varying details are split into chunks over the threads; each
    /// chunk accumulates, frame by frame over the frames some region selected, contiguous
    /// runs of the frame-major details (one per code component), so a frame nobody
    /// selected costs nothing and the inner loops are plain vector multiply-adds. The
    /// per-triangle sums run in database frame order, as in a triangle-by-triangle loop,
    /// so the result does not depend on the chunking or the thread count. A triangle with
    /// one shared detail d gets (Σ_k c_k) d, which is Σ_k c_k d up to rounding.
    fn blend_details(
        &self,
        region_weights: &[DVector<f64>; 4],
        low_grads: &[Matrix3<f64>],
        k_count: usize,
    ) -> Vec<Matrix3<f64>> {
        /// Triangles per chunk: 10 rows of 512 f64 (40 KiB) stay in L1/L2.
        const CHUNK: usize = 512;
        let varying = self.varying_count;
        let selected: Vec<(usize, [f64; 4])> = (0..k_count)
            .filter(|&k| region_weights.iter().any(|w| w[k] > 1e-9))
            .map(|k| (k, std::array::from_fn(|r| region_weights[r][k])))
            .collect();
        // Eq. (4): c_t,k = Σ_r ω̂_r,t w_r,k, the weight of frame k on triangle t.
        let frame_weight =
            |b: &[f64; 4], w: &[f64; 4]| -> f64 { (0..4).map(|r| b[r] * w[r]).sum() };
        let mut blended = vec![[0.0_f64; POLAR_CODE_LEN]; varying];
        blended
            .par_chunks_mut(CHUNK)
            .zip(self.varying_blend.par_chunks(CHUNK))
            .enumerate()
            .for_each(|(chunk, (out, blend))| {
                let j0 = chunk * CHUNK;
                let len = out.len();
                let mut acc = [[0.0_f64; CHUNK]; POLAR_CODE_LEN];
                let mut coef = [0.0_f64; CHUNK];
                for (k, w) in &selected {
                    for (c, b) in coef.iter_mut().zip(blend) {
                        *c = frame_weight(b, w);
                    }
                    for (comp, a) in acc.iter_mut().enumerate() {
                        let start = (k * POLAR_CODE_LEN + comp) * varying + j0;
                        let run = &self.details[start..start + len];
                        for ((x, &d), &c) in a[..len].iter_mut().zip(run).zip(&coef[..len]) {
                            *x += c * f64::from(d);
                        }
                    }
                }
                for (j, code) in out.iter_mut().enumerate() {
                    *code = std::array::from_fn(|c| acc[c][j]);
                }
            });
        let mut gradients = vec![Matrix3::zeros(); self.triangles.len()];
        gradients
            .par_iter_mut()
            .zip(low_grads.par_iter())
            .zip(
                self.detail_slots
                    .par_iter()
                    .zip(self.regions.blend.par_iter()),
            )
            .for_each(|((g, l), (slot, b))| {
                let code = match *slot {
                    DetailSlot::Varying(j) => blended[j as usize],
                    DetailSlot::Shared(j) => {
                        let total: f64 = selected.iter().map(|(_, w)| frame_weight(b, w)).sum();
                        self.shared_details[j as usize].map(|d| total * f64::from(d))
                    }
                };
                *g = decode_polar(&code) * l;
            });
        gradients
    }

    /// The compressed shape-space vector ã of a frame (§5.2): low-pass, Horn alignment to
    /// f(d₀), patch-averaged gradients, polar-encoded (9 · #patches values).
    ///
    /// # Errors
    /// As [`Enhancer::enhance`].
    pub fn shape_space_code(
        &self,
        positions: &[Point3<f64>],
    ) -> Result<DVector<f64>, EnhanceError> {
        if positions.len() != self.vertex_count {
            return Err(EnhanceError::Shape {
                what: "frame vertices",
                expected: self.vertex_count,
                got: positions.len(),
            });
        }
        let low = self.low_pass.apply(positions)?;
        let (aligned, _) = self.align_to_smooth_neutral(&low)?;
        Ok(self.compressed_code(&self.low_gradients(&aligned)))
    }

    /// Horn-aligns `positions` to f(d₀) over the face vertices (§5.2).
    fn align_to_smooth_neutral(
        &self,
        positions: &[Point3<f64>],
    ) -> Result<(Vec<Point3<f64>>, nalgebra::Isometry3<f64>), EnhanceError> {
        let iso = horn_alignment(positions, &self.smooth_neutral, &self.face_weights)?;
        Ok((positions.iter().map(|p| iso * p).collect(), iso))
    }

    /// Per-triangle gradients from f(d₀) to `positions` (#T).
    fn low_gradients(&self, positions: &[Point3<f64>]) -> Vec<Matrix3<f64>> {
        self.triangles
            .par_iter()
            .zip(self.rest_inverses.par_iter())
            .map(|(t, inv)| {
                let [a, b, c] = t.map(|v| positions[v as usize]);
                triangle_frame(&a, &b, &c) * inv
            })
            .collect()
    }

    /// The compressed shape-space vector: the area-weighted mean gradient of every patch,
    /// polar-encoded (9 · #patches).
    fn compressed_code(&self, gradients: &[Matrix3<f64>]) -> DVector<f64> {
        let mut mean = vec![Matrix3::zeros(); self.patch_count];
        for ((&p, &s), f) in self
            .triangle_patch
            .iter()
            .zip(&self.patch_share)
            .zip(gradients)
        {
            mean[p as usize] += f * s;
        }
        let mut out = DVector::zeros(POLAR_CODE_LEN * self.patch_count);
        for (p, m) in mean.iter().enumerate() {
            let code = encode_polar(m).unwrap_or_else(identity_code);
            for c in 0..POLAR_CODE_LEN {
                out[p * POLAR_CODE_LEN + c] = code[c];
            }
        }
        out
    }
}

/// Where a triangle's details d^h are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum DetailSlot {
    /// Index among the triangles whose details vary between frames.
    Varying(u32),
    /// Index into the details shared by every frame.
    Shared(u32),
}

/// Splits the details (component-major over all triangles: [(k · 9 + c) · #T + t]) into
/// the triangles whose codes differ between frames (returned in the same layout over
/// those triangles only, with their count) and those with one code in every frame.
fn split_shared_details(
    all: &[f32],
    t_count: usize,
    k_count: usize,
) -> (Vec<f32>, Vec<DetailSlot>, usize, Vec<[f32; POLAR_CODE_LEN]>) {
    let at = |k: usize, c: usize, t: usize| all[(k * POLAR_CODE_LEN + c) * t_count + t];
    let mut slots = Vec::with_capacity(t_count);
    let mut varying_triangles = Vec::new();
    let mut shared = Vec::new();
    for t in 0..t_count {
        let same = (1..k_count)
            .all(|k| (0..POLAR_CODE_LEN).all(|c| at(k, c, t).to_bits() == at(0, c, t).to_bits()));
        if same {
            slots.push(DetailSlot::Shared(shared.len() as u32));
            shared.push(std::array::from_fn(|c| at(0, c, t)));
        } else {
            slots.push(DetailSlot::Varying(varying_triangles.len() as u32));
            varying_triangles.push(t);
        }
    }
    let varying = varying_triangles.len();
    let mut details = vec![0f32; varying * k_count * POLAR_CODE_LEN];
    for k in 0..k_count {
        for c in 0..POLAR_CODE_LEN {
            let row = &mut details[(k * POLAR_CODE_LEN + c) * varying..][..varying];
            for (d, &t) in row.iter_mut().zip(&varying_triangles) {
                *d = at(k, c, t);
            }
        }
    }
    (details, slots, varying, shared)
}

/// The high-frequency details d^h of a frame (§4.2): per triangle, the polar code of the
/// deformation gradient from its low-pass `low` = f(d) to the frame `positions` = d.
fn detail_codes(
    triangles: &[[u32; 3]],
    low: &[Point3<f64>],
    positions: &[Point3<f64>],
) -> Vec<[f64; POLAR_CODE_LEN]> {
    triangles
        .par_iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| low[v as usize]);
            let [x, y, z] = t.map(|v| positions[v as usize]);
            let f = triangle_frame(&x, &y, &z)
                * triangle_frame(&a, &b, &c)
                    .try_inverse()
                    .unwrap_or_else(Matrix3::identity);
            encode_polar(&f).unwrap_or_else(identity_code)
        })
        .collect()
}

/// The code of the identity gradient.
fn identity_code() -> [f64; POLAR_CODE_LEN] {
    [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0]
}
