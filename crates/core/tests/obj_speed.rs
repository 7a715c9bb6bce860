//! OBJ read/write throughput on a generated 1000 x 1000 vertex quad grid
//! (1M vertices, about 1M quads, about 70 MB). Prints figures; asserts only
//! correctness. Run with
//! `cargo test --release -p meshsmooth-core --test obj_speed -- --ignored --nocapture`.

use meshsmooth_core::io::ReadLimits;
use meshsmooth_core::io::obj::{read_obj, write_obj, write_obj_plain};
use std::fmt::Write;
use std::time::Instant;

fn grid_obj(n: usize) -> Vec<u8> {
    let mut s = String::with_capacity(n * n * 72);
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f64 * 0.123456789, j as f64 * 1.000001);
            let _ = writeln!(s, "v {x} {y} {}", (x * 0.37).sin() * (y * 0.21).cos());
        }
    }
    for i in 0..n - 1 {
        for j in 0..n - 1 {
            let a = i * n + j + 1;
            let _ = writeln!(s, "f {a} {} {} {}", a + n, a + n + 1, a + 1);
        }
    }
    s.into_bytes()
}

#[test]
#[ignore = "prints throughput figures; run in release"]
fn obj_throughput() {
    let bytes = grid_obj(1000);
    let mb = bytes.len() as f64 / 1e6;
    for _ in 0..3 {
        let t = Instant::now();
        let (mesh, src) = read_obj(&bytes, &ReadLimits::default()).unwrap();
        let read = t.elapsed().as_secs_f64();

        let t = Instant::now();
        let mut out = Vec::new();
        write_obj(&src, mesh.positions(), &mut out).unwrap();
        let write = t.elapsed().as_secs_f64();

        let t = Instant::now();
        let mut plain = Vec::new();
        write_obj_plain(&mesh, mesh.positions(), &mut plain).unwrap();
        let write_plain = t.elapsed().as_secs_f64();

        assert_eq!(read_obj(&out, &ReadLimits::default()).unwrap().0, mesh);
        assert_eq!(read_obj(&plain, &ReadLimits::default()).unwrap().0, mesh);
        println!(
            "{mb:.1} MB, {} vertices, {} faces: read {read:.3} s ({:.0} MB/s), \
             write back {write:.3} s, write plain {write_plain:.3} s",
            mesh.num_vertices(),
            mesh.num_faces(),
            mb / read
        );
    }
}
