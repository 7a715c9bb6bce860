//! End-to-end tests of `meshsmooth smooth` and `meshsmooth report`: the
//! real binary on meshes generated here, checked for what a shell user sees
//! (files, stdout, exit codes, messages).

use meshsmooth_core::io::obj::write_obj_plain;
use meshsmooth_core::io::{self, Format, ReadLimits};
use meshsmooth_core::report::{SCHEMA_VERSION, sha256_hex};
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
    // The summary on stderr names the smoothness figure, before and after.
    let summary = stderr(&out);
    assert!(
        summary.contains("  curvature ") && summary.contains("mean variation"),
        "{summary}"
    );
    // And the grid the input was cut from.
    assert!(summary.contains("  grid      voxel\n"), "{summary}");

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
    let report = smooth_with_report(
        &input,
        &output,
        &report,
        &["--params", path_str(&params), "--iterations", "5"],
    );
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
    // The measures are a smoothing report's input stage, curvature included.
    let (output, report) = (dir.join("out.obj"), dir.join("report.json"));
    let smoothed = smooth_with_report(&input, &output, &report, &["-q"]);
    let variation = &json["measures"]["curvature_variation"];
    assert!(
        variation["mean_scaled"].as_f64().unwrap() > 0.0,
        "{variation}"
    );
    assert_eq!(
        variation,
        &smoothed["stages"]["input"]["curvature_variation"]
    );

    let out = meshsmooth_with_stdin(&["report", "-"], &in_bytes);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let table = String::from_utf8(out.stdout).unwrap();
    assert!(
        table.contains(&format!("faces            {}", mesh.num_faces())),
        "{table}"
    );
    assert!(table.contains("closed"), "{table}");
    assert!(table.contains("curvature var."), "{table}");
}

/// The marching-cubes triangle mesh of a ball of radius 4, and its
/// triangles' corners as a soup: three fresh vertices per triangle.
fn triangle_soup() -> (Mesh, Vec<[[f64; 3]; 3]>) {
    let (_, mesh) = shapes::mc_sphere(4.0);
    let p = mesh.positions();
    let tris = mesh
        .faces()
        .map(|f| {
            assert_eq!(f.len(), 3, "marching cubes makes triangles");
            [0, 1, 2].map(|c| p[f[c] as usize].to_array())
        })
        .collect();
    (mesh, tris)
}

/// The soup as OBJ: one `v` line per corner, faces `f 1 2 3`, `f 4 5 6`, ...
fn soup_obj(tris: &[[[f64; 3]; 3]]) -> String {
    let mut text = String::new();
    for t in tris {
        for [x, y, z] in t {
            text.push_str(&format!("v {x} {y} {z}\n"));
        }
    }
    for i in 0..tris.len() {
        text.push_str(&format!("f {} {} {}\n", 3 * i + 1, 3 * i + 2, 3 * i + 3));
    }
    text
}

/// The soup as ASCII PLY.
fn soup_ply(tris: &[[[f64; 3]; 3]]) -> String {
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\n\
         property double z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        3 * tris.len(),
        tris.len()
    );
    for t in tris {
        for [x, y, z] in t {
            text.push_str(&format!("{x} {y} {z}\n"));
        }
    }
    for i in 0..tris.len() {
        text.push_str(&format!("3 {} {} {}\n", 3 * i, 3 * i + 1, 3 * i + 2));
    }
    text
}

/// The JSON chunk of a GLB.
fn glb_json(bytes: &[u8]) -> Value {
    assert_eq!(&bytes[..4], b"glTF");
    let len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    serde_json::from_slice(&bytes[20..20 + len]).unwrap()
}

fn read_report(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// `meshsmooth report INPUT`'s table, the run checked to succeed.
fn report_table(input: &Path) -> String {
    let out = meshsmooth(&["report", path_str(input)]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    String::from_utf8(out.stdout).unwrap()
}

/// Runs `meshsmooth smooth INPUT -o OUTPUT --report REPORT EXTRA...`,
/// checks that it succeeds and returns the report.
fn smooth_with_report(input: &Path, output: &Path, report: &Path, extra: &[&str]) -> Value {
    let mut args = vec![
        "smooth",
        path_str(input),
        "-o",
        path_str(output),
        "--report",
        path_str(report),
    ];
    args.extend_from_slice(extra);
    let out = meshsmooth(&args);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    read_report(report)
}

fn vertex_count(bytes: &[u8], format: Format, weld: bool) -> usize {
    let options = io::ReadOptions {
        weld: Some(weld),
        ..io::ReadOptions::default()
    };
    io::read_with(bytes, format, &options)
        .expect("the output reads back")
        .mesh
        .num_vertices()
}

#[test]
fn stl_soups_are_welded_and_keep_their_vertices() {
    let dir = scratch("stl_soups_are_welded");
    let (mesh, tris) = triangle_soup();
    let file_vertices = 3 * tris.len();
    let mut stl = Vec::new();
    io::stl::write_stl_plain(&mesh, mesh.positions(), false, &mut stl).unwrap();
    let input = dir.join("in.stl");
    std::fs::write(&input, &stl).unwrap();

    // STL is welded by default: the smoother sees the closed ball.
    let (output, report) = (dir.join("out.stl"), dir.join("report.json"));
    let report = smooth_with_report(&input, &output, &report, &["-q"]);
    assert_eq!(report["schema_version"], SCHEMA_VERSION);
    assert_eq!(report["mesh"]["vertices"], mesh.num_vertices());
    assert_eq!(report["mesh"]["file_vertices"], file_vertices);
    assert_eq!(report["mesh"]["closed"], true);
    // Asked as `null` (the format's default); recorded as done.
    assert_eq!(report["reproducibility"]["params"]["weld"], true);
    let out_bytes = std::fs::read(&output).unwrap();
    assert_ne!(out_bytes, stl, "smoothing moved no vertex");
    // The file keeps its three vertices per triangle, and every copy of a
    // vertex moved alike: welding the output again gives the ball back.
    assert_eq!(vertex_count(&out_bytes, Format::Stl, false), file_vertices);
    assert_eq!(
        vertex_count(&out_bytes, Format::Stl, true),
        mesh.num_vertices()
    );

    // `--no-weld` smooths the soup as it is: nothing to join, nothing counted.
    let (output, report) = (dir.join("soup.stl"), dir.join("soup.json"));
    let report = smooth_with_report(&input, &output, &report, &["--no-weld", "-q"]);
    assert_eq!(report["mesh"]["vertices"], file_vertices);
    assert_eq!(report["mesh"]["file_vertices"], Value::Null);
    assert_eq!(report["mesh"]["closed"], false);
    assert_eq!(report["reproducibility"]["params"]["weld"], false);
}

#[test]
fn an_obj_soup_is_welded_unless_told_not_to() {
    let dir = scratch("an_obj_soup_is_welded_unless_told_not_to");
    let (mesh, tris) = triangle_soup();
    let file_vertices = 3 * tris.len();
    let text = soup_obj(&tris);
    let input = dir.join("in.obj");
    std::fs::write(&input, &text).unwrap();

    // No two faces share a vertex: welded by default, in OBJ too; `report`
    // takes the weld flags as well.
    let out = meshsmooth(&["report", path_str(&input), "--json"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let json: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["mesh"]["vertices"], mesh.num_vertices());
    assert_eq!(json["mesh"]["file_vertices"], file_vertices);
    assert_eq!(json["mesh"]["closed"], true);
    let out = meshsmooth(&["report", path_str(&input), "--json", "--no-weld"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let json: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["mesh"]["vertices"], file_vertices);
    assert_eq!(json["mesh"]["file_vertices"], Value::Null);

    let (output, report) = (dir.join("out.obj"), dir.join("report.json"));
    let report = smooth_with_report(&input, &output, &report, &["--no-weld", "--weld", "-q"]);
    assert_eq!(report["mesh"]["vertices"], mesh.num_vertices());
    assert_eq!(report["mesh"]["file_vertices"], file_vertices);
    assert_eq!(report["reproducibility"]["params"]["weld"], true);
    let smoothed = String::from_utf8(std::fs::read(&output).unwrap()).unwrap();
    let v_lines = smoothed.lines().filter(|l| l.starts_with("v ")).count();
    assert_eq!(v_lines, file_vertices, "the file keeps its vertices");
    let f_lines = |t: &str| -> Vec<String> {
        t.lines()
            .filter(|l| l.starts_with("f "))
            .map(str::to_owned)
            .collect()
    };
    assert_eq!(f_lines(&smoothed), f_lines(&text));
    assert_eq!(
        vertex_count(smoothed.as_bytes(), Format::Obj, true),
        mesh.num_vertices(),
        "the seams stay closed"
    );

    // A tolerance out of range is a usage error.
    let out = meshsmooth(&[
        "smooth",
        path_str(&input),
        "-o",
        path_str(&output),
        "--weld-tolerance",
        "0.5",
    ]);
    assert_eq!(code(&out), 2, "{}", stderr(&out));
    assert!(stderr(&out).contains("weld_tolerance"), "{}", stderr(&out));
}

#[test]
fn vertex_results_go_into_ply_and_glb_outputs() {
    let dir = scratch("vertex_results_go_into_ply_and_glb");
    let (mesh, tris) = triangle_soup();
    let file_vertices = 3 * tris.len();
    let input = dir.join("in.ply");
    std::fs::write(&input, soup_ply(&tris)).unwrap();

    // PLY in, PLY out, welded: the results are written per file vertex,
    // every copy of a welded vertex with the same values.
    let output = dir.join("out.ply");
    let out = meshsmooth(&[
        "smooth",
        path_str(&input),
        "-o",
        path_str(&output),
        "--weld",
        "--vertex-results",
        "-q",
    ]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let text = String::from_utf8(std::fs::read(&output).unwrap()).unwrap();
    let (header, body) = text.split_once("end_header\n").unwrap();
    let properties: Vec<&str> = header
        .lines()
        .skip_while(|l| !l.starts_with("element vertex"))
        .skip(1)
        .take_while(|l| l.starts_with("property"))
        .map(|l| l.rsplit(' ').next().unwrap())
        .collect();
    for name in [
        "label",
        "mean_curvature",
        "gaussian_curvature",
        "displacement",
    ] {
        assert!(properties.contains(&name), "{name} in {header}");
    }
    assert!(header.contains("property float mean_curvature"), "{header}");
    let column = |name: &str| properties.iter().position(|p| *p == name).unwrap();
    let (x, h) = (column("x"), column("mean_curvature"));
    let rows: Vec<Vec<f64>> = body
        .lines()
        .take(file_vertices)
        .map(|l| l.split_whitespace().map(|f| f.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), file_vertices);
    let mut seen: std::collections::HashMap<[u64; 3], (Vec<f64>, f64)> = Default::default();
    for (corner, row) in tris.iter().flatten().zip(&rows) {
        let key = corner.map(f64::to_bits);
        let value = (row[x..x + 3].to_vec(), row[h]);
        let first = seen.entry(key).or_insert_with(|| value.clone());
        assert_eq!(*first, value, "copies of a vertex disagree");
    }
    assert_eq!(seen.len(), mesh.num_vertices());
    assert!(rows.iter().any(|r| r[h] != 0.0), "no curvature written");

    // GLB out: the results are float attributes of the primitive.
    let output = dir.join("out.glb");
    let out = meshsmooth(&[
        "smooth",
        path_str(&input),
        "-o",
        path_str(&output),
        "--weld",
        "--vertex-results",
        "-q",
    ]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let bytes = std::fs::read(&output).unwrap();
    let json = glb_json(&bytes);
    let attributes = &json["meshes"][0]["primitives"][0]["attributes"];
    for name in [
        "_LABEL",
        "_MEAN_CURVATURE",
        "_GAUSSIAN_CURVATURE",
        "_DISPLACEMENT",
    ] {
        assert!(attributes[name].is_u64(), "{name} in {attributes}");
    }
    assert_eq!(
        vertex_count(&bytes, Format::Glb, false),
        mesh.num_vertices()
    );

    // Without the flag, no attributes; OBJ cannot hold them (a note says so).
    let out = meshsmooth(&["smooth", path_str(&input), "-o", path_str(&output), "-q"]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    let json = glb_json(&std::fs::read(&output).unwrap());
    assert!(json["meshes"][0]["primitives"][0]["attributes"]["_LABEL"].is_null());
    let out = meshsmooth(&[
        "smooth",
        path_str(&input),
        "-o",
        path_str(&dir.join("out.obj")),
        "--vertex-results",
    ]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    assert!(
        stderr(&out).contains("cannot hold per-vertex results"),
        "{}",
        stderr(&out)
    );
}

#[test]
fn a_part_wound_inside_out_beside_an_outward_one_is_named_and_turned() {
    let dir = scratch("a_part_wound_inside_out");
    let (_, mesh, _) = sphere_file(&dir);
    // The sphere twice, apart, the second wound inside out.
    let n = mesh.num_vertices() as u32;
    let span = mesh
        .positions()
        .iter()
        .fold(0.0f64, |m, p| m.max(p.x.abs()));
    let mut positions = mesh.positions().to_vec();
    positions.extend(
        mesh.positions()
            .iter()
            .map(|p| *p + glam::DVec3::new(4.0 * span, 0.0, 0.0)),
    );
    let mut polygons = faces(&mesh);
    polygons.extend(faces(&mesh).into_iter().map(|c| {
        let mut c: Vec<u32> = c.iter().map(|&v| v + n).collect();
        c.reverse();
        c
    }));
    let two = Mesh::from_polygons(positions, &polygons).unwrap();
    let mut bytes = Vec::new();
    write_obj_plain(&two, two.positions(), &mut bytes).unwrap();
    let input = dir.join("two.obj");
    std::fs::write(&input, &bytes).unwrap();
    let table = report_table(&input);
    assert!(
        table.contains(&format!(
            "winding          1 of its closed parts inside out beside outward ones ({} faces,",
            mesh.num_faces()
        )),
        "{table}"
    );
}

#[test]
fn faces_wound_against_their_neighbours_smooth_as_wound_outward() {
    let dir = scratch("faces_wound_against_their_neighbours");
    let (input, mesh, _) = sphere_file(&dir);
    let (output, report) = (dir.join("out.obj"), dir.join("report.json"));
    let outward = smooth_with_report(&input, &output, &report, &["-q"]);
    assert_eq!(outward["mesh"]["reoriented_faces"], 0);
    let smoothed = read_mesh(&std::fs::read(&output).unwrap());

    // Every fifth face turned, as a writer that loses track of its winding
    // (or an STL file) leaves them.
    let turned: Vec<Vec<u32>> = faces(&mesh)
        .into_iter()
        .enumerate()
        .map(|(f, mut c)| {
            if f % 5 == 0 {
                c.reverse();
            }
            c
        })
        .collect();
    let wound = Mesh::from_polygons(mesh.positions().to_vec(), &turned).unwrap();
    let mut bytes = Vec::new();
    write_obj_plain(&wound, wound.positions(), &mut bytes).unwrap();
    let input = dir.join("wound.obj");
    std::fs::write(&input, &bytes).unwrap();
    let (output, report) = (dir.join("wound_out.obj"), dir.join("wound.json"));
    let out = meshsmooth(&[
        "smooth",
        path_str(&input),
        "-o",
        path_str(&output),
        "--report",
        path_str(&report),
    ]);
    assert_eq!(code(&out), 0, "{}", stderr(&out));
    assert!(
        stderr(&out).contains("against their neighbours"),
        "{}",
        stderr(&out)
    );
    let report = read_report(&report);
    assert_eq!(
        report["mesh"]["reoriented_faces"],
        mesh.num_faces().div_ceil(5)
    );
    assert_eq!(report["mesh"]["inside_out"], false);
    assert_eq!(report["stages"], outward["stages"]);
    // The same positions; the file's own faces.
    let out_mesh = read_mesh(&std::fs::read(&output).unwrap());
    assert_eq!(out_mesh.positions(), smoothed.positions());
    assert_eq!(faces(&out_mesh), turned);

    let table = report_table(&input);
    assert!(
        table.contains(&format!(
            "winding          {} faces against their neighbours",
            mesh.num_faces().div_ceil(5)
        )),
        "{table}"
    );
}

#[test]
fn two_labels_in_one_stl_are_told_apart_and_reported() {
    // A block of 6 x 4 x 4 voxels in two labels, split at x = 3, written as
    // one STL: each label's surface with its own triangles.
    let dir = scratch("two_labels_in_one_stl");
    let label = |left: bool| {
        let mask =
            shapes::VoxelMask::from_fn(glam::IVec3::ZERO, [6, 4, 4], |i, _, _| (i < 3) == left);
        shapes::voxel_boundary_mesh(&mask)
    };
    let (a, b) = (label(true), label(false));
    let mut positions = a.positions().to_vec();
    positions.extend_from_slice(b.positions());
    let mut all = faces(&a);
    let base = a.num_vertices() as u32;
    all.extend(
        faces(&b)
            .into_iter()
            .map(|f| f.iter().map(|&v| v + base).collect()),
    );
    let both = Mesh::from_polygons(positions, &all).unwrap();
    let mut bytes = Vec::new();
    io::stl::write_stl_plain(&both, both.positions(), false, &mut bytes).unwrap();
    let input = dir.join("labels.stl");
    std::fs::write(&input, &bytes).unwrap();

    let table = report_table(&input);
    // The wall is 4 x 4 voxel faces, two triangles each.
    assert!(
        table.contains("bodies           2 touching face to face (32 shared faces)"),
        "{table}"
    );
    assert!(
        table.contains(&format!(
            "vertices         {} ",
            a.num_vertices() + b.num_vertices()
        )),
        "{table}"
    );

    let (output, report) = (dir.join("out.stl"), dir.join("report.json"));
    let report = smooth_with_report(&input, &output, &report, &[]);
    assert_eq!(report["mesh"]["touching_bodies"], 2);
    assert_eq!(report["mesh"]["shared_faces"], 32);
    assert!(report["walls_parted"]["max"].as_f64().is_some());
    assert!(
        report["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w.as_str().unwrap().contains("touch face to face")),
        "{}",
        report["warnings"]
    );
}

#[test]
fn a_label_complex_is_smoothed_region_by_region_and_reported() {
    // A block of 6 x 4 x 4 voxels in three labels (x < 2, 2-3, 4-5) as VTK's
    // surface nets write a label map: one vertex per position, each wall
    // between two labels written once.
    let dir = scratch("label_complex");
    let masks: Vec<_> = (0..3)
        .map(|label| {
            shapes::VoxelMask::from_fn(glam::IVec3::ZERO, [6, 4, 4], |i, _, _| i / 2 == label)
        })
        .collect();
    let complex = shapes::label_complex(&masks);
    let mut bytes = Vec::new();
    io::obj::write_obj_plain(&complex, complex.positions(), &mut bytes).unwrap();
    let input = dir.join("labels.obj");
    std::fs::write(&input, &bytes).unwrap();

    let table = report_table(&input);
    // Two walls of 4 x 4 voxel faces.
    assert!(
        table.contains("regions          3 sharing 32 wall faces"),
        "{table}"
    );
    // The three labels' volume, each wall counted for both.
    assert!(table.contains("volume           96.0000\n"), "{table}");

    let (output, report) = (dir.join("out.obj"), dir.join("report.json"));
    let report = smooth_with_report(&input, &output, &report, &[]);
    assert_eq!(report["mesh"]["regions"], 3);
    assert_eq!(report["mesh"]["region_walls"], 32);
    assert!(report["walls_joined"]["max"].as_f64().is_some());
    assert!(report["joined_fixes"].is_object());
    assert!(
        report["warnings"]
            .as_array()
            .unwrap()
            .iter()
            .any(|w| w.as_str().unwrap().contains("complex of 3 regions")),
        "{}",
        report["warnings"]
    );
}
