//! Flags for the main parameters, applied on top of `--params FILE.json`.
//! Each flag names a field of [`Params`]; its default is the field's default
//! (or the file's value), so no default is restated here.

use meshsmooth_core::Params;
use meshsmooth_core::params::{AdaptiveFit, BoundaryRule, Method};
use serde::de::DeserializeOwned;

/// Parameter flags of `meshsmooth smooth`; `None` keeps the value from the
/// parameter file or the default.
#[derive(Debug, Default, clap::Args)]
pub struct ParamFlags {
    /// Smoother: `wang-yu` (quadric fitting, Wang & Yu 2009), or the
    /// baselines `taubin` and `laplacian` [params: method].
    #[arg(long, value_name = "METHOD", value_parser = serde_name::<Method>)]
    method: Option<Method>,
    /// Initial smoothing passes with 2-ring fits [params: initial_passes].
    #[arg(long, value_name = "N")]
    initial_passes: Option<u32>,
    /// Adaptive smoothing passes [params: adaptive_passes].
    #[arg(long, value_name = "N")]
    adaptive_passes: Option<u32>,
    /// Surface model of the adaptive fits: `cubic` (quadric plus cubic
    /// terms) or the paper's `quadric` [params: adaptive_fit].
    #[arg(long, value_name = "MODEL", value_parser = serde_name::<AdaptiveFit>)]
    adaptive_fit: Option<AdaptiveFit>,
    /// Largest ring an adaptive neighbourhood may grow to [params: k_max].
    #[arg(long, value_name = "K")]
    k_max: Option<u32>,
    /// Most points used in one fit [params: max_fit_points].
    #[arg(long, value_name = "N")]
    max_fit_points: Option<u32>,
    /// Flatness tolerance on |H| times the mean edge length
    /// [params: tolerance_h].
    #[arg(long, value_name = "T")]
    tolerance_h: Option<f64>,
    /// Flatness tolerance on |K| times the squared mean edge length
    /// [params: tolerance_k].
    #[arg(long, value_name = "T")]
    tolerance_k: Option<f64>,
    /// Boundary vertices: `fixed` or `normal_only` [params: boundary].
    #[arg(long, value_name = "RULE", value_parser = serde_name::<BoundaryRule>)]
    boundary: Option<BoundaryRule>,
    /// Do not restore the enclosed volume at the end
    /// [params: preserve_volume = false].
    #[arg(long)]
    no_preserve_volume: bool,
    /// Skip the mesh-quality fixes [params: quality.enabled = false].
    #[arg(long)]
    no_quality: bool,
    /// Triangle-split angle (degrees) below which the sharp-angle fix acts
    /// [params: quality.sharp_angle_deg].
    #[arg(long, value_name = "DEG")]
    sharp_angle_deg: Option<f64>,
    /// Iterations of the baseline smoothers [params: baseline.iterations].
    #[arg(long, value_name = "N")]
    iterations: Option<u32>,
    /// Laplacian step of the baselines [params: baseline.lambda].
    #[arg(long, value_name = "L")]
    lambda: Option<f64>,
    /// Taubin's negative step [params: baseline.mu].
    #[arg(long, value_name = "MU", allow_negative_numbers = true)]
    mu: Option<f64>,
    #[command(flatten)]
    weld: WeldFlags,
    /// Add per-vertex results (label, curvatures, displacement) to a glTF
    /// or PLY output; OBJ, STL and OFF cannot hold them
    /// [params: vertex_results = true].
    #[arg(long)]
    vertex_results: bool,
}

/// Welding flags, shared by `smooth` and `report`; the last of `--weld`
/// and `--no-weld` wins.
#[derive(Debug, Default, clap::Args)]
pub struct WeldFlags {
    /// Join vertices that share a position before smoothing (default: on
    /// for glTF, STL and files that repeat most of their positions, off
    /// for other OBJ, PLY and OFF) [params: weld = true].
    #[arg(long, overrides_with = "no_weld")]
    weld: bool,
    /// Do not join vertices that share a position [params: weld = false].
    #[arg(long, overrides_with = "weld")]
    no_weld: bool,
    /// Join vertices closer than this fraction of the bounding-box diagonal
    /// when welding [params: weld_tolerance].
    #[arg(long, value_name = "T")]
    weld_tolerance: Option<f64>,
}

impl WeldFlags {
    /// Overrides the welding fields of `p` whose flag was given.
    pub fn apply(&self, p: &mut Params) {
        if self.weld {
            p.weld = Some(true);
        } else if self.no_weld {
            p.weld = Some(false);
        }
        if let Some(t) = self.weld_tolerance {
            p.weld_tolerance = t;
        }
    }
}

/// Parses a value by its serde name, so the flag accepts exactly what the
/// JSON parameters accept.
fn serde_name<T: DeserializeOwned>(s: &str) -> Result<T, String> {
    serde_json::from_value(serde_json::Value::String(s.to_owned())).map_err(|e| e.to_string())
}

impl ParamFlags {
    /// Overrides the fields of `p` whose flag was given.
    pub fn apply(&self, p: &mut Params) {
        fn set<T: Copy>(field: &mut T, flag: Option<T>) {
            if let Some(v) = flag {
                *field = v;
            }
        }
        set(&mut p.method, self.method);
        set(&mut p.initial_passes, self.initial_passes);
        set(&mut p.adaptive_passes, self.adaptive_passes);
        set(&mut p.adaptive_fit, self.adaptive_fit);
        set(&mut p.k_max, self.k_max);
        set(&mut p.max_fit_points, self.max_fit_points);
        set(&mut p.tolerance_h, self.tolerance_h);
        set(&mut p.tolerance_k, self.tolerance_k);
        set(&mut p.boundary, self.boundary);
        set(&mut p.quality.sharp_angle_deg, self.sharp_angle_deg);
        set(&mut p.baseline.iterations, self.iterations);
        set(&mut p.baseline.lambda, self.lambda);
        set(&mut p.baseline.mu, self.mu);
        if self.no_preserve_volume {
            p.preserve_volume = false;
        }
        if self.no_quality {
            p.quality.enabled = false;
        }
        self.weld.apply(p);
        if self.vertex_results {
            p.vertex_results = true;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_override_only_what_is_given() {
        let mut p = Params {
            k_max: 5,
            ..Params::default()
        };
        let flags = ParamFlags {
            method: Some(Method::Taubin),
            mu: Some(-0.6),
            no_quality: true,
            adaptive_fit: Some(AdaptiveFit::Quadric),
            ..ParamFlags::default()
        };
        flags.apply(&mut p);
        assert_eq!(p.adaptive_fit, AdaptiveFit::Quadric);
        assert_eq!(p.method, Method::Taubin);
        assert_eq!(p.baseline.mu, -0.6);
        assert!(!p.quality.enabled);
        assert_eq!(p.k_max, 5);
        assert_eq!(p.initial_passes, Params::default().initial_passes);
        assert!(p.preserve_volume);
        assert_eq!(p.weld, None);
        assert!(!p.vertex_results);
    }

    #[test]
    fn weld_flags_set_the_weld_fields() {
        let mut p = Params {
            weld: Some(true),
            ..Params::default()
        };
        let flags = ParamFlags {
            weld: WeldFlags {
                no_weld: true,
                weld_tolerance: Some(0.001),
                ..WeldFlags::default()
            },
            vertex_results: true,
            ..ParamFlags::default()
        };
        flags.apply(&mut p);
        assert_eq!(p.weld, Some(false));
        assert_eq!(p.weld_tolerance, 0.001);
        assert!(p.vertex_results);
        WeldFlags {
            weld: true,
            ..WeldFlags::default()
        }
        .apply(&mut p);
        assert_eq!(p.weld, Some(true));
        WeldFlags::default().apply(&mut p);
        assert_eq!(p.weld, Some(true), "no flag keeps the file's value");
    }

    #[test]
    fn names_are_the_json_names() {
        assert_eq!(serde_name::<Method>("wang-yu"), Ok(Method::WangYu));
        assert_eq!(
            serde_name::<BoundaryRule>("normal_only"),
            Ok(BoundaryRule::NormalOnly)
        );
        let e = serde_name::<Method>("wangyu").unwrap_err();
        assert!(e.contains("wang-yu") && e.contains("taubin"), "{e}");
    }
}
