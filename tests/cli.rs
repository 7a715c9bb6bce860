//! End-to-end tests of `meshsmooth smooth` and `meshsmooth report`: the
//! real binary on meshes generated here, checked for what a shell user sees
//! (files, stdout, exit codes, messages).

use meshsmooth_core::io::obj::write_obj_plain;
use meshsmooth_core::io::{self, Format, ReadLimits};
use meshsmooth_core::report::sha256_hex;
use meshsmooth_core::{Mesh, shapes};
use serde_json::Value;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn meshsmooth(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_meshsmooth"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("the binary runs")
}

fn meshsmooth_with_stdin(args: &[&str], stdin: &[u8]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_meshsmooth"))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the binary runs");
    let mut pipe = child.stdin.take().unwrap();
    pipe.write_all(stdin).unwrap();
    drop(pipe);
    child.wait_with_output().unwrap()
}

/// An empty directory for one test.
fn scratch(test: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("cli")
        .join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn path_str(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The voxel-boundary quad mesh of a ball of radius 4 (voxel units) as OBJ,
/// with a comment, an object name and a texture coordinate that must
/// survive smoothing.
fn sphere_obj() -> (Mesh, Vec<u8>) {
    let (_, mesh) = shapes::voxel_sphere(4.0);
    let mut bytes = b"# voxel ball\no ball\nvt 0.5 0.5\n".to_vec();
    write_obj_plain(&mesh, mesh.positions(), &mut bytes).unwrap();
    (mesh, bytes)
}

fn read_mesh(bytes: &[u8]) -> Mesh {
    io::read(bytes, Format::Obj, &ReadLimits::default())
        .expect("the output is a valid OBJ")
        .mesh
}

fn faces(mesh: &Mesh) -> Vec<Vec<u32>> {
    mesh.faces().map(<[u32]>::to_vec).collect()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn code(out: &Output) -> i32 {
    out.status.code().expect("exited normally")
}

/// Writes the sphere to `dir/in.obj` and returns its path and content.
fn sphere_file(dir: &Path) -> (PathBuf, Mesh, Vec<u8>) {
    let (mesh, bytes) = sphere_obj();
    let path = dir.join("in.obj");
    std::fs::write(&path, &bytes).unwrap();
    (path, mesh, bytes)
}

#[test]
fn smooth_writes_the_mesh_and_a_report() {
    let dir = scratch("smooth_writes_the_mesh_and_a_report");
    let (input, mesh, in_bytes) = sphere_file(&dir);
    let (output, report) = (dir.join("out.obj"), dir.join("report.json"));
    let out = meshsmooth(&[
        "smooth",
        path_str(&input),
        "-o",
        path_str(&output),
        "--report",
        path_str(&report),
        "--k-max",
        "5",
    ]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    assert!(
        out.stdout.is_empty(),
        "nothing on stdout when writing files"
    );

    let out_bytes = std::fs::read(&output).unwrap();
    let smoothed = read_mesh(&out_bytes);
    assert_eq!(faces(&smoothed), faces(&mesh));
    assert!(smoothed.positions().iter().all(|p| p.is_finite()));
    assert!(
        smoothed
            .positions()
            .iter()
            .zip(mesh.positions())
            .any(|(a, b)| a != b),
        "smoothing moved no vertex"
    );
    let text = String::from_utf8(out_bytes.clone()).unwrap();
    assert!(
        text.starts_with("# voxel ball\no ball\nvt 0.5 0.5\nv "),
        "{}",
        &text[..60]
    );

    let report: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let repro = &report["reproducibility"];
    assert_eq!(repro["input_sha256"], sha256_hex(&in_bytes));
    assert_eq!(repro["output_sha256"], sha256_hex(&out_bytes));
    assert_eq!(repro["params"]["k_max"], 5);
    assert_eq!(repro["params"]["method"], "wang-yu");
}

#[test]
fn stdin_to_stdout_matches_files_and_threads_do_not_change_the_output() {
    let dir = scratch("stdin_to_stdout");
    let (input, _, in_bytes) = sphere_file(&dir);
    let piped = meshsmooth_with_stdin(&["smooth", "-", "-o", "-", "--threads", "1"], &in_bytes);
    assert_eq!(code(&piped), 0, "{}", stderr(&piped));
    assert!(!piped.stdout.is_empty());

    let output = dir.join("out.obj");
    let filed = meshsmooth(&[
        "smooth",
        path_str(&input),
        "-o",
        path_str(&output),
        "--threads",
        "2",
        "--quiet",
    ]);
    assert_eq!(code(&filed), 0, "{}", stderr(&filed));
    assert!(filed.stderr.is_empty(), "--quiet prints nothing");
    assert_eq!(std::fs::read(&output).unwrap(), piped.stdout);
}

#[test]
fn parameter_file_and_flags_combine() {
    let dir = scratch("parameter_file_and_flags_combine");
    let (input, mesh, _) = sphere_file(&dir);
    let params = dir.join("params.json");
    std::fs::write(
        &params,
        r#"{"method": "laplacian", "baseline": {"iterations": 3, "lambda": 0.3}}"#,
    )
    .unwrap();
    let (output, report) = (dir.join("out.obj"), dir.join("report.json"));
    let out = meshsmooth(&[
        "smooth",
        path_str(&input),
        "-o",
        path_str(&output),
        "--params",
        path_str(&params),
        "--iterations",
        "5",
        "--report",
        path_str(&report),
    ]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let report: Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let used = &report["reproducibility"]["params"];
    assert_eq!(used["method"], "laplacian");
    assert_eq!(used["baseline"]["iterations"], 5);
    assert_eq!(used["baseline"]["lambda"], 0.3);
    let laplacian = read_mesh(&std::fs::read(&output).unwrap());
    assert_eq!(faces(&laplacian), faces(&mesh));

    let taubin = meshsmooth(&[
        "smooth",
        path_str(&input),
        "-o",
        "-",
        "--method",
        "taubin",
        "-q",
    ]);
    assert_eq!(code(&taubin), 0, "{}", stderr(&taubin));
    assert_ne!(read_mesh(&taubin.stdout).positions(), laplacian.positions());
}

#[test]
fn bad_parameters_exit_2_and_name_the_problem() {
    let dir = scratch("bad_parameters_exit_2");
    let (input, _, _) = sphere_file(&dir);
    let output = dir.join("out.obj");
    let params = dir.join("params.json");
    std::fs::write(&params, "{\n  \"k_maks\": 3\n}").unwrap();
    let common = ["smooth", path_str(&input), "-o", path_str(&output)];

    let out = meshsmooth(&[&common[..], &["--params", path_str(&params)]].concat());
    assert_eq!(code(&out), 2);
    let msg = stderr(&out);
    assert!(
        msg.contains("params.json") && msg.contains("k_maks") && msg.contains("line 2"),
        "{msg}"
    );

    let out = meshsmooth(&[&common[..], &["--params", path_str(&dir.join("nope.json"))]].concat());
    assert_eq!(code(&out), 2);
    assert!(stderr(&out).contains("nope.json"), "{}", stderr(&out));

    let out = meshsmooth(&[&common[..], &["--k-max", "1"]].concat());
    assert_eq!(code(&out), 2);
    let msg = stderr(&out);
    assert!(msg.contains("k_max") && msg.contains("allowed"), "{msg}");

    let out = meshsmooth(&[&common[..], &["--method", "wangyu"]].concat());
    assert_eq!(code(&out), 2);
    assert!(stderr(&out).contains("wang-yu"), "{}", stderr(&out));

    let out = meshsmooth(&["smooth", path_str(&input), "-o", "-", "--report", "-"]);
    assert_eq!(code(&out), 2);
    assert!(stderr(&out).contains("stdout"), "{}", stderr(&out));
    assert!(!output.exists(), "no output after a usage error");
}

#[test]
fn unreadable_input_exits_3_and_names_file_and_line() {
    let dir = scratch("unreadable_input_exits_3");
    let output = dir.join("out.obj");
    let missing = dir.join("missing.obj");
    let out = meshsmooth(&["smooth", path_str(&missing), "-o", path_str(&output)]);
    assert_eq!(code(&out), 3);
    assert!(stderr(&out).contains("missing.obj"), "{}", stderr(&out));

    let bad = dir.join("bad.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 0 one 0\nf 1 2 3\n").unwrap();
    let smooth = ["smooth", path_str(&bad), "-o", path_str(&output)];
    for args in [&smooth[..], &["report", path_str(&bad)]] {
        let out = meshsmooth(args);
        assert_eq!(code(&out), 3, "{args:?}");
        let msg = stderr(&out);
        assert!(
            msg.contains("bad.obj") && msg.contains("line 3") && msg.contains("`one`"),
            "{msg}"
        );
    }

    let lines = dir.join("lines.obj");
    std::fs::write(&lines, "v 0 0 0\nv 1 0 0\nl 1 2\n").unwrap();
    let out = meshsmooth(&["smooth", path_str(&lines), "-o", path_str(&output)]);
    assert_eq!(code(&out), 3);
    assert!(stderr(&out).contains("no faces"), "{}", stderr(&out));

    let unknown = dir.join("mesh.xyz");
    std::fs::write(&unknown, "hello\n").unwrap();
    let out = meshsmooth(&["smooth", path_str(&unknown), "-o", path_str(&output)]);
    assert_eq!(code(&out), 3);
    assert!(stderr(&out).contains("--input-format"), "{}", stderr(&out));
    assert!(!output.exists());
}

#[test]
fn unwritable_output_exits_1() {
    let dir = scratch("unwritable_output_exits_1");
    let (input, _, _) = sphere_file(&dir);
    let output = dir.join("no-such-dir").join("out.obj");
    let out = meshsmooth(&["smooth", path_str(&input), "-o", path_str(&output), "-q"]);
    assert_eq!(code(&out), 1);
    assert!(stderr(&out).contains("no-such-dir"), "{}", stderr(&out));
}

#[test]
fn report_prints_the_measures_of_a_mesh() {
    let dir = scratch("report_prints_the_measures");
    let (input, mesh, in_bytes) = sphere_file(&dir);
    let out = meshsmooth(&["report", path_str(&input), "--json"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let json: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["mesh"]["vertices"], mesh.num_vertices());
    assert_eq!(json["mesh"]["faces"], mesh.num_faces());
    assert_eq!(json["mesh"]["quads"], mesh.num_faces());
    assert_eq!(json["mesh"]["closed"], true);
    assert_eq!(json["input_sha256"], sha256_hex(&in_bytes));
    // Every corner of a voxel quad is a right angle.
    let angles = &json["measures"]["polygon_angles"];
    for key in ["min_deg", "max_deg"] {
        let deg = angles[key].as_f64().unwrap();
        assert!((deg - 90.0).abs() < 1e-9, "{key} {deg}");
    }

    let out = meshsmooth_with_stdin(&["report", "-"], &in_bytes);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let table = String::from_utf8(out.stdout).unwrap();
    assert!(
        table.contains(&format!("faces            {}", mesh.num_faces())),
        "{table}"
    );
    assert!(table.contains("closed"), "{table}");
}
