//! Smoothing parameters: one serde struct shared by the CLI (`--params
//! FILE.json` and flags) and the HTTP API (JSON body or query string).
//!
//! Every default lives in exactly one place, the `Default` impls below; each
//! field's doc comment states it, and `tests::defaults_are_pinned` pins it.
//! Unknown fields are rejected when deserialising.

use crate::error::ErrorCode;
use crate::fit::quadric_fit::MAX_FIT_POINTS;
use crate::smoothing::neighbourhood::MAX_RINGS;
use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use crate::quality::QualityParams;

/// Which smoother to run.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// Quadric fitting with curvature-adaptive neighbourhoods (Wang & Yu 2009).
    #[default]
    WangYu,
    /// Taubin λ/μ smoothing (baseline).
    Taubin,
    /// Uniform Laplacian smoothing (baseline).
    Laplacian,
}

/// The surface model of the adaptive passes' fits (section 3; the paper
/// fits a quadric).
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum AdaptiveFit {
    /// The quadric plus the four cubic terms (default): where the curvature
    /// changes across a neighbourhood, the cubic terms take up what a
    /// quadric would turn into a height bias at every pass. Falls back to
    /// the quadric below 14 fitted points.
    #[default]
    Cubic,
    /// The paper's quadric.
    Quadric,
}

/// What happens at boundary vertices (edges with a single face). Section 0
/// of the algorithm notes leaves this open.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum BoundaryRule {
    /// Boundary vertices never move (default): the rim of a cropped surface
    /// stays exactly where the crop put it.
    #[default]
    Fixed,
    /// Boundary vertices move along their normal only, onto a plane fitted
    /// to their one-sided neighbourhood (a quadric would extrapolate).
    NormalOnly,
}

/// All parameters of a run. Defaults: `Params::default()`.
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema), schema(default))]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    /// Smoother. Default `wang-yu`.
    pub method: Method,
    /// Passes of initial smoothing with fixed 2-ring fits (section 2.2).
    /// Default 3; range 0..=100.
    pub initial_passes: u32,
    /// `initial_passes` on a marching-cubes mesh of a mask: the staircase
    /// relaxation after the first pass has done most of their work, and a
    /// third pass of 2-ring fits flattens a thin sheet's folds (a cortical
    /// ribbon one or two voxels thick) where the adaptive passes cannot
    /// bring them back. Chosen from 1, 2 and 3 on the WM crop and GM masks
    /// at four grid placements each and on the analytic families
    /// (`docs/tuning.md`). Default 2; range 0..=100.
    pub marching_cubes_initial_passes: u32,
    /// Passes of adaptive smoothing (section 2.3). Default 22; range 0..=200:
    /// enough passes to damp a large sphere's long staircase waves, few
    /// enough that a surface of changing curvature does not drift
    /// (`docs/tuning.md`). Vertices whose neighbourhood grew to 15 rings or
    /// more (flat regions) move with momentum and make 8 in 11 of these
    /// passes (16 of 22), which damps those waves as far with less drift.
    pub adaptive_passes: u32,
    /// `adaptive_passes` on a voxel lattice: the lattice fairing has
    /// already damped the staircase's long waves, and fewer passes keep the
    /// analytic families closer at every grid placement (`docs/tuning.md`).
    /// Default 16; range 0..=200.
    pub lattice_adaptive_passes: u32,
    /// Surface model of the adaptive fits. Default `cubic`.
    pub adaptive_fit: AdaptiveFit,
    /// Largest ring `k` an adaptive neighbourhood may grow to (section 2.3).
    /// Default 16; range 2..=32.
    pub k_max: u32,
    /// Most neighbours used in one fit: larger rings are thinned to this many
    /// well-spread points, so a fit's cost does not grow with `k`.
    /// Default 56, the fewest that keep the voxel ellipsoid within its
    /// accuracy target (`docs/tuning.md`); range 6..=512.
    pub max_fit_points: u32,
    /// Ring of the fits that estimate the curvature used for labelling and
    /// ring growth, after initial smoothing (open in the paper: a wider fit
    /// than the 2-ring keeps staircase noise out of the labels).
    /// Default 6; range 2..=32.
    pub curvature_ring: u32,
    /// Flatness tolerance `t_H` on `|H| l` (l = mean edge length), section 6.
    /// Default 0.04; range 0..=10.
    pub tolerance_h: f64,
    /// Flatness tolerance `t_K` on `|K| l^2`, section 6. Default 0.002;
    /// range 0..=10.
    pub tolerance_k: f64,
    /// A ring candidate agrees with the centre's label when its curvature
    /// lies within this margin (on `H l`) of the centre's label region, so
    /// noise near a tolerance does not split a smooth region. 0 is the
    /// paper's exact test. Default 0.04; range 0..=10.
    pub label_margin: f64,
    /// Growth stops when more than this fraction of the next ring's
    /// vertices disagree with the centre's label (0 is the paper's "any
    /// vertex"; a small fraction keeps isolated noisy estimates from
    /// stopping growth on a smooth surface). Default 0.25; range 0..=1.
    pub label_disagreement: f64,
    /// Growth takes the next ring only if the standard deviation of `H l`
    /// over the grown set does not rise by more than this (the paper asks for
    /// a decrease; curvature estimates carry noise of about this size).
    /// Default 0.005; range 0..=10.
    pub std_tolerance: f64,
    /// Growth stops when the standard deviation of `H l` over the grown set
    /// would exceed this bound (section 2.3). Default 0.05; range 0..=100.
    pub curvature_std_bound: f64,
    /// Growth stops when a quadric fitted out to the next ring would bias
    /// the projection outward by more than this many mean edge lengths: a
    /// paraboloid fitted to a sphere of curvature `kappa` over radius `rho`
    /// sits `rho^4 kappa^3 / 48` above it; `kappa` is estimated from the
    /// heights of the ring over the tangent plane. Default 0.06; range 0..=10.
    pub bias_bound: f64,
    /// A neighbour whose normal turns more than this many degrees from the
    /// vertex's normal is left out of the vertex's fits: it lies on the far
    /// side of a thin plate or tube (a one-voxel sheet, a neurite) or
    /// across a fold, and fitting it would pull both sides together (open
    /// in the paper). 180 keeps every neighbour. Default 60; range 0..=180.
    pub max_normal_angle_deg: f64,
    /// Staircase relaxation steps (our addition to section 2.2): each moves
    /// every vertex part of the way to the mean of its neighbours, within
    /// the fidelity bound. On a voxel lattice (a voxel-boundary mesh) the
    /// relaxation replaces the initial passes: `lattice_staircase_lambda`
    /// steps over all neighbours remove the staircase, and quadric fits
    /// made on the staircase itself (in frames tilted along its diagonals)
    /// would only pull the corners back toward it; the corners where voxels
    /// touch along an edge or at a corner (non-manifold vertices, which no
    /// other step moves) relax with the rest. On a marching-cubes mesh of a
    /// mask (every vertex at a lattice edge's midpoint, on an axis-aligned
    /// grid) the steps (`staircase_lambda`, facing neighbours only) run
    /// between the first and the second initial pass, so the later fits are
    /// made in frames that follow the surface (needs at least 2 initial
    /// passes). A mesh that samples no lattice (a neuron, a molecular
    /// surface) has no staircase: it gets the paper's passes alone.
    /// Default 2; range 0..=10 (0 on a lattice: the paper's initial passes).
    pub staircase_steps: u32,
    /// Step of the staircase relaxation, a fraction of the way to the
    /// neighbours' mean: two half steps remove the corners' spikes without
    /// the shrinking of a full umbrella step, on a surface that is not a
    /// voxel staircase. Default 0.5; range 0 < l <= 1.
    pub staircase_lambda: f64,
    /// Step of the staircase relaxation on a voxel lattice: a full step
    /// moves a voxel corner to the mean of its lattice neighbours, and two
    /// of them bring outer and inner corners of the staircase together onto
    /// the surface the mask samples, where half steps leave them part of
    /// the way (the fidelity bound keeps every corner in its dual voxel).
    /// Default 1; range 0 < l <= 1.
    pub lattice_staircase_lambda: f64,
    /// After the staircase relaxation (when `staircase_steps` is not 0),
    /// each vertex moves back out along its normal by this fraction of the
    /// normal part of its umbrella vector, averaged over a few rings: the
    /// inward shift an umbrella step gives a curved patch, largest where
    /// the curvature is (a gyrus's crown, a crop's rim), which the volume
    /// restoration's one global offset cannot put back where it was lost.
    /// 0 leaves it. Default 0.5, the best of 0 to 1.5 on the real brain
    /// masks (`docs/tuning.md`); range 0..=2.
    pub shrinkage_compensation: f64,
    /// [`Params::shrinkage_compensation`] on a voxel lattice. Default 0.5;
    /// range 0..=2.
    pub lattice_shrinkage_compensation: f64,
    /// Accelerated steps of the lattice fairing (our addition to section
    /// 2.2, `smoothing/fairing.rs`): on a voxel lattice, after the
    /// staircase relaxation, the surface of least bending (thin-plate
    /// energy of the umbrella operator) that stays near the input corners
    /// and inside their dual voxels. The relaxation leaves a terrace (a
    /// flat run of faces, a sphere's pole) flat wherever the grid fell; the
    /// fairing bends it with its rims, so the accuracy no longer depends on
    /// the grid's placement. 40 steps leave every corner within a few
    /// hundredths of a voxel of the minimiser (`docs/tuning.md`). 0 turns
    /// it off; it needs the fidelity bound (`max_displacement`). Default
    /// 40; range 0..=1000.
    pub lattice_fairing_iterations: u32,
    /// The lattice fairing's pull toward the input corners, relative to the
    /// bending energy: `s^-4` keeps the input's shape at wavelengths longer
    /// than about `2 pi s` edges and smooths shorter ones within the dual
    /// voxels. Corners deep inside a wide terrace are pulled only within its
    /// plane, so it bends with its rims wherever the grid put it. Default
    /// 0.03 (`s` about 2.4), the best of 0.01 to 0.06 on the real voxel
    /// masks and the analytic families (`docs/tuning.md`); range 0 < a <=
    /// 100.
    pub lattice_fairing_anchor: f64,
    /// A vertex whose adaptive neighbourhood stays within this many rings
    /// lies on the shape, not on the staircase: the curvature changes
    /// within a few rings of it (a gyrus, a thin tube). The initial passes
    /// already removed the staircase there, and further passes with fits
    /// that small would flatten the shape, so it makes only
    /// `shape_passes` adaptive passes. 2 is the initial passes' ring: the
    /// vertices whose growth stopped at once. Default 2; range 0..=32 (0:
    /// no vertex stops).
    pub shape_ring: u32,
    /// Adaptive passes of the vertices on the shape (`shape_ring`).
    /// Default 4; range 0..=200 (at least `adaptive_passes`: they make all).
    pub shape_passes: u32,
    /// `shape_passes` on a voxel lattice. The lattice relaxation has already
    /// removed the staircase where the curvature changes within a few
    /// voxels (a gyrus, a sheet two voxels thick), and any pass of fits
    /// that small moves the surface away from the shape the mask samples.
    /// Default 0; range 0..=200.
    pub lattice_shape_passes: u32,
    /// Taubin λ/μ step pairs on a voxel lattice after the adaptive passes
    /// (our addition; `smoothing::taubin::LOWPASS_LAMBDA` and `LOWPASS_MU`),
    /// within the fidelity bound. The fits and the fairing leave corners
    /// against the walls of their dual voxels in the grid's own pattern, a
    /// ripple one or two voxels long that no mask can resolve; a few steps
    /// of a low-pass filter that barely shrinks remove it and keep every
    /// longer wave. Chosen from 0, 2, 4 and 8 on the real masks at several
    /// grid placements and on the analytic families (`docs/tuning.md`):
    /// more helps the thin tubes and the WM crop, the GM mask's finest
    /// folds lose past 4. Default 4; range 0..=100.
    pub lattice_lowpass_steps: u32,
    /// The fidelity bound: how far a vertex may end from its input
    /// position. A vertex of a voxel lattice is held in the box of this
    /// many voxel spacings along each of the lattice's axes (0.5 is its
    /// dual voxel, which the true surface crosses, as long across thick
    /// slices as they are: no vertex of a voxel mesh moves more than
    /// `sqrt(3)/2` voxel); any other vertex within a ball of this many of
    /// its mean input edge lengths. A vertex of a marching-cubes
    /// mesh of a mask is also held, across the surface, where the surface
    /// crosses its lattice edge within 0.85 of this many voxel spacings of
    /// its midpoint (0.5: between the edge's two voxel centres, 0.075
    /// spacing short of each). Every smoothing
    /// pass, the volume restoration and the quality fixes keep to it; the
    /// report counts the vertices it held back. `null` lets vertices move
    /// freely.
    /// Default 0.5; range 0 < d <= 10.
    pub max_displacement: Option<f64>,
    /// On a mesh cut from no voxel grid (the marching cubes of a probability
    /// map, a blurred or decimated mask's mesh, a molecular surface): how
    /// far a vertex may move across its input surface, in multiples of the
    /// input's noise. The noise is estimated from the input itself: the
    /// median height of a vertex above the quadric with cubic terms fitted
    /// to its 2-ring, in its mean edge lengths (reported as
    /// `wang_yu.input_noise`). Such a mesh may already be smooth, and the
    /// passes' fits would reshape its folds; independent noise of standard
    /// deviation `sigma` gives an estimate of about `0.85 sigma`, so the
    /// default 2 lets a vertex move 1.7 standard deviations of it: the
    /// noise is taken out but for its tails, and a move farther across is
    /// the fits reshaping the surface (on the meshes of real probability
    /// maps, their folds), not noise (`docs/tuning.md`). The distance
    /// across is measured from the input's own quadric through the vertex,
    /// so moves along a curved surface are free (within
    /// `max_displacement`). After the passes, the move across that a vertex
    /// shares with its 1-ring (the fits' bias, which flattens folds; noise
    /// averages out over a ring) is taken back. Needs `max_displacement`;
    /// `null` holds such vertices in its ball alone and takes nothing back.
    /// Default 2; range 0 < k <= 100.
    pub noise_bound: Option<f64>,
    /// What boundary vertices do. Default `fixed`.
    pub boundary: BoundaryRule,
    /// Restore the input's enclosed volume at the end by a uniform offset
    /// along the vertex normals (closed meshes only; the solids and the
    /// cavities each get their own). On a voxel lattice the smooth surface
    /// through the vertices gets the mask's volume, so the flat faces of a
    /// thin convex part enclose slightly less (at most 1.5%; the report's
    /// `wang_yu.volume_target_change`). A connected part that collapses
    /// (a fragment or a hole a voxel or two across, which its mask
    /// overstates, whose loss no offset of half an edge gives back) is left
    /// as smoothed, and a warning says so when that is more than 0.5% of
    /// the volume.
    /// Default true.
    pub preserve_volume: bool,
    /// Join vertices that share a position before smoothing (glTF seams,
    /// STL triangle soups). Every file vertex gets its welded vertex's
    /// position, so seams stay closed and an output in the input's format
    /// keeps the file's vertex count and order (another format gets the
    /// welded mesh). `null` takes the format's default: on for glTF/GLB and
    /// STL, and for an OBJ, PLY or OFF that repeats most of its positions
    /// (welding leaves at most half its vertices: a face soup, a
    /// flat-shaded export) or whose repeated positions join open edges (a
    /// crack: separate sheets meeting at the same rim, as VTK's surface
    /// nets leave where voxels touch along an edge; a PLY cut along its
    /// texture seams); off for other OBJ, PLY and OFF. Bodies whose surfaces
    /// touch face to face (segments of a segmentation written into one
    /// file, each with its own vertices) are welded each on its own and
    /// smoothed apart (report `mesh.touching_bodies`). Default `null`.
    pub weld: Option<bool>,
    /// Welding tolerance as a fraction of the bounding-box diagonal; 0 joins
    /// only equal positions. Default 0; range 0..=0.01.
    pub weld_tolerance: f64,
    /// Add per-vertex results (label, mean and Gaussian curvature,
    /// displacement) to the written mesh: glTF attributes `_LABEL`,
    /// `_MEAN_CURVATURE`, `_GAUSSIAN_CURVATURE`, `_DISPLACEMENT`; PLY vertex
    /// properties `label`, `mean_curvature`, `gaussian_curvature`,
    /// `displacement`. OBJ, STL and OFF cannot hold them: ignored there.
    /// Default false.
    pub vertex_results: bool,
    /// Mesh-quality fixes (section 2.4).
    pub quality: QualityParams,
    /// Parameters of the baseline methods.
    pub baseline: BaselineParams,
}

impl Default for Params {
    fn default() -> Self {
        Params {
            method: Method::WangYu,
            initial_passes: 3,
            marching_cubes_initial_passes: 2,
            adaptive_passes: 22,
            lattice_adaptive_passes: 16,
            adaptive_fit: AdaptiveFit::Cubic,
            k_max: 16,
            max_fit_points: 56,
            curvature_ring: 6,
            tolerance_h: 0.04,
            tolerance_k: 0.002,
            label_margin: 0.04,
            label_disagreement: 0.25,
            std_tolerance: 0.005,
            curvature_std_bound: 0.05,
            bias_bound: 0.06,
            max_normal_angle_deg: 60.0,
            staircase_steps: 2,
            staircase_lambda: 0.5,
            lattice_staircase_lambda: 1.0,
            shrinkage_compensation: 0.5,
            lattice_shrinkage_compensation: 0.5,
            lattice_fairing_iterations: 40,
            lattice_fairing_anchor: 0.03,
            shape_ring: 2,
            shape_passes: 4,
            lattice_shape_passes: 0,
            lattice_lowpass_steps: 4,
            max_displacement: Some(0.5),
            noise_bound: Some(2.0),
            boundary: BoundaryRule::Fixed,
            preserve_volume: true,
            weld: None,
            weld_tolerance: 0.0,
            vertex_results: false,
            quality: QualityParams::default(),
            baseline: BaselineParams::default(),
        }
    }
}

/// Parameters of the baseline smoothers (`method = taubin | laplacian`).
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema), schema(default))]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BaselineParams {
    /// Iterations. Default 20; range 0..=10000.
    pub iterations: u32,
    /// Laplacian step λ (both methods). Default 0.5; range 0 < λ <= 1.
    pub lambda: f64,
    /// Taubin's inflating step μ. Default -0.53; range -1 <= μ < 0, |μ| > λ.
    pub mu: f64,
}

impl Default for BaselineParams {
    fn default() -> Self {
        BaselineParams {
            iterations: 20,
            lambda: 0.5,
            mu: -0.53,
        }
    }
}

/// A parameter out of its allowed range.
#[derive(Debug, Error, Clone, PartialEq)]
#[error("parameter `{field}` = {value} is out of range: allowed {allowed}")]
pub struct ParamError {
    /// Dotted field path, e.g. `quality.sharp_angle_deg`.
    pub field: &'static str,
    /// The rejected value, as text.
    pub value: String,
    /// The allowed range, as text.
    pub allowed: &'static str,
}

impl ParamError {
    /// Stable code.
    pub fn code(&self) -> ErrorCode {
        ErrorCode::ParameterOutOfRange
    }
}

// The ranges of `k_max`, `curvature_ring`, `shape_ring` and
// `max_fit_points` are the ring walker's and the fits' limits; the texts in
// `validate` name them.
const _: () = assert!(MAX_RINGS == 32 && MAX_FIT_POINTS == 512);

fn check_u32(
    field: &'static str,
    v: u32,
    lo: u32,
    hi: u32,
    allowed: &'static str,
) -> Result<(), ParamError> {
    if v < lo || v > hi {
        return Err(ParamError {
            field,
            value: v.to_string(),
            allowed,
        });
    }
    Ok(())
}

fn check_f64(
    field: &'static str,
    v: f64,
    ok: bool,
    allowed: &'static str,
) -> Result<(), ParamError> {
    if !v.is_finite() || !ok {
        return Err(ParamError {
            field,
            value: v.to_string(),
            allowed,
        });
    }
    Ok(())
}

impl Params {
    /// Checks every range; the error names the field and the allowed range.
    pub fn validate(&self) -> Result<(), ParamError> {
        check_u32("initial_passes", self.initial_passes, 0, 100, "0..=100")?;
        check_u32(
            "marching_cubes_initial_passes",
            self.marching_cubes_initial_passes,
            0,
            100,
            "0..=100",
        )?;
        check_u32("adaptive_passes", self.adaptive_passes, 0, 200, "0..=200")?;
        check_u32(
            "lattice_adaptive_passes",
            self.lattice_adaptive_passes,
            0,
            200,
            "0..=200",
        )?;
        check_u32("k_max", self.k_max, 2, MAX_RINGS as u32, "2..=32")?;
        check_u32(
            "max_fit_points",
            self.max_fit_points,
            6,
            MAX_FIT_POINTS as u32,
            "6..=512",
        )?;
        check_u32(
            "curvature_ring",
            self.curvature_ring,
            2,
            MAX_RINGS as u32,
            "2..=32",
        )?;
        check_u32("shape_ring", self.shape_ring, 0, MAX_RINGS as u32, "0..=32")?;
        check_u32("staircase_steps", self.staircase_steps, 0, 10, "0..=10")?;
        let l = self.staircase_lambda;
        check_f64("staircase_lambda", l, l > 0.0 && l <= 1.0, "0 < l <= 1")?;
        let l = self.lattice_staircase_lambda;
        check_f64(
            "lattice_staircase_lambda",
            l,
            l > 0.0 && l <= 1.0,
            "0 < l <= 1",
        )?;
        check_u32("shape_passes", self.shape_passes, 0, 200, "0..=200")?;
        check_u32(
            "lattice_fairing_iterations",
            self.lattice_fairing_iterations,
            0,
            1000,
            "0..=1000",
        )?;
        let a = self.lattice_fairing_anchor;
        check_f64(
            "lattice_fairing_anchor",
            a,
            a > 0.0 && a <= 100.0,
            "0 < a <= 100",
        )?;
        check_u32(
            "lattice_shape_passes",
            self.lattice_shape_passes,
            0,
            200,
            "0..=200",
        )?;
        check_u32(
            "lattice_lowpass_steps",
            self.lattice_lowpass_steps,
            0,
            100,
            "0..=100",
        )?;
        for (field, v, hi, allowed) in [
            ("tolerance_h", self.tolerance_h, 10.0, "0..=10"),
            ("tolerance_k", self.tolerance_k, 10.0, "0..=10"),
            ("label_margin", self.label_margin, 10.0, "0..=10"),
            ("label_disagreement", self.label_disagreement, 1.0, "0..=1"),
            ("std_tolerance", self.std_tolerance, 10.0, "0..=10"),
            (
                "curvature_std_bound",
                self.curvature_std_bound,
                100.0,
                "0..=100",
            ),
            ("bias_bound", self.bias_bound, 10.0, "0..=10"),
            (
                "shrinkage_compensation",
                self.shrinkage_compensation,
                2.0,
                "0..=2",
            ),
            (
                "lattice_shrinkage_compensation",
                self.lattice_shrinkage_compensation,
                2.0,
                "0..=2",
            ),
            (
                "max_normal_angle_deg",
                self.max_normal_angle_deg,
                180.0,
                "0..=180",
            ),
        ] {
            check_f64(field, v, (0.0..=hi).contains(&v), allowed)?;
        }
        if let Some(d) = self.max_displacement {
            check_f64("max_displacement", d, d > 0.0 && d <= 10.0, "0 < d <= 10")?;
        }
        if let Some(k) = self.noise_bound {
            check_f64("noise_bound", k, k > 0.0 && k <= 100.0, "0 < k <= 100")?;
        }
        let w = self.weld_tolerance;
        check_f64("weld_tolerance", w, (0.0..=0.01).contains(&w), "0..=0.01")?;
        let q = &self.quality;
        let f = q.short_edge_fraction;
        check_f64(
            "quality.short_edge_fraction",
            f,
            (0.0..=1.0).contains(&f),
            "0..=1",
        )?;
        let a = q.sharp_angle_deg;
        check_f64(
            "quality.sharp_angle_deg",
            a,
            (0.0..=60.0).contains(&a),
            "0..=60",
        )?;
        check_u32("quality.max_sweeps", q.max_sweeps, 0, 100, "0..=100")?;
        let b = &self.baseline;
        check_u32("baseline.iterations", b.iterations, 0, 10_000, "0..=10000")?;
        let l = b.lambda;
        check_f64("baseline.lambda", l, l > 0.0 && l <= 1.0, "0 < lambda <= 1")?;
        let m = b.mu;
        check_f64(
            "baseline.mu",
            m,
            (-1.0..0.0).contains(&m) && -m > l,
            "-1 <= mu < 0 and |mu| > lambda",
        )?;
        Ok(())
    }

    /// Cosine of [`Params::max_normal_angle_deg`]: the smallest accepted
    /// cosine between a fitted neighbour's normal and the vertex's (below
    /// -1 at 180°, so nothing is left out).
    pub fn min_normal_cos(&self) -> f64 {
        if self.max_normal_angle_deg >= 180.0 {
            f64::NEG_INFINITY
        } else {
            self.max_normal_angle_deg.to_radians().cos()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_pinned() {
        let p = Params::default();
        assert_eq!(p.method, Method::WangYu);
        assert_eq!(p.initial_passes, 3);
        assert_eq!(p.adaptive_passes, 22);
        assert_eq!(p.adaptive_fit, AdaptiveFit::Cubic);
        assert_eq!(p.k_max, 16);
        assert_eq!(p.max_fit_points, 56);
        assert_eq!(p.curvature_ring, 6);
        assert_eq!(p.tolerance_h, 0.04);
        assert_eq!(p.tolerance_k, 0.002);
        assert_eq!(p.label_margin, 0.04);
        assert_eq!(p.label_disagreement, 0.25);
        assert_eq!(p.std_tolerance, 0.005);
        assert_eq!(p.curvature_std_bound, 0.05);
        assert_eq!(p.bias_bound, 0.06);
        assert_eq!(p.max_normal_angle_deg, 60.0);
        assert_eq!(p.boundary, BoundaryRule::Fixed);
        assert!(p.preserve_volume);
        assert_eq!(p.weld, None);
        assert_eq!(p.weld_tolerance, 0.0);
        assert!(!p.vertex_results);
        assert_eq!(
            p.quality,
            QualityParams {
                enabled: true,
                short_edge_fraction: 0.2,
                sharp_angle_deg: 20.0,
                max_sweeps: 20
            }
        );
        assert_eq!(
            p.baseline,
            BaselineParams {
                iterations: 20,
                lambda: 0.5,
                mu: -0.53
            }
        );
        p.validate().unwrap();
    }

    #[test]
    fn out_of_range_names_field_and_range() {
        let p = Params {
            k_max: 40,
            ..Params::default()
        };
        let e = p.validate().unwrap_err();
        assert_eq!(e.field, "k_max");
        assert!(e.to_string().contains("2..=32"), "{e}");
        let mut p = Params::default();
        p.quality.sharp_angle_deg = f64::NAN;
        assert_eq!(p.validate().unwrap_err().field, "quality.sharp_angle_deg");
    }

    #[test]
    fn unknown_fields_are_rejected() {
        let e = serde_json::from_str::<Params>(r#"{"k_maks": 3}"#).unwrap_err();
        assert!(e.to_string().contains("k_maks"), "{e}");
        let p: Params =
            serde_json::from_str(r#"{"method": "taubin", "quality": {"enabled": false}}"#).unwrap();
        assert_eq!(p.method, Method::Taubin);
        assert!(!p.quality.enabled);
        assert_eq!(p.k_max, Params::default().k_max);
    }

    #[test]
    fn adaptive_fit_is_cubic_or_quadric() {
        let p: Params = serde_json::from_str(r#"{"adaptive_fit": "quadric"}"#).unwrap();
        assert_eq!(p.adaptive_fit, AdaptiveFit::Quadric);
        let p: Params = serde_json::from_str(r#"{"adaptive_fit": "cubic"}"#).unwrap();
        assert_eq!(p.adaptive_fit, AdaptiveFit::Cubic);
        let e = serde_json::from_str::<Params>(r#"{"adaptive_fit": "quartic"}"#).unwrap_err();
        assert!(e.to_string().contains("quartic"), "{e}");
    }

    #[test]
    fn weld_is_null_true_or_false() {
        for (json, weld) in [
            (r#"{"weld": null}"#, None),
            (r#"{"weld": true}"#, Some(true)),
            (r#"{"weld": false}"#, Some(false)),
            ("{}", None),
        ] {
            let p: Params = serde_json::from_str(json).unwrap();
            assert_eq!(p.weld, weld, "{json}");
            let back = serde_json::to_value(&p).unwrap();
            assert_eq!(back["weld"], serde_json::to_value(weld).unwrap(), "{json}");
        }
        assert!(serde_json::from_str::<Params>(r#"{"weld": "yes"}"#).is_err());
        let p: Params =
            serde_json::from_str(r#"{"weld_tolerance": 0.001, "vertex_results": true}"#).unwrap();
        assert_eq!(p.weld_tolerance, 0.001);
        assert!(p.vertex_results);
    }

    #[test]
    fn weld_tolerance_is_range_checked() {
        for ok in [0.0, 1e-6, 0.01] {
            let p = Params {
                weld_tolerance: ok,
                ..Params::default()
            };
            p.validate().unwrap();
        }
        for bad in [-1e-9, 0.0101, f64::NAN, f64::INFINITY] {
            let p = Params {
                weld_tolerance: bad,
                ..Params::default()
            };
            let e = p.validate().unwrap_err();
            assert_eq!(e.field, "weld_tolerance");
            assert!(e.to_string().contains("0..=0.01"), "{e}");
        }
    }
}
