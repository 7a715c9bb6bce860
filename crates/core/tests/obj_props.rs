//! Property tests of the OBJ reader and writer: any bytes give `Ok` or a
//! typed error, generated files read back exactly, the non-`v` lines of a
//! file survive a write unchanged, errors name the right line, and the
//! reader agrees with `tobj` on the faces it sees.

use glam::DVec3;
use meshsmooth_core::io::obj::{read_obj, write_obj, write_obj_plain};
use meshsmooth_core::io::{IoError, ReadLimits};
use proptest::prelude::*;

/// A generated OBJ file together with what reading it must give.
#[derive(Debug, Clone)]
struct Generated {
    text: Vec<u8>,
    positions: Vec<DVec3>,
    faces: Vec<Vec<u32>>,
    /// Per line: its bytes and, for a `v` line, what must stay around the
    /// coordinates; other lines must be copied verbatim.
    lines: Vec<(Vec<u8>, Option<VertexFrame>)>,
}

/// The bytes before (`v` and the blank after it) and after (extra fields,
/// comment, line ending) the coordinates of a `v` line.
type VertexFrame = (Vec<u8>, Vec<u8>);

#[derive(Debug, Clone)]
enum Item {
    Vertex {
        xyz: [f64; 3],
        scientific: bool,
        sep: &'static str,
        extra: &'static str,
    },
    Face(Vec<(u32, bool, usize)>),
    Other(String),
}

fn coordinate() -> impl Strategy<Value = f64> {
    prop_oneof![
        prop::num::f64::NORMAL | prop::num::f64::SUBNORMAL | prop::num::f64::ZERO,
        (-1000i32..1000).prop_map(|i| f64::from(i) / 8.0),
        -1e3..1e3f64,
    ]
}

fn other_line() -> impl Strategy<Value = String> {
    let keyword = prop::sample::select(vec![
        "vt", "vn", "vp", "o", "g", "s", "usemtl", "mtllib", "#", "l", "p", "curv",
    ]);
    let sep = prop::sample::select(vec![" ", "\t", "  ", " \t "]);
    (keyword, sep, "[a-zA-Z0-9_./ #-]{0,12}").prop_map(|(k, s, w)| format!("{k}{s}{w}"))
}

fn item() -> impl Strategy<Value = Item> {
    let vertex = (
        [coordinate(), coordinate(), coordinate()],
        any::<bool>(),
        prop::sample::select(vec![" ", "\t", "  "]),
        prop::sample::select(vec!["", " 1", " 0.5 0.25 0.125", "   # c", " 1 0 0 "]),
    )
        .prop_map(|(xyz, scientific, sep, extra)| Item::Vertex {
            xyz,
            scientific,
            sep,
            extra,
        });
    let face =
        prop::collection::vec((any::<u32>(), any::<bool>(), 0usize..4), 3..7).prop_map(Item::Face);
    prop_oneof![3 => vertex, 2 => face, 2 => other_line().prop_map(Item::Other)]
}

fn number(x: f64, scientific: bool) -> String {
    if scientific {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// Assembles items into a file. A vertex is prepended and a face appended so
/// every file is readable.
fn assemble(mut items: Vec<Item>, crlf: bool) -> Generated {
    items.insert(
        0,
        Item::Vertex {
            xyz: [0.0, 0.0, 0.0],
            scientific: false,
            sep: " ",
            extra: "",
        },
    );
    items.push(Item::Face(vec![(0, false, 0), (1, false, 0), (2, true, 0)]));
    let total = items
        .iter()
        .filter(|i| matches!(i, Item::Vertex { .. }))
        .count() as u32;
    let end = if crlf { "\r\n" } else { "\n" };
    let mut g = Generated {
        text: Vec::new(),
        positions: Vec::new(),
        faces: Vec::new(),
        lines: Vec::new(),
    };
    for item in items {
        let (line, v) = match item {
            Item::Vertex {
                xyz,
                scientific,
                sep,
                extra,
            } => {
                g.positions.push(DVec3::from_array(xyz));
                let [x, y, z] = xyz.map(|c| number(c, scientific));
                let prefix = format!("v{sep}");
                let line = format!("{prefix}{x} {y} {z}{extra}");
                (line, Some((prefix.into_bytes(), extra.as_bytes().to_vec())))
            }
            Item::Face(corners) => {
                let defined = g.positions.len() as u32;
                let mut face = Vec::new();
                let mut line = String::from("f");
                for (seed, negative, form) in corners {
                    let (written, index) = if negative && defined > 0 {
                        let back = 1 + seed % defined;
                        (format!("-{back}"), defined - back)
                    } else {
                        let index = seed % total;
                        (format!("{}", index + 1), index)
                    };
                    face.push(index);
                    let corner = match form {
                        0 => written,
                        1 => format!("{written}/1"),
                        2 => format!("{written}//-1"),
                        _ => format!("{written}/2/3"),
                    };
                    line.push(' ');
                    line.push_str(&corner);
                }
                g.faces.push(face);
                (line, None)
            }
            Item::Other(line) => (line, None),
        };
        g.text.extend_from_slice(line.as_bytes());
        g.text.extend_from_slice(end.as_bytes());
        let suffix_end = |(p, s): (Vec<u8>, Vec<u8>)| (p, [s, end.as_bytes().to_vec()].concat());
        g.lines.push((
            [line.as_bytes(), end.as_bytes()].concat(),
            v.map(suffix_end),
        ));
    }
    g
}

fn generated() -> impl Strategy<Value = Generated> {
    (prop::collection::vec(item(), 0..40), any::<bool>())
        .prop_map(|(items, crlf)| assemble(items, crlf))
}

fn faces_of(mesh: &meshsmooth_core::Mesh) -> Vec<Vec<u32>> {
    mesh.faces().map(<[u32]>::to_vec).collect()
}

fn split_lines(bytes: &[u8]) -> Vec<&[u8]> {
    bytes.split_inclusive(|&b| b == b'\n').collect()
}

/// Bytes an adversary would pick to confuse an OBJ parser.
fn objish_bytes() -> impl Strategy<Value = Vec<u8>> {
    let alphabet: Vec<u8> = b"vf0123456789-+./ \t\r\n#eEinfa\0\xFF\xFEltpo".to_vec();
    prop::collection::vec(prop::sample::select(alphabet), 0..300)
}

fn check_never_panics(bytes: &[u8]) {
    let limits = ReadLimits {
        max_vertices: 1000,
        max_faces: 1000,
    };
    match read_obj(bytes, &limits) {
        Ok((mesh, src)) => {
            assert!(mesh.num_faces() > 0);
            assert!(mesh.positions().iter().all(|p| p.is_finite()));
            let mut out = Vec::new();
            write_obj(&src, mesh.positions(), &mut out).expect("writing back what was read");
            let (again, _) = read_obj(&out, &limits).expect("reading what was written");
            assert_eq!(again, mesh);
        }
        Err(e) => {
            assert!(!e.code().as_str().is_empty());
            assert!(!e.to_string().is_empty());
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn any_bytes_give_ok_or_a_typed_error(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        check_never_panics(&bytes);
    }

    #[test]
    fn objish_bytes_give_ok_or_a_typed_error(bytes in objish_bytes()) {
        check_never_panics(&bytes);
    }

    #[test]
    fn mutated_files_give_ok_or_a_typed_error(
        g in generated(),
        edits in prop::collection::vec((any::<prop::sample::Index>(), objish_bytes()), 1..4),
    ) {
        let mut bytes = g.text;
        for (at, insert) in edits {
            let at = at.index(bytes.len() + 1);
            bytes.splice(at..at, insert.into_iter().take(6));
        }
        check_never_panics(&bytes);
    }

    #[test]
    fn generated_files_read_exactly(g in generated()) {
        let (mesh, _) = read_obj(&g.text, &ReadLimits::default()).unwrap();
        let bits = |p: &[DVec3]| p.iter().map(|v| v.to_array().map(f64::to_bits)).collect::<Vec<_>>();
        prop_assert_eq!(bits(mesh.positions()), bits(&g.positions));
        prop_assert_eq!(faces_of(&mesh), g.faces);
    }

    #[test]
    fn writing_changes_only_coordinates(g in generated(), scale in -4.0..4.0f64, shift in -10.0..10.0f64) {
        let (mesh, src) = read_obj(&g.text, &ReadLimits::default()).unwrap();
        let moved: Vec<DVec3> = mesh.positions().iter().map(|p| *p * scale + shift).collect();
        prop_assume!(moved.iter().all(|p| p.is_finite()));
        let mut out = Vec::new();
        write_obj(&src, &moved, &mut out).unwrap();

        let out_lines = split_lines(&out);
        prop_assert_eq!(out_lines.len(), g.lines.len());
        for (written, (original, vertex)) in out_lines.iter().zip(&g.lines) {
            match vertex {
                None => prop_assert_eq!(*written, &original[..]),
                Some((prefix, suffix)) => {
                    prop_assert!(written.starts_with(prefix) && written.ends_with(suffix),
                        "{:?} from {:?}", String::from_utf8_lossy(written), String::from_utf8_lossy(original));
                }
            }
        }

        let (again, _) = read_obj(&out, &ReadLimits::default()).unwrap();
        prop_assert_eq!(again.positions(), &moved[..]);
        prop_assert_eq!(faces_of(&again), faces_of(&mesh));

        let mut plain = Vec::new();
        write_obj_plain(&mesh, &moved, &mut plain).unwrap();
        let (plain_mesh, _) = read_obj(&plain, &ReadLimits::default()).unwrap();
        prop_assert_eq!(plain_mesh, again);
    }

    #[test]
    fn a_bad_coordinate_is_reported_on_its_line(
        g in generated(),
        at in any::<prop::sample::Index>(),
        bad in prop::sample::select(vec!["1..2", "nan", "inf", "-infinity", "1e", "0x10", "--1", "1,5"]),
    ) {
        let mut lines = split_lines(&g.text);
        let at = at.index(lines.len() + 1);
        let bad_line = format!("v 1 {bad} 3\n");
        lines.insert(at, bad_line.as_bytes());
        let bytes = lines.concat();
        // NaN and infinities have their own code; both name the line.
        let non_finite = ["nan", "inf", "-infinity"].contains(&bad);
        match read_obj(&bytes, &ReadLimits::default()) {
            Err(
                e @ (IoError::Parse { .. } | IoError::NonFiniteCoordinate { .. }),
            ) => {
                let expected = if non_finite { "non_finite_coordinate" } else { "parse_error" };
                prop_assert_eq!(e.code(), expected);
                let text = e.to_string();
                prop_assert!(text.contains(&format!("on line {}:", at + 1)), "{}", text);
                prop_assert!(text.contains(bad) && text.contains("y coordinate"), "{}", text);
            }
            other => prop_assert!(false, "expected a parse error, got {:?}", other),
        }
    }

    #[test]
    fn faces_agree_with_tobj(g in generated(), with_attributes in any::<bool>()) {
        // tobj splits models at `o`/`g` and re-indexes vertices per model,
        // so compare the corner positions of each face, on files with only
        // vertex, attribute and face lines.
        let mut text = String::from(if with_attributes { "vt 0 0\nvt 1 0\nvn 0 0 1\n" } else { "" });
        let mut expected = Vec::new();
        let mut defined = 0usize;
        for (line, vertex) in &g.lines {
            let line = String::from_utf8_lossy(line);
            if vertex.is_some() {
                let fields: Vec<&str> = line.split_whitespace().take(4).collect();
                text.push_str(&fields.join(" "));
                text.push('\n');
                defined += 1;
            } else if let Some(corners) = line.strip_prefix("f ") {
                let written: Vec<i64> = corners
                    .split_whitespace()
                    .map(|c| c.split('/').next().unwrap().parse().unwrap())
                    .collect();
                // tobj cannot resolve forward references; leave those faces out.
                if written.iter().any(|&v| v > defined as i64) {
                    continue;
                }
                let mut face = String::from("f");
                let mut positions = Vec::new();
                for v in written {
                    let index = if v < 0 { defined as i64 + v } else { v - 1 };
                    positions.push(g.positions[index as usize]);
                    face.push_str(&if with_attributes { format!(" {v}/1/1") } else { format!(" {v}") });
                }
                text.push_str(&face);
                text.push('\n');
                expected.push(positions);
            }
        }
        prop_assume!(!expected.is_empty());
        let (mesh, _) = read_obj(text.as_bytes(), &ReadLimits::default()).unwrap();
        let ours: Vec<Vec<DVec3>> = mesh.faces().map(|f| f.iter().map(|&i| mesh.positions()[i as usize]).collect()).collect();
        prop_assert_eq!(&ours, &expected);

        let options = tobj::LoadOptions { triangulate: false, single_index: false, ..Default::default() };
        let (models, _) = tobj::load_obj_buf(&mut text.as_bytes(), &options, |_| {
            Err(tobj::LoadError::OpenFileFailed)
        }).unwrap();
        prop_assert_eq!(models.len(), 1);
        let m = &models[0].mesh;
        let arities: Vec<usize> = if m.face_arities.is_empty() {
            vec![3; m.indices.len() / 3]
        } else {
            m.face_arities.iter().map(|&a| a as usize).collect()
        };
        let mut theirs = Vec::new();
        let mut corner = 0;
        for a in arities {
            let face = m.indices[corner..corner + a].iter().map(|&i| {
                let i = i as usize * 3;
                DVec3::new(m.positions[i], m.positions[i + 1], m.positions[i + 2])
            });
            theirs.push(face.collect::<Vec<_>>());
            corner += a;
        }
        prop_assert_eq!(ours, theirs);
    }
}
