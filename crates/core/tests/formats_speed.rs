//! Read and write throughput of every format on a generated 1000 x 1000
//! vertex triangle grid (1M vertices, 2M triangles). Prints figures; asserts
//! only that what is read back is the mesh written. Run with
//! `cargo test --release -p meshsmooth-core --test formats_speed -- --ignored --nocapture`.
//! With `MESHSMOOTH_BENCH_SMOOTH=1` it also times the default smoothing of
//! the same mesh, to compare.

use glam::DVec3;
use meshsmooth_core::io::{self, Format, ReadLimits};
use meshsmooth_core::{Mesh, NoProgress, Params};
use std::sync::atomic::AtomicBool;
use std::time::Instant;

fn grid(n: usize) -> Mesh {
    let mut positions = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f64 * 0.123456789, j as f64 * 1.000001);
            positions.push(DVec3::new(x, y, (x * 0.37).sin() * (y * 0.21).cos()));
        }
    }
    let mut faces = Vec::with_capacity(2 * (n - 1) * (n - 1));
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let a = (i * n + j) as u32;
            let n = n as u32;
            faces.push([a, a + n, a + n + 1]);
            faces.push([a, a + n + 1, a + 1]);
        }
    }
    Mesh::from_polygons(positions, &faces).unwrap()
}

/// Best of three runs of `f`, in seconds.
fn best<T>(mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut last = None;
    for _ in 0..3 {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64());
        last = Some(r);
    }
    (best, last.unwrap())
}

#[test]
#[ignore = "prints throughput figures; run in release"]
fn read_and_write_throughput() {
    let mesh = grid(1000);
    let mut obj = Vec::new();
    io::obj::write_obj_plain(&mesh, mesh.positions(), &mut obj).unwrap();
    let source = io::read(&obj, Format::Obj, &ReadLimits::default()).unwrap();
    println!(
        "{} vertices, {} triangles; best of 3 runs",
        mesh.num_vertices(),
        mesh.num_faces()
    );
    println!(
        "format      MB   read s  read MB/s  write s  write MB/s  (read includes welding for GLB and STL)"
    );
    let mut total = Vec::new();
    for format in [
        Format::Obj,
        Format::Glb,
        Format::Ply,
        Format::Stl,
        Format::Off,
    ] {
        let bytes = io::write(&source, source.mesh.positions(), format).unwrap();
        let mb = bytes.len() as f64 / 1e6;
        let (read, doc) = best(|| io::read(&bytes, format, &ReadLimits::default()).unwrap());
        // STL comes back welded in first-use order: compare counts only.
        assert_eq!(doc.mesh.num_vertices(), mesh.num_vertices(), "{format}");
        assert_eq!(doc.mesh.num_faces(), mesh.num_faces(), "{format}");
        if format != Format::Stl {
            assert!(doc.mesh.face_vertices() == mesh.face_vertices(), "{format}");
            let close = doc.mesh.positions().iter().zip(mesh.positions());
            assert!(
                close
                    .into_iter()
                    .all(|(p, q)| (*p - *q).abs().max_element() < 1e-4)
            );
        }
        let (write, out) = best(|| io::write(&doc, doc.mesh.positions(), format).unwrap());
        assert_eq!(out.len(), bytes.len(), "{format}");
        println!(
            "{:<6} {:>7.1} {:>8.3} {:>10.0} {:>8.3} {:>11.0}",
            format.name(),
            mb,
            read,
            mb / read,
            write,
            mb / write
        );
        total.push((format, read + write));
    }
    if std::env::var_os("MESHSMOOTH_BENCH_SMOOTH").is_some() {
        let t = Instant::now();
        meshsmooth_core::run(
            &mesh,
            &Params::default(),
            &NoProgress,
            &AtomicBool::new(false),
        )
        .unwrap();
        let smooth = t.elapsed().as_secs_f64();
        println!("default smoothing: {smooth:.2} s");
        for (format, io_time) in total {
            println!(
                "{format}: read + write = {:.1}% of the smoothing time",
                100.0 * io_time / smooth
            );
        }
    }
}
