use super::*;
use crate::mesh::{Topology, VertexKind};
use glam::IVec3;
use std::collections::HashMap;
use std::time::Instant;

fn euler(mesh: &Mesh, topo: &Topology) -> i64 {
    mesh.num_vertices() as i64 - topo.edges().len() as i64 + mesh.num_faces() as i64
}

/// Every directed face side is matched by as many opposite sides: a closed,
/// consistently oriented surface (edges may have 4 faces).
fn assert_closed_and_oriented(mesh: &Mesh) {
    let mut sides = HashMap::new();
    for face in mesh.faces() {
        for j in 0..face.len() {
            *sides
                .entry((face[j], face[(j + 1) % face.len()]))
                .or_insert(0) += 1;
        }
    }
    for (&(a, b), &n) in &sides {
        assert_eq!(sides.get(&(b, a)), Some(&n), "side ({a}, {b}) unmatched");
    }
}

fn assert_manifold(mesh: &Mesh, topo: &Topology) {
    assert_eq!(topo.num_boundary_edges(), 0);
    assert_eq!(topo.num_non_manifold_edges(), 0);
    assert_eq!(topo.count_kind(VertexKind::Interior), mesh.num_vertices());
}

#[test]
fn voxel_sphere_is_closed_with_exact_volume() {
    let (sphere, mesh) = voxel_sphere(12.0);
    let topo = Topology::build(&mesh);
    assert_manifold(&mesh, &topo);
    assert_closed_and_oriented(&mesh);
    assert_eq!(euler(&mesh, &topo), 2);
    assert_eq!(topo.num_components(), 1);
    let inside = voxel_mask(&sphere).count_inside();
    assert_eq!(mesh.signed_volume(), inside as f64);
    let rel = (mesh.signed_volume() / sphere.volume() - 1.0).abs();
    assert!(rel < 0.01, "volume off by {rel}");
    // Every quad faces away from the centre.
    for f in 0..mesh.num_faces() {
        let face = mesh.face(f);
        let c = face
            .iter()
            .map(|&v| mesh.positions()[v as usize])
            .sum::<DVec3>()
            / 4.0;
        assert!(mesh.face_vector_area(f).dot(c - sphere.center) > 0.0);
    }
    // Each vertex is a corner of an inside and an outside voxel, whose
    // centres lie within sqrt(3)/2 of it on either side of the surface.
    let max = max_distance(&sphere, mesh.positions());
    assert!(max <= 0.75f64.sqrt(), "max distance {max}");
    assert!(rms_distance(&sphere, mesh.positions()) < max);
}

#[test]
fn mc_sphere_is_closed_manifold_and_outward() {
    let (sphere, mesh) = mc_sphere(12.0);
    let topo = Topology::build(&mesh);
    assert_manifold(&mesh, &topo);
    assert_closed_and_oriented(&mesh);
    assert_eq!(euler(&mesh, &topo), 2);
    assert_eq!(topo.num_components(), 1);
    let rel = (mesh.signed_volume() / sphere.volume() - 1.0).abs();
    assert!(rel < 0.03, "volume off by {rel}");
    // Vertices halve the segment between an inside and an outside centre.
    let max = max_distance(&sphere, mesh.positions());
    assert!(max <= 0.5 + 1e-12, "max distance {max}");
}

#[test]
fn tori_have_genus_one_and_ellipsoids_genus_zero() {
    for (mesh, chi, volume) in [
        {
            let (t, m) = voxel_torus(20.0, 8.0);
            (m, 0, t.volume())
        },
        {
            let (t, m) = mc_torus(20.0, 8.0);
            (m, 0, t.volume())
        },
        {
            let (e, m) = voxel_ellipsoid(30.0, 20.0, 12.0);
            (m, 2, e.volume())
        },
        {
            let (e, m) = mc_ellipsoid(30.0, 20.0, 12.0);
            (m, 2, e.volume())
        },
    ] {
        let topo = Topology::build(&mesh);
        assert_manifold(&mesh, &topo);
        assert_closed_and_oriented(&mesh);
        assert_eq!(euler(&mesh, &topo), chi);
        let rel = (mesh.signed_volume() / volume - 1.0).abs();
        assert!(rel < 0.03, "volume off by {rel}");
    }
}

#[test]
fn single_voxel_gives_cube_and_octahedron() {
    let mask = VoxelMask::from_fn(IVec3::new(-1, 2, 5), [1, 1, 1], |_, _, _| true);
    let cube = voxel_boundary_mesh(&mask);
    assert_eq!((cube.num_vertices(), cube.num_faces()), (8, 6));
    assert_eq!(cube.signed_volume(), 1.0);
    assert_eq!(cube.positions()[0], DVec3::new(-1.0, 2.0, 5.0));
    assert_closed_and_oriented(&cube);
    let octa = marching_cubes_mesh(&mask);
    assert_eq!((octa.num_vertices(), octa.num_faces()), (6, 8));
    assert!((octa.signed_volume() - 1.0 / 6.0).abs() < 1e-15);
    let centre = DVec3::new(-0.5, 2.5, 5.5);
    for p in octa.positions() {
        assert!((p.distance(centre) - 0.5).abs() < 1e-15);
    }
}

#[test]
fn edge_touching_voxels_stay_welded_in_quads_and_apart_in_mc() {
    let mask = VoxelMask::from_fn(IVec3::ZERO, [2, 2, 1], |i, j, _| i == j);
    let quads = voxel_boundary_mesh(&mask);
    assert_eq!(quads.num_vertices(), 14);
    let topo = Topology::build(&quads);
    assert_eq!(topo.num_non_manifold_edges(), 1);
    assert_eq!(topo.max_faces_per_edge(), 4);
    assert_eq!(quads.signed_volume(), 2.0);
    assert_closed_and_oriented(&quads);
    let mc = marching_cubes_mesh(&mask);
    let topo = Topology::build(&mc);
    assert_manifold(&mc, &topo);
    assert_eq!(topo.num_components(), 2);
    assert_eq!(euler(&mc, &topo), 4);
}

#[test]
fn every_cube_configuration_gives_a_closed_oriented_surface() {
    for case in 0..256usize {
        let mask = VoxelMask::from_fn(IVec3::ZERO, [2, 2, 2], |i, j, k| {
            case >> (i | j << 1 | k << 2) & 1 == 1
        });
        let inside = case.count_ones() as f64;
        let quads = voxel_boundary_mesh(&mask);
        assert_closed_and_oriented(&quads);
        assert_eq!(quads.signed_volume(), inside);
        let mc = marching_cubes_mesh(&mask);
        let topo = Topology::build(&mc);
        assert_closed_and_oriented(&mc);
        assert_manifold(&mc, &topo);
        // Each component of a closed surface bounding a 6-connected set of
        // at most 8 voxels in a 2x2x2 block is a sphere.
        assert_eq!(
            euler(&mc, &topo),
            2 * topo.num_components() as i64,
            "case {case}"
        );
        // The surface runs through the centre-to-centre segments, so it
        // encloses some but not all of the inside voxels' volume.
        let v = mc.signed_volume();
        assert!(case == 0 || (v > 0.0 && v < inside), "case {case}: {v}");
    }
}

#[test]
fn generation_is_deterministic() {
    assert_eq!(voxel_torus(9.0, 3.5).1, voxel_torus(9.0, 3.5).1);
    assert_eq!(mc_torus(9.0, 3.5).1, mc_torus(9.0, 3.5).1);
}

#[test]
fn sphere_and_torus_distances() {
    let s = Sphere {
        center: DVec3::new(1.0, 2.0, 3.0),
        radius: 4.0,
    };
    assert_eq!(s.distance(DVec3::new(1.0, 2.0, 3.0)), 4.0);
    assert_eq!(s.distance(DVec3::new(1.0, 2.0, 10.0)), 3.0);
    let c = DVec3::new(0.5, -1.0, 2.0);
    let t = Torus {
        center: c,
        major: 5.0,
        minor: 2.0,
    };
    assert_eq!(t.distance(c), 3.0);
    assert!(!t.inside(c));
    assert_eq!(t.distance(c + DVec3::new(0.0, 5.0, 0.0)), 2.0);
    assert!(t.inside(c + DVec3::new(0.0, 5.0, 0.0)));
    assert_eq!(t.distance(c + DVec3::new(-8.0, 0.0, 0.0)), 1.0);
    let on_axis = c + DVec3::new(0.0, 0.0, 12.0);
    assert!((t.distance(on_axis) - 11.0).abs() < 1e-12); // sqrt(25 + 144) - 2
    let (lo, hi) = t.bounds();
    assert_eq!(hi - lo, DVec3::new(14.0, 14.0, 4.0));
}

#[test]
fn ellipsoid_distance_on_axes() {
    let e = Ellipsoid {
        center: DVec3::new(0.3, 0.1, 0.2),
        semi_axes: DVec3::new(30.0, 20.0, 12.0),
    };
    let c = e.center;
    // The nearest point to the centre is an end of the shortest axis.
    assert!((e.distance(c) - 12.0).abs() < 1e-12);
    assert!((e.distance(c + DVec3::new(33.0, 0.0, 0.0)) - 3.0).abs() < 1e-12);
    assert!((e.distance(c + DVec3::new(0.0, -25.0, 0.0)) - 5.0).abs() < 1e-12);
    assert!((e.distance(c + DVec3::new(0.0, 0.0, 4.0)) - 8.0).abs() < 1e-12);
    // Deep inside along the longest axis the nearest point leaves the axis:
    // it is the evolute case, closer than the axis end 25 away.
    let p = c + DVec3::new(5.0, 0.0, 0.0);
    assert!(e.distance(p) < 12.0);
    // Surface points are at distance 0.
    let q = c + DVec3::new(30.0 * 0.6, 20.0 * 0.0, 12.0 * 0.8);
    assert!(e.distance(q) < 1e-12);
}

#[test]
fn ellipsoid_distance_matches_brute_force() {
    let axes = [
        DVec3::new(30.0, 20.0, 12.0),
        DVec3::new(5.0, 9.0, 9.0),
        DVec3::new(7.0, 7.0, 7.0),
        DVec3::new(1.0, 40.0, 3.0),
    ];
    // Dense surface sample for the brute-force minimum.
    let (nu, nv) = (720, 360);
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut rand = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    for semi_axes in axes {
        let e = Ellipsoid {
            center: DVec3::new(0.3, -0.1, 0.2),
            semi_axes,
        };
        let surface: Vec<DVec3> = (0..=nv)
            .flat_map(|j| {
                let v = std::f64::consts::PI * j as f64 / nv as f64;
                (0..nu).map(move |i| {
                    let u = std::f64::consts::TAU * i as f64 / nu as f64;
                    e.center + semi_axes * DVec3::new(v.sin() * u.cos(), v.sin() * u.sin(), v.cos())
                })
            })
            .collect();
        let spacing = semi_axes.max_element() * std::f64::consts::PI / nv as f64;
        for n in 0..60 {
            let scale = if n % 2 == 0 { 0.9 } else { 1.6 };
            let mut p = e.center
                + scale
                    * semi_axes
                    * DVec3::new(rand() * 2.0 - 1.0, rand() * 2.0 - 1.0, rand() * 2.0 - 1.0);
            if n % 5 == 0 {
                p.z = e.center.z; // exercise the plane cases
            }
            let x = e.closest_point(p);
            let on = ((x - e.center) / semi_axes).length_squared();
            assert!(
                (on - 1.0).abs() < 1e-9,
                "closest point off the surface: {on}"
            );
            let d = e.distance(p);
            let brute = surface
                .iter()
                .map(|s| s.distance(p))
                .fold(f64::INFINITY, f64::min);
            assert!(d <= brute + 1e-9, "{semi_axes} {p}: {d} > brute {brute}");
            assert!(
                d >= brute - spacing,
                "{semi_axes} {p}: {d} << brute {brute}"
            );
        }
    }
}

#[test]
fn distance_summaries() {
    let s = Sphere {
        center: DVec3::ZERO,
        radius: 1.0,
    };
    let pts = [DVec3::new(2.0, 0.0, 0.0), DVec3::new(0.0, 0.0, 0.0)];
    assert_eq!(rms_distance(&s, &pts), 1.0);
    assert_eq!(max_distance(&s, &pts), 1.0);
    let pts = [DVec3::new(3.0, 0.0, 0.0), DVec3::new(0.0, 1.0, 0.0)];
    assert_eq!(rms_distance(&s, &pts), 2.0f64.sqrt());
    assert_eq!(max_distance(&s, &pts), 2.0);
    assert_eq!(rms_distance(&s, &[]), 0.0);
    assert_eq!(max_distance(&s, &[]), 0.0);
}

/// Sizes and timings of large spheres:
/// `cargo test --release -p meshsmooth-core -- --ignored shapes_sizes --nocapture`.
#[test]
#[ignore]
fn shapes_sizes() {
    for r in [62.0, 110.0, 231.0] {
        let t = Instant::now();
        let mask = voxel_mask(&Sphere {
            center: CENTER_OFFSET,
            radius: r,
        });
        println!("mask {:?} in {:.2?}", mask.dims(), t.elapsed());
        let t = Instant::now();
        let (s, m) = voxel_sphere(r);
        let tv = t.elapsed();
        let t = Instant::now();
        let (_, mc) = mc_sphere(r);
        let tm = t.elapsed();
        println!(
            "sphere r={r}: voxel {} vertices {} quads in {tv:.2?} (vol err {:.2e}); \
             mc {} vertices {} triangles in {tm:.2?} (vol err {:.2e})",
            m.num_vertices(),
            m.num_faces(),
            m.signed_volume() / s.volume() - 1.0,
            mc.num_vertices(),
            mc.num_faces(),
            mc.signed_volume() / s.volume() - 1.0,
        );
    }
}

/// Deterministic pseudo-random masks: sparse, dense, and blobs with long
/// runs, in grids of awkward sizes.
fn random_masks() -> Vec<VoxelMask> {
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut rand = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut masks = Vec::new();
    for dims in [[9, 7, 6], [1, 5, 3], [13, 2, 11], [17, 15, 12]] {
        for density in [0.15, 0.5, 0.85] {
            let bits: Vec<bool> = (0..dims[0] * dims[1] * dims[2])
                .map(|_| rand() < density)
                .collect();
            masks.push(VoxelMask::from_fn(IVec3::new(-3, 1, 0), dims, |i, j, k| {
                bits[(k * dims[1] + j) * dims[0] + i]
            }));
        }
        let c = DVec3::new(rand(), rand(), rand())
            * DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
        let r = 0.4 * dims.iter().copied().min().unwrap_or(1) as f64 + 1.0;
        masks.push(VoxelMask::from_fn(IVec3::ZERO, dims, |i, j, k| {
            let p = DVec3::new(i as f64, j as f64, k as f64);
            p.distance(c) < r || (i + 2 * j) % 7 == 0
        }));
    }
    masks
}

#[test]
fn fast_voxel_boundary_matches_brute_force() {
    use std::collections::BTreeMap;
    for mask in random_masks() {
        let [nx, ny, nz] = mask.dims().map(|n| n as i64);
        let mut quads: Vec<[[i64; 3]; 4]> = Vec::new();
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    if !mask.get(i, j, k) {
                        continue;
                    }
                    // -x, +x, -y, +y, -z, +z with corners anticlockwise
                    // seen from outside.
                    let sides: [([i64; 3], [[i64; 3]; 4]); 6] = [
                        ([-1, 0, 0], [[0, 0, 0], [0, 0, 1], [0, 1, 1], [0, 1, 0]]),
                        ([1, 0, 0], [[1, 0, 0], [1, 1, 0], [1, 1, 1], [1, 0, 1]]),
                        ([0, -1, 0], [[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]]),
                        ([0, 1, 0], [[0, 1, 0], [0, 1, 1], [1, 1, 1], [1, 1, 0]]),
                        ([0, 0, -1], [[0, 0, 0], [0, 1, 0], [1, 1, 0], [1, 0, 0]]),
                        ([0, 0, 1], [[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]),
                    ];
                    for (d, corners) in sides {
                        if !mask.get(i + d[0], j + d[1], k + d[2]) {
                            quads.push(corners.map(|c| [i + c[0], j + c[1], k + c[2]]));
                        }
                    }
                }
            }
        }
        let mut ids = BTreeMap::new();
        for q in &quads {
            for c in q {
                ids.insert([c[2], c[1], c[0]], 0u32);
            }
        }
        for (n, id) in ids.values_mut().enumerate() {
            *id = n as u32;
        }
        let o = mask.origin().as_dvec3();
        let positions = ids
            .keys()
            .map(|c| o + DVec3::new(c[2] as f64, c[1] as f64, c[0] as f64))
            .collect();
        let faces: Vec<[u32; 4]> = quads
            .iter()
            .map(|q| q.map(|c| ids[&[c[2], c[1], c[0]]]))
            .collect();
        let expected = Mesh::from_polygons(positions, &faces).unwrap();
        assert_eq!(voxel_boundary_mesh(&mask), expected);
    }
}

#[test]
fn fast_voxel_mask_matches_per_voxel_tests() {
    let shapes: Vec<Box<dyn Shape>> = vec![
        Box::new(Sphere {
            center: DVec3::new(0.5, 0.5, 0.5),
            radius: 9.0,
        }),
        Box::new(Sphere {
            center: CENTER_OFFSET,
            radius: 17.3,
        }),
        Box::new(torus(13.0, 4.5)),
        Box::new(ellipsoid(21.0, 9.0, 5.5)),
    ];
    for shape in shapes {
        let mask = voxel_mask(shape.as_ref());
        let o = mask.origin();
        let brute = VoxelMask::from_fn(o, mask.dims(), |i, j, k| {
            shape.inside(mask.voxel_center(i as i64, j as i64, k as i64))
        });
        assert_eq!(mask, brute);
        let (lo, hi) = shape.bounds();
        assert!(o.as_dvec3().cmple(lo - 2.0).all());
        let top = o.as_dvec3() + DVec3::from(mask.dims().map(|n| n as f64));
        assert!(top.cmpge(hi + 2.0).all());
    }
}
