//! FreeSurfer MGH / MGZ reader and writer against nibabel: the fixtures of `tests/data/mgh/` (written by nibabel 5.4.2,
//! `data-scripts/mgh_nibabel.py`) read to nibabel's affine and voxels; `.mgz` reads as its `.mgh`; our files read back
//! to the volume written, with nibabel's layout byte for byte; bad files are refused naming the file and the problem.

use std::path::{Path, PathBuf};

use serde_json::Value;
use warpbench_io::mgh;
use warpbench_io::{ErrorKind, Format, GeometrySource, LoadOptions, SampleType, VolumeFileKind};

use crate::support::{numbers, open_frame as open, sample_volumes, samples_f64};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/mgh")
}

fn reference() -> Vec<Value> {
    let path = data_dir().join("reference.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let v: Value = serde_json::from_str(&text).expect("JSON");
    v["volumes"].as_array().expect("volumes").clone()
}

fn matrix(v: &Value) -> [[f64; 4]; 4] {
    let rows: Vec<Vec<f64>> = v.as_array().expect("rows").iter().map(numbers).collect();
    std::array::from_fn(|r| std::array::from_fn(|c| rows[r][c]))
}

/// nibabel's RAS vox2ras as our LPS one: the first two rows negated.
fn lps_of_ras(ras: [[f64; 4]; 4]) -> [[f64; 4]; 4] {
    std::array::from_fn(|r| std::array::from_fn(|c| if r < 2 { -ras[r][c] } else { ras[r][c] }))
}

/// nibabel computes the affine from the same f32 fields in mixed f32/f64 arithmetic, we in f64: they agree to f32's
/// precision, relative to the matrix's largest entry.
const AFFINE_REL_TOL: f64 = 1e-6;

fn assert_matrix_close(got: [[f64; 4]; 4], want: [[f64; 4]; 4], rel: f64, what: &str) {
    let scale = want.iter().flatten().fold(1.0f64, |m, x| m.max(x.abs()));
    for r in 0..4 {
        for c in 0..4 {
            assert!(
                (got[r][c] - want[r][c]).abs() <= rel * scale,
                "{what} [{r}][{c}]: {} vs {} (tolerance {})\n got {got:?}\nwant {want:?}",
                got[r][c],
                want[r][c],
                rel * scale
            );
        }
    }
}

/// The sample type our rules give nibabel's dtype.
fn expected_type(dtype: &str) -> SampleType {
    match dtype {
        "uint8" => SampleType::U8,
        "int16" => SampleType::I16,
        "uint16" => SampleType::U16,
        "int32" | "float32" => SampleType::F32,
        other => panic!("no rule for {other}"),
    }
}

#[test]
fn every_fixture_reads_to_what_nibabel_read() {
    let volumes = reference();
    assert_eq!(volumes.len(), 9);
    for f in &volumes {
        let name = f["name"].as_str().expect("name");
        let shape: Vec<usize> = numbers(&f["shape"]).into_iter().map(|s| s as usize).collect();
        let frames = shape.get(3).copied().unwrap_or(1);
        let n = shape[0] * shape[1] * shape[2];
        let all = numbers(&f["voxels"]);
        let dtype = f["dtype"].as_str().expect("dtype");
        for file in f["files"].as_array().expect("files").iter().map(|x| x.as_str().expect("file")) {
            let path = data_dir().join(file);
            assert_eq!(Format::detect(&path).expect("detect"), Format::Mgh, "{file}");
            for frame in 0..frames {
                let v = open(&path, (frames > 1).then_some(frame)).unwrap_or_else(|e| panic!("{e}"));
                assert_eq!(v.dims, [shape[0], shape[1], shape[2]], "{file}");
                assert_eq!(v.geometry_source, GeometrySource::Mgh, "{file}");
                assert_eq!(v.sample_type(), expected_type(dtype), "{file}");
                assert!(v.rescale.is_identity() && !v.rescale.applied, "{file}: MGH has no rescale");
                // Voxels, i fastest: nibabel's values (int32 rounded to nearest f32 by our rules, as numpy does).
                let want: Vec<f64> = all[frame * n..(frame + 1) * n]
                    .iter()
                    .map(|&x| if dtype == "int32" { f64::from(x as f32) } else { x })
                    .collect();
                assert_eq!(samples_f64(&v.data), want, "{file} frame {frame}");
                if name == "no_ras_flag" {
                    continue; // below
                }
                assert!(v.metadata.warnings.is_empty(), "{file}: {:?}", v.metadata.warnings);
                let want = lps_of_ras(matrix(&f["affine"]));
                assert_matrix_close(v.lps_from_index.rows(), want, AFFINE_REL_TOL, file);
            }
        }
    }
}

/// goodRASflag 0: FreeSurfer's coronal default (LIA, 1 mm, c_ras 0) with a warning. nibabel 5.4.2 assumes LSP
/// instead: the same unit voxels and the same index N/2 at RAS 0, the j and k columns of the opposite sign.
#[test]
fn no_ras_flag_is_freesurfers_coronal_default_with_a_warning() {
    let f = reference().into_iter().find(|f| f["name"] == "no_ras_flag").expect("no_ras_flag");
    assert_eq!(f["good_ras_flag"], 0);
    let v = warpbench_io::open(data_dir().join("no_ras_flag.mgh")).expect("open");
    // RAS: i → (−1, 0, 0), j → (0, 0, −1), k → (0, 1, 0), index (2.5, 2, 1.5) at 0; in LPS, x and y negated.
    let ours = [[1.0, 0.0, 0.0, -2.5], [0.0, 0.0, -1.0, 1.5], [0.0, -1.0, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0]];
    assert_eq!(v.lps_from_index.rows(), ours);
    let nibabel = [[1.0, 0.0, 0.0, -2.5], [0.0, 0.0, 1.0, -1.5], [0.0, 1.0, 0.0, -2.0], [0.0, 0.0, 0.0, 1.0]];
    assert_eq!(lps_of_ras(matrix(&f["affine"])), nibabel, "nibabel 5.4.2's default");
    let warnings = v.metadata.warnings.join("\n");
    assert!(warnings.contains("goodRASflag is 0") && warnings.contains("LIA"), "{warnings}");
}

#[test]
fn an_mgz_reads_as_its_mgh_and_tags_are_ignored() {
    for name in ["oblique_u8", "oblique_i16", "oblique_u16", "oblique_i32", "oblique_f32", "conformed_lia_u8"] {
        let plain = warpbench_io::open(data_dir().join(format!("{name}.mgh"))).expect("mgh");
        let gzip = warpbench_io::open(data_dir().join(format!("{name}.mgz"))).expect("mgz");
        assert_eq!(plain, gzip, "{name}");
    }
    for frame in 0..2 {
        let plain = open(&data_dir().join("frames_f32.mgh"), Some(frame)).expect("mgh");
        let gzip = open(&data_dir().join("frames_f32.mgz"), Some(frame)).expect("mgz");
        assert_eq!(plain, gzip, "frame {frame}");
    }
    let plain = warpbench_io::open(data_dir().join("oblique_i16.mgh")).expect("mgh");
    let tagged = warpbench_io::open(data_dir().join("with_tags.mgz")).expect("with tags");
    assert_eq!(plain, tagged);
    // The bytes in memory read as the file does, compressed or not as the name says.
    for file in ["oblique_f32.mgh", "oblique_f32.mgz"] {
        let bytes = std::fs::read(data_dir().join(file)).expect("read");
        let v = mgh::read_bytes(Path::new(file), &bytes, &mut LoadOptions::new()).expect(file);
        assert_eq!(v, warpbench_io::open(data_dir().join(file)).expect(file), "{file}");
    }
}

#[test]
fn a_file_of_several_frames_needs_a_frame_in_range() {
    let path = data_dir().join("frames_f32.mgz");
    let e = warpbench_io::open(&path).expect_err("two frames");
    assert!(matches!(e.kind, ErrorKind::FrameRequired { frames: 2 }), "{e}");
    assert!(e.to_string().starts_with(&path.display().to_string()), "{e}");
    let e = open(&path, Some(2)).expect_err("frame 2");
    assert!(e.to_string().contains("frame 2 is out of range: the file has 2 frame(s)"), "{e}");
    // A frame of a 3-D file: 0 only.
    assert!(open(&data_dir().join("oblique_u8.mgh"), Some(0)).is_ok());
}

/// The geometry is stored as f32: it reads back within f32's rounding of the coordinates (about 6e-8 relative).
const F32_GEOMETRY_REL_TOL: f64 = 8.0 * f32::EPSILON as f64;

#[test]
fn what_we_write_reads_back_to_the_volume_written() {
    let dir = tempfile::tempdir().expect("tempdir");
    for v in sample_volumes() {
        let t = v.sample_type().name();
        for ext in ["mgh", "mgz", "MGH.GZ"] {
            let path = dir.path().join(format!("out_{t}.{ext}"));
            assert_eq!(VolumeFileKind::of(&path), Some(VolumeFileKind::Mgh), "{ext}");
            warpbench_io::write_volume(&path, &v).unwrap_or_else(|e| panic!("{e}"));
            let gzip = ext != "mgh";
            assert_eq!(std::fs::read(&path).expect("read").starts_with(&[0x1f, 0x8b]), gzip, "{ext}");
            let back = warpbench_io::open(&path).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(back.dims, v.dims, "{t} {ext}");
            assert_eq!(back.data, v.data, "{t} {ext}: the sample type and the samples are kept");
            assert_eq!(back.geometry_source, GeometrySource::Mgh);
            assert!(back.metadata.warnings.is_empty(), "{:?}", back.metadata.warnings);
            assert_matrix_close(back.lps_from_index.rows(), v.lps_from_index.rows(), F32_GEOMETRY_REL_TOL, t);
            let bytes = mgh::to_bytes(&path, &v, gzip).expect("to_bytes");
            let again = mgh::read_bytes(&path, &bytes, &mut LoadOptions::new()).expect("read_bytes");
            assert_eq!(again, back, "to_bytes writes what write does");
        }
    }
    let v = &sample_volumes()[0];
    let e = mgh::write(&dir.path().join("out.nii"), v).expect_err("not an MGH name");
    assert!(e.to_string().contains(".mgh, or .mgz"), "{e}");
    assert!(!dir.path().join("out.nii").exists());
    let e = warpbench_io::write_volume(&dir.path().join("out.png"), v).expect_err("png");
    assert!(e.to_string().contains("FreeSurfer MGH (.mgh, .mgz)"), "{e}");
}

/// Our file of a nibabel fixture has nibabel's bytes: the same header fields before the geometry, the geometry within
/// f32 rounding, and the samples and the five scan parameters after them byte for byte.
#[test]
fn our_files_have_nibabels_layout() {
    let dir = tempfile::tempdir().expect("tempdir");
    for name in ["oblique_u8", "oblique_i16", "oblique_u16", "oblique_f32", "conformed_lia_u8"] {
        let theirs = std::fs::read(data_dir().join(format!("{name}.mgh"))).expect("fixture");
        let v = warpbench_io::open(data_dir().join(format!("{name}.mgh"))).expect("open");
        let path = dir.path().join(format!("{name}.mgh"));
        mgh::write(&path, &v).expect("write");
        let ours = std::fs::read(&path).expect("ours");
        assert_eq!(ours.len(), theirs.len(), "{name}");
        assert_eq!(ours[..30], theirs[..30], "{name}: version, dims, type, dof, goodRASflag");
        assert_eq!(ours[mgh::HEADER_BYTES..], theirs[mgh::HEADER_BYTES..], "{name}: samples and scan parameters");
        assert!(ours[90..mgh::HEADER_BYTES].iter().all(|&b| b == 0), "{name}: the unused header");
        let f32_at = |b: &[u8], o: usize| f64::from(f32::from_be_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]));
        for o in (30..90).step_by(4) {
            let (a, b) = (f32_at(&ours, o), f32_at(&theirs, o));
            assert!((a - b).abs() <= 4.0 * f64::from(f32::EPSILON) * b.abs().max(1.0), "{name} byte {o}: {a} vs {b}");
        }
    }
}

/// `bytes` with `value` written big-endian at `offset`.
fn patched(bytes: &[u8], offset: usize, value: &[u8]) -> Vec<u8> {
    let mut b = bytes.to_vec();
    b[offset..offset + value.len()].copy_from_slice(value);
    b
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    use std::io::Write as _;
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    enc.write_all(bytes).expect("gzip");
    enc.finish().expect("gzip")
}

/// A bad file: its name, its bytes, the kind of error it must give and what the message must say.
type BadCase = (&'static str, Vec<u8>, fn(&ErrorKind) -> bool, &'static str);

#[test]
fn bad_files_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let u8_file = std::fs::read(data_dir().join("oblique_u8.mgh")).expect("fixture");
    let i16_file = std::fs::read(data_dir().join("oblique_i16.mgh")).expect("fixture");
    let mgz = std::fs::read(data_dir().join("oblique_u8.mgz")).expect("fixture");
    let big = i32::MAX.to_be_bytes();
    let absurd = [big, big, big, 1i32.to_be_bytes()].concat();
    let large = [1000i32.to_be_bytes(), 1000i32.to_be_bytes(), 100i32.to_be_bytes()].concat();
    let cases: Vec<BadCase> = vec![
        (
            "empty.mgh",
            Vec::new(),
            |k| matches!(k, ErrorKind::Truncated(_)),
            "the file ends inside the 284-byte MGH header, after 0 bytes",
        ),
        ("short_header.mgh", u8_file[..100].to_vec(), |k| matches!(k, ErrorKind::Truncated(_)), "284-byte MGH header"),
        (
            "short_header.mgz",
            gzip(&u8_file[..100]),
            |k| matches!(k, ErrorKind::Truncated(_)),
            "the file ends inside the 284-byte MGH header, after 100 bytes",
        ),
        (
            "short_data.mgh",
            i16_file[..i16_file.len() - 30].to_vec(),
            |k| matches!(k, ErrorKind::Truncated(_)),
            "the 5×4×3 SHORT samples of frame 0 end at byte 404 but the file has 394 bytes",
        ),
        (
            "short_data.mgz",
            gzip(&i16_file[..300]),
            |k| matches!(k, ErrorKind::Truncated(_)),
            "the file ends inside the voxel data",
        ),
        (
            "cut_stream.mgz",
            mgz[..mgz.len() / 2].to_vec(),
            |k| matches!(k, ErrorKind::Truncated(_)),
            "the file ends inside",
        ),
        (
            "type_7.mgh",
            patched(&u8_file, 20, &7i32.to_be_bytes()),
            |k| matches!(k, ErrorKind::Unsupported(_)),
            "MGH data type 7 (MRI_FLOAT_COMPLEX); readable: 0 UCHAR",
        ),
        (
            "type_99.mgh",
            patched(&u8_file, 20, &99i32.to_be_bytes()),
            |k| matches!(k, ErrorKind::Unsupported(_)),
            "MGH data type 99 (not an MGH type code)",
        ),
        (
            "zero_dim.mgh",
            patched(&u8_file, 8, &0i32.to_be_bytes()),
            |k| matches!(k, ErrorKind::Invalid(_)),
            "a dimension is zero: width 5, height 0, depth 3, frames 1",
        ),
        (
            "negative_frames.mgh",
            patched(&u8_file, 16, &(-2i32).to_be_bytes()),
            |k| matches!(k, ErrorKind::Invalid(_)),
            "a dimension is negative",
        ),
        (
            "absurd_dims.mgh",
            patched(&u8_file, 4, &absurd),
            |k| matches!(k, ErrorKind::TooLarge { .. }),
            "volume too large: dims [2147483647, 2147483647, 2147483647]",
        ),
        (
            "large_dims.mgh",
            patched(&u8_file, 4, &large),
            |k| matches!(k, ErrorKind::Truncated(_)),
            "end at byte 100000284 but the file has 364 bytes",
        ),
        (
            "large_dims.mgz",
            gzip(&patched(&u8_file, 4, &large)),
            |k| matches!(k, ErrorKind::Truncated(_)),
            "gzip stream inflates to at most 1032 times that",
        ),
        (
            "version_2.mgh",
            patched(&u8_file, 0, &2i32.to_be_bytes()),
            |k| matches!(k, ErrorKind::BadMagic { .. }),
            "not a MGH file: version 2, expected 1",
        ),
        (
            "plain.mgz",
            u8_file.clone(),
            |k| matches!(k, ErrorKind::BadMagic { .. }),
            "not a gzip-compressed MGH (.mgz) file: it does not start with gzip's magic bytes",
        ),
        (
            "compressed.mgh",
            mgz.clone(),
            |k| matches!(k, ErrorKind::BadMagic { .. }),
            "(the file is gzip-compressed: name it .mgz)",
        ),
        (
            "corrupt.mgz",
            // The first deflate block's type, 3: reserved, an error.
            patched(&mgz, 10, &[0x07]),
            |k| matches!(k, ErrorKind::Invalid(_)),
            "corrupt compressed data in the 284-byte MGH header",
        ),
        (
            "zero_delta.mgh",
            patched(&u8_file, 30, &0f32.to_be_bytes()),
            |k| matches!(k, ErrorKind::Invalid(_)),
            "singular or not finite",
        ),
    ];
    for (name, bytes, kind, message) in cases {
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).expect("write");
        let e = warpbench_io::open(&path).expect_err(name);
        let text = e.to_string();
        assert!(kind(&e.kind), "{name}: {text}");
        assert!(text.starts_with(&path.display().to_string()), "{name}: {text}");
        assert!(text.contains(message), "{name}: {text}\n(expected {message:?})");
        let from_memory = mgh::read_bytes(Path::new(name), &bytes, &mut LoadOptions::new()).expect_err(name);
        assert!(kind(&from_memory.kind), "{name} from memory: {from_memory}");
    }
}

#[test]
fn a_low_memory_cap_is_honoured_before_allocating() {
    let path = data_dir().join("oblique_f32.mgz");
    let e = LoadOptions::new().max_voxel_bytes(100).open(&path).expect_err("cap");
    assert!(matches!(e.kind, ErrorKind::TooLarge { bytes: 240, limit: 100, .. }), "{e}");
}

#[test]
fn reading_reports_progress_and_can_be_cancelled() {
    let path = data_dir().join("frames_f32.mgz");
    let mut seen = Vec::new();
    LoadOptions::new()
        .frame(1)
        .progress(|p| {
            seen.push((p.done, p.total));
            std::ops::ControlFlow::Continue(())
        })
        .open(&path)
        .expect("open");
    assert_eq!(seen.last(), Some(&(480, 480)), "{seen:?}: frame 0 is read through in a gzip stream");
    let e = LoadOptions::new().frame(1).progress(|_| std::ops::ControlFlow::Break(())).open(&path).expect_err("cancel");
    assert!(matches!(e.kind, ErrorKind::Cancelled), "{e}");
}
