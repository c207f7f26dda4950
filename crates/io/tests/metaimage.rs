//! MetaImage reader and writer against SimpleITK: the fixtures of `tests/data/metaimage/` (written by SimpleITK 2.5.7,
//! `data-scripts/metaimage_sitk.py`) read to what SimpleITK read from them; our files read back exactly; our
//! header has SimpleITK's keys and values; bad files are refused naming the file and the problem.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde_json::Value;
use warpbench_io::metaimage::{self, MetaImageWriteOptions};
use warpbench_io::{ErrorKind, Format, GeometrySource, LoadOptions, SampleType, Volume};

use crate::support::{numbers, open_frame as open, samples_f64};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/metaimage")
}

fn reference() -> Vec<Value> {
    let path = data_dir().join("sitk_reference.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let v: Value = serde_json::from_str(&text).expect("JSON");
    v["fixtures"].as_array().expect("fixtures").clone()
}

/// The sample type our rules give SimpleITK's pixel type, and each SimpleITK value as our sample.
fn expected_type(pixel_type: &str) -> SampleType {
    match pixel_type {
        "8-bit unsigned integer" => SampleType::U8,
        "8-bit signed integer" | "16-bit signed integer" => SampleType::I16,
        "16-bit unsigned integer" => SampleType::U16,
        "32-bit float" | "64-bit float" => SampleType::F32,
        other => panic!("no rule for {other}"),
    }
}

#[test]
fn every_fixture_reads_to_what_simpleitk_read() {
    for f in reference() {
        let file = f["file"].as_str().expect("file");
        let path = data_dir().join(file);
        assert_eq!(Format::detect(&path).expect("detect"), Format::MetaImage, "{file}");
        let size: Vec<usize> = numbers(&f["size"]).into_iter().map(|s| s as usize).collect();
        let frames = size.get(3).copied().unwrap_or(1);
        let n = size[0] * size[1] * size[2];
        let all = numbers(&f["voxels"]);
        for frame in 0..frames {
            let v = open(&path, (frames > 1).then_some(frame)).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(v.dims, [size[0], size[1], size[2]], "{file}");
            assert_eq!(v.geometry_source, GeometrySource::MetaImage);
            let pixel_type = f["pixel_type"].as_str().expect("type");
            assert_eq!(v.sample_type(), expected_type(pixel_type), "{file}");
            // SimpleITK's lps_from_index, D · diag(s) | o in float64, is ours bit for bit.
            let want: Vec<Vec<f64>> = f["lps_from_index"].as_array().expect("rows").iter().map(numbers).collect();
            let rows = v.lps_from_index.rows();
            for r in 0..4 {
                for c in 0..4 {
                    assert_eq!(rows[r][c].to_bits(), want[r][c].to_bits(), "{file} [{r}][{c}]: {rows:?} vs {want:?}");
                }
            }
            // Voxels, i fastest: the same values (f64 rounded to nearest f32 by our rules, as numpy does).
            let expected: Vec<f64> = all[frame * n..(frame + 1) * n]
                .iter()
                .map(|&x| if pixel_type == "64-bit float" { f64::from(x as f32) } else { x })
                .collect();
            assert_eq!(samples_f64(&v.data), expected, "{file} frame {frame}");
        }
    }
}

#[test]
fn a_four_d_file_needs_a_frame() {
    let path = data_dir().join("frames_4d.mha");
    let e = open(&path, None).expect_err("two frames");
    assert!(matches!(e.kind, ErrorKind::FrameRequired { frames: 2 }), "{e}");
    let e = open(&path, Some(2)).expect_err("no frame 2");
    assert!(e.to_string().contains("frame 2 of a file of 2 frames"), "{e}");
}

/// The `(key, value)` lines of a MetaImage header.
fn header_fields(bytes: &[u8]) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for line in bytes.split(|&b| b == b'\n') {
        let text = String::from_utf8_lossy(line);
        let (k, v) = text.split_once('=').expect("Key = Value");
        out.push((k.trim().to_owned(), v.trim().to_owned()));
        if k.trim() == "ElementDataFile" {
            return out;
        }
    }
    panic!("no ElementDataFile")
}

/// Values agree: numbers to 2 ulp (SimpleITK prints 17 digits, we print the shortest round trip of a direction
/// and spacing recomputed from their product), text exactly.
fn same_value(key: &str, ours: &str, theirs: &str) -> bool {
    let parse = |s: &str| s.split_whitespace().map(str::parse::<f64>).collect::<Result<Vec<_>, _>>();
    match (parse(ours), parse(theirs)) {
        (Ok(a), Ok(b)) if !a.is_empty() => {
            a.len() == b.len() && a.iter().zip(&b).all(|(x, y)| (x - y).abs() <= 4.0 * f64::EPSILON * y.abs().max(1.0))
        }
        _ => key == "ElementDataFile" || ours == theirs,
    }
}

#[test]
fn our_header_has_simpleitks_keys_and_values() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (file, compressed) in
        [("oblique_i16.mha", true), ("oblique_u8.mhd", false), ("oblique_f32.mha", false), ("msb_u16.mha", false)]
    {
        let theirs_path = data_dir().join(file);
        let volume = open(&theirs_path, None).expect("read");
        let ours_path = dir.path().join(file);
        metaimage::write_with(&ours_path, &volume, MetaImageWriteOptions { compressed }).expect("write");
        let ours = header_fields(&std::fs::read(&ours_path).expect("ours"));
        let mut theirs = header_fields(&std::fs::read(&theirs_path).expect("theirs"));
        // The big-endian fixture is ours made by hand; SimpleITK writes little-endian.
        for (k, v) in &mut theirs {
            if k == "BinaryDataByteOrderMSB" {
                *v = "False".to_owned();
            }
        }
        let keys = |f: &[(String, String)]| f.iter().map(|(k, _)| k.clone()).collect::<Vec<_>>();
        assert_eq!(keys(&ours), keys(&theirs), "{file}: key order");
        for ((k, a), (_, b)) in ours.iter().zip(&theirs) {
            // zlib's output depends on its level and implementation: the size is checked by reading back.
            if k != "CompressedDataSize" {
                assert!(same_value(k, a, b), "{file}: {k} = {a} (ours), {b} (SimpleITK)");
            }
        }
        let back = open(&ours_path, None).expect("read ours");
        assert_eq!(back.data, volume.data, "{file}");
    }
}

#[test]
fn written_files_read_back_exactly() {
    let dir = tempfile::tempdir().expect("tempdir");
    for f in reference().iter().filter(|f| f["size"].as_array().is_some_and(|s| s.len() == 3)) {
        let file = f["file"].as_str().expect("file");
        let volume = open(&data_dir().join(file), None).expect("read");
        for (name, compressed) in [("a.mha", true), ("b.mha", false), ("c.mhd", false), ("d.mhd", true)] {
            let path = dir.path().join(name);
            metaimage::write_with(&path, &volume, MetaImageWriteOptions { compressed }).expect("write");
            let back = open(&path, None).expect("read back");
            assert_eq!(back.data, volume.data, "{file} as {name}");
            assert_eq!(back.dims, volume.dims);
            let bits = |v: &Volume| v.lps_from_index.rows().map(|r| r.map(f64::to_bits));
            assert_eq!(bits(&back), bits(&volume), "{file} as {name}: geometry");
        }
        // The default: .mha compressed, .mhd with an uncompressed .raw.
        metaimage::write(&dir.path().join("e.mhd"), &volume).expect("write");
        assert!(dir.path().join("e.raw").is_file());
        let text = std::fs::read(dir.path().join("e.mhd")).expect("header");
        assert!(header_fields(&text).contains(&("ElementDataFile".into(), "e.raw".into())));
        metaimage::write(&dir.path().join("f.mha"), &volume).expect("write");
        let text = std::fs::read(dir.path().join("f.mha")).expect("file");
        assert!(header_fields(&text).contains(&("CompressedData".into(), "True".into())));
    }
    let memory = std::fs::read(dir.path().join("f.mha")).expect("bytes");
    let v = metaimage::read_bytes(Path::new("mem.mha"), &memory, &mut LoadOptions::new()).expect("from memory");
    assert_eq!(v.dims, [7, 6, 5]);
    let e = metaimage::read_bytes(
        Path::new("mem.mhd"),
        &std::fs::read(dir.path().join("e.mhd")).expect("hdr"),
        &mut LoadOptions::new(),
    )
    .expect_err("detached from memory");
    assert!(e.to_string().contains("cannot be read from memory"), "{e}");
}

#[test]
fn the_magic_is_detected_without_the_extension() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("volume.img");
    std::fs::copy(data_dir().join("oblique_i16.mha"), &path).expect("copy");
    assert_eq!(Format::detect(&path).expect("detect"), Format::MetaImage);
    assert_eq!(warpbench_io::open(&path).expect("open").dims, [7, 6, 5]);
    let volume = warpbench_io::open(&path).expect("open");
    for name in ["out.mha", "out.mhd", "out.nrrd", "out.nii.gz"] {
        let out = dir.path().join(name);
        warpbench_io::write_volume(&out, &volume).expect(name);
        assert_eq!(warpbench_io::open(&out).expect(name).data, volume.data, "{name}");
    }
    let e = warpbench_io::write_volume(&dir.path().join("out.png"), &volume).expect_err("png");
    assert!(e.to_string().contains("MetaImage (.mha, or .mhd with a .raw)"), "{e}");
}

/// The i16 fixture's header and data, for editing into bad files.
fn i16_parts(compressed: bool) -> (String, Vec<u8>) {
    let name = if compressed { "oblique_i16.mha" } else { "oblique_f32.mha" };
    let bytes = std::fs::read(data_dir().join(name)).expect("fixture");
    let marker = b"ElementDataFile = LOCAL\n";
    let end = bytes.windows(marker.len()).position(|w| w == marker).expect("LOCAL") + marker.len();
    (String::from_utf8(bytes[..end].to_vec()).expect("text"), bytes[end..].to_vec())
}

fn write_file(dir: &Path, name: &str, header: &str, data: &[u8]) -> PathBuf {
    let path = dir.join(name);
    let mut f = std::fs::File::create(&path).expect("create");
    f.write_all(header.as_bytes()).expect("write");
    f.write_all(data).expect("write");
    path
}

#[test]
fn bad_files_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (zh, zdata) = i16_parts(true);
    let (rh, rdata) = i16_parts(false);
    let size = zdata.len();
    let short_z = format!("but only {} bytes", size - 40);
    let large_z = format!("CompressedDataSize = {}, but only {size} bytes", size + 7);
    let cases: Vec<(&str, String, Vec<u8>, &str)> = vec![
        ("truncated.mha", rh.clone(), rdata[..rdata.len() - 5].to_vec(), "truncated"),
        ("truncated_z.mha", zh.clone(), zdata[..size - 40].to_vec(), &short_z),
        ("bad_type.mha", rh.replace("MET_FLOAT", "MET_FLOATY"), rdata.clone(), "ElementType \"MET_FLOATY\""),
        ("vector.mha", rh.replace("MET_FLOAT", "MET_FLOAT_ARRAY"), rdata.clone(), "vector or matrix type"),
        (
            "small_size.mha",
            zh.replace(&format!("CompressedDataSize = {size}"), "CompressedDataSize = 100"),
            zdata.clone(),
            "the file is truncated or CompressedDataSize is wrong",
        ),
        (
            "large_size.mha",
            zh.replace(&format!("CompressedDataSize = {size}"), &format!("CompressedDataSize = {}", size + 7)),
            zdata.clone(),
            &large_z,
        ),
        ("corrupt_z.mha", zh.clone(), vec![0x55; size], "CompressedDataSize"),
        (
            "two_d.mha",
            rh.replace("NDims = 3", "NDims = 2").replace("DimSize = 7 6 5", "DimSize = 7 6"),
            rdata.clone(),
            "NDims = 2",
        ),
        ("dims.mha", rh.replace("DimSize = 7 6 5", "DimSize = 7 6"), rdata.clone(), "DimSize \"7 6\" is not 3"),
        (
            "channels.mha",
            rh.replace("ElementType", "ElementNumberOfChannels = 3\nElementType"),
            rdata.clone(),
            "ElementNumberOfChannels = 3",
        ),
        ("list.mha", rh.replace("ElementDataFile = LOCAL", "ElementDataFile = LIST"), Vec::new(), "LIST"),
        ("text.mha", rh.replace("BinaryData = True", "BinaryData = False"), rdata.clone(), "stored as text"),
        ("twice.mha", rh.replace("NDims = 3", "NDims = 3\nNDims = 3"), rdata.clone(), "\"NDims\" given twice"),
        (
            "synonyms.mha",
            rh.replace("Offset = -10.5 20.25 3", "Offset = -10.5 20.25 3\nOrigin = 1 2 3"),
            rdata.clone(),
            "contradicts Offset",
        ),
        ("nan.mha", rh.replace("Offset = -10.5", "Offset = nan"), rdata.clone(), "Offset"),
        (
            "transform.mha",
            rh.replace("ObjectType = Image", "ObjectType = Transform"),
            rdata.clone(),
            "ObjectType = Transform",
        ),
        ("no_end.mha", rh.replace("ElementDataFile = LOCAL\n", ""), Vec::new(), "without an ElementDataFile line"),
        ("garbage.mha", "hello world\n".to_owned(), Vec::new(), "not a MetaImage file"),
        ("empty.mha", String::new(), Vec::new(), "the file is empty"),
        (
            "singular.mha",
            rh.replace("ElementSpacing = 0.69999999999999996 1.3 2.5", "ElementSpacing = 0 1.3 2.5"),
            rdata.clone(),
            "singular",
        ),
        (
            "missing.mhd",
            rh.replace("ElementDataFile = LOCAL", "ElementDataFile = nowhere.raw"),
            Vec::new(),
            "its ElementDataFile",
        ),
    ];
    for (name, header, data, needle) in cases {
        let path = write_file(dir.path(), name, &header, &data);
        let e = open(&path, None).expect_err(name);
        let msg = e.to_string();
        assert!(msg.starts_with(&path.display().to_string()), "{name}: {msg}");
        assert!(msg.contains(needle), "{name}: {msg:?} lacks {needle:?}");
    }
    // A missing detached file names both files.
    let e = open(&dir.path().join("missing.mhd"), None).expect_err("missing");
    assert!(e.to_string().contains("nowhere.raw") && e.to_string().contains("No such file"), "{e}");
}

#[test]
fn a_detached_file_that_is_short_or_a_pipe_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let header = std::fs::read_to_string(data_dir().join("oblique_u8.mhd")).expect("header");
    let raw = std::fs::read(data_dir().join("oblique_u8.raw")).expect("raw");
    std::fs::write(dir.path().join("oblique_u8.raw"), &raw[..100]).expect("short raw");
    let path = write_file(dir.path(), "short.mhd", &header, &[]);
    let e = open(&path, None).expect_err("short");
    assert!(matches!(e.kind, ErrorKind::Truncated(_)), "{e}");
    assert!(e.to_string().contains("oblique_u8.raw: file is truncated"), "{e}");

    let fifo = dir.path().join("pipe.raw");
    let status = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo");
    assert!(status.success());
    let path = write_file(dir.path(), "pipe.mhd", &header.replace("oblique_u8.raw", "pipe.raw"), &[]);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(open(&path, None).map(|_| ()));
    });
    let result = rx.recv_timeout(std::time::Duration::from_secs(20)).expect("no hang on a pipe");
    let e = result.expect_err("a pipe");
    assert!(matches!(e.kind, ErrorKind::NotARegularFile { .. }), "{e}");
}

#[test]
fn sizes_are_checked_before_allocating() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (rh, _) = i16_parts(false);
    let header = rh.replace("DimSize = 7 6 5", "DimSize = 100000 100000 100000");
    let path = write_file(dir.path(), "huge.mha", &header, &[0; 64]);
    let e = open(&path, None).expect_err("huge");
    assert!(matches!(e.kind, ErrorKind::TooLarge { .. }), "{e}");
    let header = rh.replace("DimSize = 7 6 5", "DimSize = 1000 1000 10");
    let path = write_file(dir.path(), "short.mha", &header, &[0; 64]);
    let e = open(&path, None).expect_err("short");
    assert!(matches!(e.kind, ErrorKind::Truncated(_)), "{e}");
}

/// What `data-scripts/elastix_field.py` recorded: the grid as ITK reports it, voxel indices, their centres and
/// where transformix's point transformation maps them.
struct TransformixReference {
    size: Vec<usize>,
    lps_from_index: [[f64; 4]; 3],
    indices: Vec<[usize; 3]>,
    centres: Vec<[f64; 3]>,
    mapped: Vec<[f64; 3]>,
}

fn transformix_reference() -> TransformixReference {
    let path = data_dir().join("transformix_field_reference.json");
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("JSON");
    let triples = |key: &str| -> Vec<[f64; 3]> {
        v[key].as_array().expect("list").iter().map(|p| std::array::from_fn(|a| numbers(p)[a])).collect()
    };
    let (spacing, origin, direction) = (numbers(&v["spacing"]), numbers(&v["origin"]), numbers(&v["direction"]));
    TransformixReference {
        size: numbers(&v["size"]).into_iter().map(|s| s as usize).collect(),
        // ITK's index-to-physical map: D · diag(spacing) · ijk + origin, D row-major as recorded.
        lps_from_index: std::array::from_fn(|r| {
            std::array::from_fn(|c| if c == 3 { origin[r] } else { direction[3 * r + c] * spacing[c] })
        }),
        indices: triples("indices").into_iter().map(|p| p.map(|x| x as usize)).collect(),
        centres: triples("centres_lps"),
        mapped: triples("transformix_points_lps"),
    }
}

/// transformix's deformation field (`deformationField.mhd`, and the same field as a compressed `.mha`), read as a
/// displacement field: its grid is the one ITK reports, and every recorded voxel centre x plus its vector lands where
/// transformix's own point transformation puts x. The bound: the file holds float32 vectors of at most 1.6 mm
/// (rounding ≤ 1.2e-7 mm a component) and transformix prints its points to about 1e-6 mm; the script measured
/// 5.1e-7 mm.
#[test]
fn transformixs_deformation_field_reads_to_where_transformix_maps_the_points() {
    use warpbench_io::displacement::{FieldFormat, FieldSource, read_field_info};
    let r = transformix_reference();
    let mut fields = Vec::new();
    for file in ["transformix_field.mhd", "transformix_field.mha"] {
        let read = read_field_info(&data_dir().join(file)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((read.source, read.direction), (FieldSource::Field(FieldFormat::MetaImage), None), "{file}");
        let field = read.field;
        assert_eq!(field.dims.to_vec(), r.size, "{file}");
        assert_eq!(field.geometry_source, GeometrySource::MetaImage);
        let m = field.lps_from_index.matrix();
        for (row, want) in r.lps_from_index.iter().enumerate() {
            for (c, w) in want.iter().enumerate() {
                assert!(
                    (m[(row, c)] - w).abs() < 1e-12,
                    "{file}: lps_from_index[{row}][{c}] {} vs ITK's {w}",
                    m[(row, c)]
                );
            }
        }
        let mut worst = 0.0f64;
        for ((ijk, centre), mapped) in r.indices.iter().zip(&r.centres).zip(&r.mapped) {
            let x: [f64; 3] =
                std::array::from_fn(|a| (0..3).map(|c| m[(a, c)] * ijk[c] as f64).sum::<f64>() + m[(a, 3)]);
            assert!((0..3).all(|a| (x[a] - centre[a]).abs() < 1e-9), "{file}: voxel {ijk:?} at {x:?}, ITK {centre:?}");
            let d = field.displacements_lps[ijk[0] + r.size[0] * (ijk[1] + r.size[1] * ijk[2])];
            for a in 0..3 {
                worst = worst.max((x[a] + f64::from(d[a]) - mapped[a]).abs());
            }
        }
        assert!(worst < 1e-5, "{file}: x + D(x) is {worst} mm from transformix's point");
        assert!(field.displacements_lps.iter().any(|d| d.iter().any(|c| c.abs() > 0.5)), "a field that moves");
        fields.push(field);
    }
    assert_eq!(fields[0], fields[1], "the .mhd and the .mha hold one field");
}

/// Our MetaImage field is what ITK writes for it: SimpleITK's keys in its order with the same values, and the `.raw`
/// byte for byte; the compressed `.mha` reads back bit for bit.
#[test]
fn our_field_file_has_itks_header_and_bytes() {
    use warpbench_io::displacement::{FieldFormat, read_field, write_field};
    let dir = tempfile::tempdir().expect("tempdir");
    let theirs = data_dir().join("transformix_field.mhd");
    let (field, _) = read_field(&theirs).expect("read");
    let ours = dir.path().join("ours.mhd");
    write_field(&ours, FieldFormat::MetaImage, field.dims, &field.lps_from_index, &field.displacements_lps)
        .expect("write");
    let (a, b) =
        (header_fields(&std::fs::read(&ours).expect("ours")), header_fields(&std::fs::read(&theirs).expect("theirs")));
    let keys = |f: &[(String, String)]| f.iter().map(|(k, _)| k.clone()).collect::<Vec<_>>();
    assert_eq!(keys(&a), keys(&b), "key order");
    for ((k, x), (_, y)) in a.iter().zip(&b) {
        assert!(same_value(k, x, y), "{k} = {x} (ours), {y} (ITK)");
    }
    assert_eq!(a.last().map(|(_, v)| v.as_str()), Some("ours.raw"));
    assert_eq!(
        std::fs::read(dir.path().join("ours.raw")).expect("our data"),
        std::fs::read(data_dir().join("transformix_field.raw")).expect("ITK's data"),
        "the interleaved float32 vectors, byte for byte"
    );
    let mha = dir.path().join("ours.mha");
    write_field(&mha, FieldFormat::MetaImage, field.dims, &field.lps_from_index, &field.displacements_lps)
        .expect("write");
    assert_eq!(read_field(&mha).expect("read back").0, field);
    assert!(header_fields(&std::fs::read(&mha).expect("read")).contains(&("CompressedData".into(), "True".into())));
}

/// Files that are not displacement fields, or bad ones, are refused naming the file; a field is not a volume.
#[test]
fn bad_metaimage_fields_are_refused_naming_the_file() {
    use warpbench_io::displacement::read_field;
    let dir = tempfile::tempdir().expect("tempdir");
    let raw = std::fs::read(data_dir().join("transformix_field.raw")).expect("raw");
    let header = String::from_utf8(std::fs::read(data_dir().join("transformix_field.mhd")).expect("mhd"))
        .expect("text")
        .replace("ElementDataFile = transformix_field.raw", "ElementDataFile = LOCAL");
    let put = |name: &str, header: &str, data: &[u8]| write_file(dir.path(), name, header, data);
    let refused = |p: &Path, needle: &str| {
        let e = read_field(p).expect_err("refused");
        let text = e.to_string();
        assert!(text.starts_with(&format!("{}: ", p.display())) && text.contains(needle), "{needle:?} in {text}");
    };
    let whole = put("whole.mha", &header, &raw);
    assert!(read_field(&whole).is_ok());
    refused(&put("short.mha", &header, &raw[..raw.len() - 4]), "truncated");
    refused(&put("two.mha", &header.replace("Channels = 3", "Channels = 2"), &raw), "ElementNumberOfChannels = 2");
    refused(
        &put("scalar.mha", &header.replace("ElementNumberOfChannels = 3\n", ""), &raw),
        "ElementNumberOfChannels = 1",
    );
    refused(&put("short_type.mha", &header.replace("MET_FLOAT", "MET_SHORT"), &raw), "integer samples");
    let mut nan = raw.clone();
    let o = 12 * (1 + 9 * (2 + 8 * 3)) + 8; // the z component of voxel (1, 2, 3)
    nan[o..o + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    refused(&put("nan.mha", &header, &nan), "voxel [1, 2, 3]");
    refused(
        &put("flat.mha", &header.replace("ElementSpacing = 1.5 2 2.5", "ElementSpacing = 1.5 0 2.5"), &raw),
        "singular",
    );
    let e = open(&whole, None).expect_err("a field is not a volume");
    assert!(
        e.to_string().contains("ElementNumberOfChannels = 3") && e.to_string().contains("displacement field"),
        "{e}"
    );
}
