//! Work per upload is bounded by its size: a vertex of huge valence (a fan)
//! or a face of huge arity is refused before any stage whose cost grows
//! with their square, with a typed error naming the vertex or face.

use meshsmooth_core::error::ErrorCode;
use meshsmooth_core::pipeline::{MAX_FACE_CORNERS, MAX_VALENCE, measure};
use meshsmooth_core::shapes::{big_face, fan};
use meshsmooth_core::{Mesh, NoProgress, Params, run};
use std::sync::atomic::AtomicBool;

fn code_of(mesh: &Mesh) -> Option<ErrorCode> {
    run(
        mesh,
        &Params::default(),
        &NoProgress,
        &AtomicBool::new(false),
    )
    .err()
    .map(|e| e.code())
}

#[test]
fn a_wide_fan_is_refused_and_a_narrow_one_smooths() {
    let wide = fan(20 * MAX_VALENCE);
    assert_eq!(code_of(&wide), Some(ErrorCode::VertexValenceTooHigh));
    let err = run(
        &wide,
        &Params::default(),
        &NoProgress,
        &AtomicBool::new(false),
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("vertex 0 has 20000 edges"),
        "{err}"
    );
    assert_eq!(code_of(&fan(MAX_VALENCE)), None);
    // Measuring it still works, without the curvature, and says why.
    let report = measure(&wide, &Params::default());
    assert!(report.stages.input.unwrap().curvature_variation.is_none());
    assert!(
        report.warnings[0].contains("20000 edges"),
        "{:?}",
        report.warnings
    );
}

#[test]
fn a_huge_polygon_is_refused() {
    let huge = big_face(20 * MAX_FACE_CORNERS);
    assert_eq!(code_of(&huge), Some(ErrorCode::FaceTooLarge));
    let err = run(
        &huge,
        &Params::default(),
        &NoProgress,
        &AtomicBool::new(false),
    )
    .unwrap_err();
    assert!(
        err.to_string().contains("face 0 has 20000 corners"),
        "{err}"
    );
}
