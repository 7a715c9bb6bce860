//! The volume a mesh encloses, measured the same way wherever its file puts
//! the origin.
//!
//! The divergence theorem sums, over the faces, the cones from one apex.
//! A surface whose faces close up (every edge shared by an even number of
//! faces, wound alike) encloses the same volume from any apex. One with
//! edges of an odd number of faces does not: a neuron's junctions, where
//! three sheets meet at an edge, or a fin left on a segmentation's surface.
//! There the sum depends on the apex, and an apex fixed at the origin makes
//! it depend on where the file puts its origin. Every volume the smoothing
//! restores and the report states is therefore taken from apexes that move
//! with the mesh: each connected component's centroid at the input
//! positions ([`VolumeApexes`]). Near the surface, the apexes also keep the
//! digits that far coordinates would cancel.

use super::{Mesh, Topology, cone_volume6_about, sum_over_face_chunks};
use glam::DVec3;

/// Each connected component's apex, the mean of its input positions, and
/// each vertex's component: the cones of every volume of a run are taken
/// from them (module docs).
#[derive(Debug, Clone)]
pub struct VolumeApexes {
    /// Each vertex's connected component ([`Topology::component_ids`]).
    component: Vec<u32>,
    /// Each component's apex.
    apex: Vec<DVec3>,
}

impl VolumeApexes {
    /// The apexes of `topo`'s components at the `input` positions (one per
    /// vertex).
    ///
    /// Panics if `input` does not have one position per vertex (a caller
    /// bug, not a user input).
    pub fn new(topo: &Topology, input: &[DVec3]) -> Self {
        let (component, count) = topo.component_ids();
        assert_eq!(component.len(), input.len(), "one position per vertex");
        let mut sums = vec![(DVec3::ZERO, 0u32); count];
        for (&c, &p) in component.iter().zip(input) {
            let (sum, n) = &mut sums[c as usize];
            *sum += p;
            *n += 1;
        }
        VolumeApexes {
            component: component.to_vec(),
            apex: sums
                .into_iter()
                .map(|(sum, n)| sum / f64::from(n.max(1)))
                .collect(),
        }
    }

    /// Each vertex's connected component.
    pub fn component(&self) -> &[u32] {
        &self.component
    }

    /// The number of connected components.
    pub fn count(&self) -> usize {
        self.apex.len()
    }

    /// Six times the signed volume of the cone over `face` at `positions`
    /// from the apex of its first corner's component.
    #[inline]
    pub fn cone_volume6(&self, face: &[u32], positions: &[DVec3]) -> f64 {
        let apex = face
            .first()
            .and_then(|&v| self.component.get(v as usize))
            .and_then(|&c| self.apex.get(c as usize))
            .copied()
            .unwrap_or_default();
        cone_volume6_about(face, positions, apex)
    }

    /// The signed volume `mesh` encloses with its vertices at `positions`:
    /// the same bits whatever the thread count.
    pub fn volume(&self, mesh: &Mesh, positions: &[DVec3]) -> f64 {
        sum_over_face_chunks(mesh.num_faces(), |faces| {
            faces
                .map(|f| self.cone_volume6(mesh.face(f), positions))
                .sum::<f64>()
        }) / 6.0
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::shapes::{VoxelMask, label_complex, voxel_sphere};
    use glam::IVec3;

    /// A voxel ball of `radius` about the origin as a closed two-label
    /// complex ([`label_complex`]): its two halves, `x < 0` and `x > 0`,
    /// share the wall at `x = 0`, whose rim edges have three faces each (as
    /// at a neuron's junctions); its positions moved by `shift`.
    pub(crate) fn walled_sphere(radius: f64, shift: DVec3) -> Mesh {
        let n = radius.ceil() as i32 + 1;
        let side = 2 * n as usize;
        let half = |left: bool| {
            VoxelMask::from_fn(IVec3::splat(-n), [side, side, side], |i, j, k| {
                let c = DVec3::new(i as f64, j as f64, k as f64) + 0.5 - f64::from(n);
                c.length() < radius && (c.x < 0.0) == left
            })
        };
        let mut walled = label_complex(&[half(true), half(false)]);
        for p in walled.positions_mut() {
            *p += shift;
        }
        walled
    }

    #[test]
    fn a_closed_surface_encloses_its_volume_from_any_apex() {
        let (_, sphere) = voxel_sphere(4.0);
        let topo = Topology::build(&sphere);
        let apexes = VolumeApexes::new(&topo, sphere.positions());
        let v = apexes.volume(&sphere, sphere.positions());
        assert!((v - sphere.signed_volume()).abs() < 1e-9 * v, "{v}");
    }

    #[test]
    fn a_walled_surface_measures_alike_wherever_the_origin_lies() {
        let volume = |shift: DVec3| {
            let mesh = walled_sphere(4.0, shift);
            let topo = Topology::build(&mesh);
            assert_eq!(topo.num_boundary_edges(), 0);
            (
                VolumeApexes::new(&topo, mesh.positions()).volume(&mesh, mesh.positions()),
                mesh.signed_volume(),
            )
        };
        let (here, from_origin_here) = volume(DVec3::ZERO);
        let (there, from_origin_there) = volume(DVec3::new(400.0, -250.0, 120.0));
        assert!((here - there).abs() < 1e-9 * here, "{here} vs {there}");
        // The origin's cones see the shift: the measure above must not.
        assert!(
            (from_origin_here - from_origin_there).abs() > 1.0,
            "{from_origin_here} vs {from_origin_there}"
        );
    }
}
