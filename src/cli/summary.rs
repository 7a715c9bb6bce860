//! Short human-readable summaries on a terminal: after `smooth` (stderr) and
//! for `report` without `--json` (stdout).

use meshsmooth_core::Mesh;
use meshsmooth_core::report::{AngleStats, MeshStatistics, QualityReport, StageMeasures};
use std::io::{self, Write};
use std::time::Duration;

/// The end-of-run summary: stage timings, displacement, angles, curvature
/// variation, volume.
pub fn smoothed(
    w: &mut impl Write,
    mesh: &Mesh,
    r: &QualityReport,
    elapsed: Duration,
) -> io::Result<()> {
    let method = serde_json::to_value(r.reproducibility.method)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default();
    writeln!(
        w,
        "smoothed {} vertices, {} faces with {method} in {:.2} s",
        mesh.num_vertices(),
        mesh.num_faces(),
        elapsed.as_secs_f64()
    )?;
    if !r.timings.is_empty() {
        let stages: Vec<String> = r
            .timings
            .iter()
            .map(|t| format!("{} {:.0} ms", t.stage, t.ms))
            .collect();
        writeln!(w, "  stages    {}", stages.join(", "))?;
    }
    let (Some(input), Some(output)) = (&r.stages.input, &r.stages.final_stage) else {
        return Ok(());
    };
    let d = &output.displacement;
    writeln!(
        w,
        "  moved     rms {}, max {} (mean edge length {})",
        sig(d.rms),
        sig(d.max),
        sig(input.mean_edge_length)
    )?;
    if let Some(wy) = &r.wang_yu {
        // The grid decides the fidelity bound's shape; off any grid, the
        // input's noise decides how far across its surface a vertex moved.
        let grid = serde_json::to_value(wy.input_grid)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_default();
        match wy.input_noise {
            Some(noise) => writeln!(
                w,
                "  grid      {grid}; input noise {} mean edge lengths",
                sig(noise)
            )?,
            None => writeln!(w, "  grid      {grid}")?,
        }
    }
    writeln!(
        w,
        "  angles    {} (input {})",
        angles(&output.triangle_angles),
        angles(&input.triangle_angles)
    )?;
    if let (Some(a), Some(b)) = (input.curvature_variation, output.curvature_variation) {
        writeln!(
            w,
            "  curvature {} (input {}): mean variation times the mean edge length",
            sig(b.mean_scaled),
            sig(a.mean_scaled)
        )?;
    }
    if let Some(change) = output.volume.and_then(|v| v.relative_change) {
        writeln!(w, "  volume    {:+.3} %", change * 100.0)?;
    }
    writeln!(
        w,
        "  quality   inverted faces {}, twisted quads {} (input {}), short edges {} (input {})",
        output.inverted_faces,
        output.twisted_quads,
        input.twisted_quads,
        output.short_edges,
        input.short_edges
    )?;
    for warning in &r.warnings {
        writeln!(w, "  warning   {warning}")?;
    }
    Ok(())
}

/// The table printed by `meshsmooth report`.
pub fn measured(w: &mut impl Write, m: &MeshStatistics, s: &StageMeasures) -> io::Result<()> {
    writeln!(
        w,
        "faces            {} ({} triangles, {} quads, {} larger polygons; up to {} corners)",
        m.faces, m.triangles, m.quads, m.polygons, m.max_face_arity
    )?;
    writeln!(
        w,
        "vertices         {} ({} boundary, {} non-manifold, {} isolated)",
        m.vertices, m.boundary_vertices, m.non_manifold_vertices, m.isolated_vertices
    )?;
    writeln!(
        w,
        "edges            {} ({} boundary, {} non-manifold, up to {} faces per edge)",
        m.edges, m.boundary_edges, m.non_manifold_edges, m.max_faces_per_edge
    )?;
    writeln!(
        w,
        "components       {}; {}; {} degenerate faces",
        m.components,
        if m.closed { "closed" } else { "open" },
        m.degenerate_faces
    )?;
    writeln!(w, "winding          {}", winding(m))?;
    if m.touching_bodies > 0 {
        writeln!(
            w,
            "bodies           {} touching face to face ({} shared faces), welded apart",
            m.touching_bodies, m.shared_faces
        )?;
    }
    if m.regions > 0 {
        writeln!(
            w,
            "regions          {} sharing {} wall faces (a multi-label complex), smoothed one by one",
            m.regions, m.region_walls
        )?;
    }
    writeln!(w, "mean edge length {}", sig(s.mean_edge_length))?;
    if let Some(c) = s.curvature_variation {
        writeln!(
            w,
            "curvature var.   {} ({} times the mean edge length)",
            sig(c.mean),
            sig(c.mean_scaled)
        )?;
    }
    writeln!(
        w,
        "short edges      {} (shorter than {})",
        s.short_edges,
        sig(s.short_edge_threshold)
    )?;
    writeln!(w, "twisted quads    {}", s.twisted_quads)?;
    if let Some(v) = s.volume {
        writeln!(w, "volume           {}", sig(v.volume))?;
    }
    writeln!(w, "triangle angles  {}", angles(&s.triangle_angles))?;
    writeln!(w, "polygon angles   {}", angles(&s.polygon_angles))
}

/// `x` with about 6 significant digits, in plain notation.
fn sig(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let decimals = (5 - x.abs().log10().floor() as i32).clamp(0, 12) as usize;
    format!("{x:.decimals$}")
}

/// `min 31.2°, max 118.0°, < 20°: 0, < 30°: 4, > 150°: 0`.
fn angles(a: &AngleStats) -> String {
    let deg = |x: Option<f64>| x.map_or("-".to_owned(), |x| format!("{x:.1}°"));
    format!(
        "min {}, max {}, < 20°: {}, < 30°: {}, > 150°: {}",
        deg(a.min_deg),
        deg(a.max_deg),
        a.below_20,
        a.below_30,
        a.above_150
    )
}

/// How the faces were wound: what the measures (and a smoothing run) turned
/// before reading them.
fn winding(m: &MeshStatistics) -> String {
    let mut parts = Vec::new();
    if m.inside_out {
        parts.push("inside out (measured turned)".to_owned());
    }
    if m.inside_out_bodies > 0 {
        parts.push(format!(
            "{} of its closed parts inside out beside outward ones ({} faces, measured turned)",
            m.inside_out_bodies, m.inside_out_body_faces
        ));
    }
    let against = m.faces_wound_against();
    if against > 0 {
        parts.push(format!(
            "{against} faces against their neighbours (measured turned)"
        ));
    }
    if m.orientation_seams > 0 {
        parts.push(format!(
            "{} seams no turn removes (not orientable)",
            m.orientation_seams
        ));
    }
    if parts.is_empty() {
        "consistent, outward".to_owned()
    } else {
        parts.join("; ")
    }
}

#[cfg(test)]
mod tests {
    use super::sig;

    #[test]
    fn six_significant_digits() {
        assert_eq!(sig(115.87635131001794), "115.876");
        assert_eq!(sig(1281193243.767616), "1281193244");
        assert_eq!(sig(0.000123456789), "0.000123457");
        assert_eq!(sig(0.0), "0");
    }
}
