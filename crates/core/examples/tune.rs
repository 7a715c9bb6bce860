//! Temporary tuning harness (lead's experiments).
use glam::DVec3;
use meshsmooth_core::pipeline::{NoProgress, movable_mask, wang_yu};
use meshsmooth_core::{Mesh, Params, Topology};
use std::collections::HashMap;
use std::sync::atomic::AtomicBool;

fn voxel_mesh(inside: impl Fn(DVec3) -> bool, lo: i32, hi: i32) -> Mesh {
    let idx = |i: i32, j: i32, k: i32| -> bool { inside(DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5)) };
    let mut verts: HashMap<(i32, i32, i32), u32> = HashMap::new();
    let mut pos = Vec::new();
    let mut faces = Vec::new();
    let mut vid = |c: (i32, i32, i32), pos: &mut Vec<DVec3>| -> u32 {
        *verts.entry(c).or_insert_with(|| {
            pos.push(DVec3::new(c.0 as f64, c.1 as f64, c.2 as f64));
            (pos.len() - 1) as u32
        })
    };
    for i in lo..hi {
        for j in lo..hi {
            for k in lo..hi {
                if !idx(i, j, k) {
                    continue;
                }
                // +x face
                let dirs = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)];
                for d in dirs {
                    if idx(i + d.0, j + d.1, k + d.2) {
                        continue;
                    }
                    // face corners on the side d of voxel (i,j,k), ccw seen from outside
                    let (a, b) = match d {
                        (1, 0, 0) | (-1, 0, 0) => ((0, 1, 0), (0, 0, 1)),
                        (0, 1, 0) | (0, -1, 0) => ((0, 0, 1), (1, 0, 0)),
                        _ => ((1, 0, 0), (0, 1, 0)),
                    };
                    let s = d.0 + d.1 + d.2;
                    let base = (
                        i + if d.0 > 0 { 1 } else { 0 },
                        j + if d.1 > 0 { 1 } else { 0 },
                        k + if d.2 > 0 { 1 } else { 0 },
                    );
                    let c0 = base;
                    let c1 = (base.0 + a.0, base.1 + a.1, base.2 + a.2);
                    let c2 = (base.0 + a.0 + b.0, base.1 + a.1 + b.1, base.2 + a.2 + b.2);
                    let c3 = (base.0 + b.0, base.1 + b.1, base.2 + b.2);
                    let mut f = [vid(c0, &mut pos), vid(c1, &mut pos), vid(c2, &mut pos), vid(c3, &mut pos)];
                    if s < 0 {
                        f.reverse();
                    }
                    faces.push(f);
                }
            }
        }
    }
    Mesh::from_polygons(pos, &faces).unwrap()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let shape = args.get(1).map(|s| s.as_str()).unwrap_or("s12");
    let params: Params = match args.get(2) {
        Some(j) => serde_json::from_str(j).unwrap(),
        None => Params::default(),
    };
    let c = DVec3::new(0.37, 0.21, 0.13);
    let (mesh, dist, truevol): (Mesh, Box<dyn Fn(DVec3) -> f64>, f64) = match shape {
        "s12" | "s40" | "s62" | "s110" => {
            let r: f64 = shape[1..].parse().unwrap();
            let m = voxel_mesh(|p| (p - c).length() < r, -(r as i32) - 3, r as i32 + 3);
            (m, Box::new(move |p| ((p - c).length() - r).abs()), 4.0 / 3.0 * std::f64::consts::PI * r * r * r)
        }
        "torus" => {
            let (big, small) = (20.0, 8.0);
            let d = move |p: DVec3| {
                let q = p - c;
                let rho = (q.x * q.x + q.y * q.y).sqrt();
                ((rho - big).powi(2) + q.z * q.z).sqrt() - small
            };
            let m = voxel_mesh(move |p| d(p) < 0.0, -31, 31);
            (m, Box::new(move |p| d(p).abs()), 2.0 * std::f64::consts::PI.powi(2) * big * small * small)
        }
        _ => panic!("shape"),
    };
    let topo = Topology::build(&mesh);
    let movable = movable_mask(&topo, params.boundary);
    let rms = |p: &[DVec3]| (p.iter().map(|&q| dist(q).powi(2)).sum::<f64>() / p.len() as f64).sqrt();
    let t = std::time::Instant::now();
    let r = wang_yu(&mesh, &topo, &movable, &params, &NoProgress, &AtomicBool::new(false)).unwrap();
    let el = t.elapsed();
    let mut hist = [0usize; 17];
    for &k in &r.ring {
        hist[k as usize] += 1;
    }
    let mut lc = [0usize; 4];
    for &l in &r.labels {
        lc[l as usize] += 1;
    }
    let vol = meshsmooth_core::mesh::signed_volume(&mesh, &r.adaptive);
    let mut lsmall = [0usize; 4];
    for (k, l) in r.ring.iter().zip(&r.labels) {
        if *k <= 4 {
            lsmall[*l as usize] += 1;
        }
    }
    eprintln!("labels of k<=4: {:?}", lsmall);
    let meank = r.ring.iter().map(|&k| k as f64).sum::<f64>() / r.ring.len() as f64;
    let small = r.ring.iter().filter(|&&k| k <= 4).count();
    println!(
        "{shape:6} n={:6} rms in {:.4} init {:.4} FINAL {:.4} vol {:+.3}% (in {:+.3}%) off {:+.4} meank {:.1} k<=4 {:5} t {:?} labels {:?}",
        mesh.num_vertices(),
        rms(mesh.positions()),
        rms(&r.initial),
        rms(&r.adaptive),
        (vol / truevol - 1.0) * 100.0,
        (mesh.signed_volume() / truevol - 1.0) * 100.0,
        r.volume_offset,
        meank,
        small,
        r.timings_ms.iter().map(|t| t.1 as u32).collect::<Vec<_>>(),
        lc
    );
}
