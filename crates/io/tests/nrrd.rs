//! NRRD reader and writer: hand-built headers, round trips, bad input and the lung CT fixture.

use std::io::Write;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use flate2::Compression;
use flate2::write::GzEncoder;
use proptest::prelude::*;
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::nrrd::{self, NrrdWriteOptions};
use warpbench_io::{ErrorKind, GeometrySource, LoadOptions, Volume, VoxelData};

/// Geometry of a write/read round trip must agree to this (mm); we print shortest round-trip f64.
const GEOMETRY_TOL_MM: f64 = 1e-9;

fn name() -> &'static Path {
    Path::new("test.nrrd")
}

fn read(bytes: &[u8]) -> warpbench_io::Result<Volume> {
    nrrd::read_bytes(name(), bytes, &mut LoadOptions::new())
}

fn nrrd_file(header: &str, data: &[u8]) -> Vec<u8> {
    let mut v = header.as_bytes().to_vec();
    v.extend_from_slice(data);
    v
}

fn gzip(data: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::default());
    e.write_all(data).expect("gzip");
    e.finish().expect("gzip")
}

fn i16_le(v: &[i16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

const SAMPLES: [i16; 12] = [-1024, -1, 0, 1, 2, 3, 100, 200, 300, 3071, i16::MIN, i16::MAX];

fn lps_header(encoding: &str) -> String {
    format!(
        "NRRD0004\n# a comment\ntype: short\ndimension: 3\nspace: left-posterior-superior\nsizes: 3 2 2\n\
         space directions: (0.5,0,0) (0,0.75,0) (0,0,2.5)\nkinds: domain domain domain\nendian: little\n\
         encoding: {encoding}\nspace origin: (-146,-325,-777.5)\nmy key:=my: value\n\n"
    )
}

fn assert_rows(t: &Transform<Lps, Index>, want: [[f64; 4]; 3]) {
    let rows = t.rows();
    for r in 0..3 {
        for c in 0..4 {
            assert!((rows[r][c] - want[r][c]).abs() <= GEOMETRY_TOL_MM, "row {r} col {c}: {rows:?} vs {want:?}");
        }
    }
}

#[test]
fn raw_lps_header_gives_samples_and_geometry() {
    let v = read(&nrrd_file(&lps_header("raw"), &i16_le(&SAMPLES))).expect("read");
    assert_eq!(v.dims, [3, 2, 2]);
    assert_eq!(v.data, VoxelData::I16(SAMPLES.to_vec()));
    assert_eq!(v.geometry_source, GeometrySource::NrrdSpace);
    assert_rows(&v.lps_from_index, [[0.5, 0.0, 0.0, -146.0], [0.0, 0.75, 0.0, -325.0], [0.0, 0.0, 2.5, -777.5]]);
    assert!(v.rescale.is_identity() && !v.rescale.applied);
}

#[test]
fn gzip_reads_the_same_as_raw() {
    let raw = read(&nrrd_file(&lps_header("raw"), &i16_le(&SAMPLES))).expect("raw");
    let gz = read(&nrrd_file(&lps_header("gzip"), &gzip(&i16_le(&SAMPLES)))).expect("gzip");
    let gz2 = read(&nrrd_file(&lps_header("gz"), &gzip(&i16_le(&SAMPLES)))).expect("gz");
    assert_eq!(raw, gz);
    assert_eq!(raw, gz2);
}

#[test]
fn ras_and_las_spaces_are_converted_to_lps() {
    let h = |space: &str| {
        format!(
            "NRRD0005\ntype: uchar\ndimension: 3\nspace: {space}\nsizes: 2 1 1\n\
             space directions: (1,0.5,0) (0,2,0) (0,0,3)\nencoding: raw\nspace origin: (10,20,30)\n\n"
        )
    };
    let ras = read(&nrrd_file(&h("right-anterior-superior"), &[7, 8])).expect("ras");
    assert_rows(&ras.lps_from_index, [[-1.0, 0.0, 0.0, -10.0], [-0.5, -2.0, 0.0, -20.0], [0.0, 0.0, 3.0, 30.0]]);
    let ras_short = read(&nrrd_file(&h("RAS"), &[7, 8])).expect("RAS");
    assert_eq!(ras.lps_from_index, ras_short.lps_from_index);
    let las = read(&nrrd_file(&h("left-anterior-superior"), &[7, 8])).expect("las");
    assert_rows(&las.lps_from_index, [[1.0, 0.0, 0.0, 10.0], [-0.5, -2.0, 0.0, -20.0], [0.0, 0.0, 3.0, 30.0]]);
    assert_eq!(las.data, VoxelData::U8(vec![7, 8]));
}

#[test]
fn spacings_only_is_axis_aligned_at_origin_zero() {
    let h = "NRRD0001\ntype: unsigned char\ndimension: 3\nsizes: 2 2 1\nspacings: 0.5 0.25 4\nencoding: raw\n\n";
    let v = read(&nrrd_file(h, &[1, 2, 3, 4])).expect("read");
    assert_eq!(v.geometry_source, GeometrySource::NrrdSpacings);
    assert_rows(&v.lps_from_index, [[0.5, 0.0, 0.0, 0.0], [0.0, 0.25, 0.0, 0.0], [0.0, 0.0, 4.0, 0.0]]);
    // No space and no spacings: unit spacing, with a warning.
    let h = "NRRD0001\ntype: uchar\ndimension: 3\nsizes: 2 2 1\nencoding: raw\n\n";
    let v = read(&nrrd_file(h, &[1, 2, 3, 4])).expect("read");
    assert_rows(&v.lps_from_index, [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]]);
    assert!(!v.metadata.warnings.is_empty());
}

fn typed(ty: &str, endian: &str, data: &[u8]) -> warpbench_io::Result<Volume> {
    let h = format!("NRRD0004\ntype: {ty}\ndimension: 3\nsizes: 2 1 1\nendian: {endian}\nencoding: raw\n\n");
    read(&nrrd_file(&h, data))
}

#[test]
fn sample_types_follow_the_manifest_rules() {
    let be_u16: Vec<u8> = [513u16, 65535].iter().flat_map(|x| x.to_be_bytes()).collect();
    for alias in ["ushort", "unsigned short", "unsigned short int", "uint16", "uint16_t"] {
        assert_eq!(typed(alias, "big", &be_u16).expect(alias).data, VoxelData::U16(vec![513, 65535]), "{alias}");
    }
    for alias in ["signed char", "int8", "int8_t"] {
        assert_eq!(typed(alias, "little", &[0x80, 0x7f]).expect(alias).data, VoxelData::I16(vec![-128, 127]));
    }
    for alias in ["uchar", "unsigned char", "uint8", "uint8_t"] {
        assert_eq!(typed(alias, "little", &[0, 255]).expect(alias).data, VoxelData::U8(vec![0, 255]));
    }
    let be_i16: Vec<u8> = [-2i16, 300].iter().flat_map(|x| x.to_be_bytes()).collect();
    for alias in ["short", "short int", "signed short", "signed short int", "int16", "int16_t"] {
        assert_eq!(typed(alias, "big", &be_i16).expect(alias).data, VoxelData::I16(vec![-2, 300]));
    }
    let i32s: Vec<u8> = [-70000i32, 5].iter().flat_map(|x| x.to_le_bytes()).collect();
    for alias in ["int", "signed int", "int32", "int32_t"] {
        assert_eq!(typed(alias, "little", &i32s).expect(alias).data, VoxelData::F32(vec![-70000.0, 5.0]));
    }
    let u32s: Vec<u8> = [4_000_000_000u32, 5].iter().flat_map(|x| x.to_be_bytes()).collect();
    for alias in ["uint", "unsigned int", "uint32", "uint32_t"] {
        assert_eq!(typed(alias, "big", &u32s).expect(alias).data, VoxelData::F32(vec![4e9, 5.0]));
    }
    let i64s: Vec<u8> = [-3i64, 1 << 40].iter().flat_map(|x| x.to_le_bytes()).collect();
    for alias in ["longlong", "long long", "long long int", "signed long long", "signed long long int", "int64"] {
        assert_eq!(typed(alias, "little", &i64s).expect(alias).data, VoxelData::F32(vec![-3.0, 1_099_511_627_776.0]));
    }
    let u64s: Vec<u8> = [7u64, 9].iter().flat_map(|x| x.to_le_bytes()).collect();
    for alias in ["ulonglong", "unsigned long long", "unsigned long long int", "uint64", "uint64_t"] {
        assert_eq!(typed(alias, "little", &u64s).expect(alias).data, VoxelData::F32(vec![7.0, 9.0]));
    }
    let f32s: Vec<u8> = [1.5f32, -0.25].iter().flat_map(|x| x.to_be_bytes()).collect();
    assert_eq!(typed("float", "big", &f32s).expect("float").data, VoxelData::F32(vec![1.5, -0.25]));
    let f64s: Vec<u8> = [0.1f64, -1e10].iter().flat_map(|x| x.to_le_bytes()).collect();
    assert_eq!(typed("double", "little", &f64s).expect("double").data, VoxelData::F32(vec![0.1, -1e10]));
    let e = typed("block", "little", &[0, 0]).expect_err("block");
    assert!(matches!(e.kind, ErrorKind::Unsupported(_)), "{e}");
}

#[test]
fn byte_skip_and_line_skip() {
    let h = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 1 1\nencoding: raw\nbyte skip: 3\n\n";
    assert_eq!(read(&nrrd_file(h, &[9, 9, 9, 1, 2])).expect("skip 3").data, VoxelData::U8(vec![1, 2]));
    // -1: the data are the last bytes of the file, whatever precedes them.
    let h = "NRRD0004\ntype: short\ndimension: 3\nsizes: 2 1 1\nendian: little\nencoding: raw\nbyte skip: -1\n\n";
    let mut data = b"junk of any length".to_vec();
    data.extend(i16_le(&[5, -6]));
    assert_eq!(read(&nrrd_file(h, &data)).expect("skip -1").data, VoxelData::I16(vec![5, -6]));
    // Compressed: the byte skip counts decompressed bytes.
    let h = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 1 1\nencoding: gzip\nbyte skip: 2\n\n";
    assert_eq!(read(&nrrd_file(h, &gzip(&[0, 0, 4, 5]))).expect("gz skip").data, VoxelData::U8(vec![4, 5]));
    let h = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 1 1\nencoding: gzip\nbyte skip: -1\n\n";
    assert!(read(&nrrd_file(h, &gzip(&[4, 5]))).is_err(), "-1 is raw only");
    // Line skip, then byte skip.
    let h = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 1 1\nencoding: raw\nline skip: 2\nbyte skip: 1\n\n";
    assert_eq!(read(&nrrd_file(h, b"P5 a\nline two\nX\x01\x02")).expect("line skip").data, VoxelData::U8(vec![1, 2]));
}

#[test]
fn detached_header_with_raw_and_gzip_data_files() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("vol.raw"), i16_le(&SAMPLES)).expect("raw");
    std::fs::create_dir(dir.path().join("sub")).expect("mkdir");
    std::fs::write(dir.path().join("sub/vol.raw.gz"), gzip(&i16_le(&SAMPLES))).expect("gz");
    let base = "NRRD0004\ntype: int16\ndimension: 3\nsizes: 3 2 2\nendian: little\nspacings: 1 1 1\n";
    // A detached header may end at the end of the file, without a blank line.
    let raw_hdr = dir.path().join("vol.nhdr");
    std::fs::write(&raw_hdr, format!("{base}encoding: raw\ndata file: vol.raw\n")).expect("nhdr");
    let gz_hdr = dir.path().join("volgz.nhdr");
    std::fs::write(&gz_hdr, format!("{base}encoding: gzip\ndata file: ./sub/vol.raw.gz\n\n")).expect("nhdr");
    let a = nrrd::read(&raw_hdr, &mut LoadOptions::new()).expect("raw nhdr");
    let b = warpbench_io::open(&gz_hdr).expect("gz nhdr");
    assert_eq!(a.data, VoxelData::I16(SAMPLES.to_vec()));
    assert_eq!(a.data, b.data);
    // A missing data file is an error naming it.
    let bad = dir.path().join("bad.nhdr");
    std::fs::write(&bad, format!("{base}encoding: raw\ndata file: nothere.raw\n\n")).expect("nhdr");
    let e = nrrd::read(&bad, &mut LoadOptions::new()).expect_err("missing data file");
    assert!(e.path.ends_with("nothere.raw"), "{e}");
    // Multi-file forms are refused clearly; so is a detached file in memory.
    let list = format!("{base}encoding: raw\ndata file: LIST\nvol.raw\n");
    let e = read(list.as_bytes()).expect_err("LIST");
    assert!(matches!(e.kind, ErrorKind::Unsupported(_)), "{e}");
    let e = read(format!("{base}encoding: raw\ndata file: vol.raw\n\n").as_bytes()).expect_err("in memory");
    assert!(e.to_string().contains("detached"), "{e}");
}

#[test]
fn ascii_and_hex_encodings() {
    let h = "NRRD0004\ntype: float\ndimension: 3\nsizes: 2 2 1\nencoding: ascii\n\n";
    assert_eq!(
        read(&nrrd_file(h, b"1.5 -2\n3e2,\t4\n")).expect("ascii").data,
        VoxelData::F32(vec![1.5, -2.0, 300.0, 4.0])
    );
    let h = "NRRD0004\ntype: signed char\ndimension: 3\nsizes: 2 1 1\nencoding: text\n\n";
    assert_eq!(read(&nrrd_file(h, b"-128 127")).expect("ascii i8").data, VoxelData::I16(vec![-128, 127]));
    assert!(read(&nrrd_file(h, b"-129 127")).is_err(), "out of range for i8");
    assert!(matches!(read(&nrrd_file(h, b"5")).expect_err("short").kind, ErrorKind::Truncated(_)));
    let h = "NRRD0004\ntype: ushort\ndimension: 3\nsizes: 2 1 1\nendian: big\nencoding: hex\n\n";
    assert_eq!(read(&nrrd_file(h, b"0102\nFFfe\n")).expect("hex").data, VoxelData::U16(vec![0x0102, 0xfffe]));
    assert!(read(&nrrd_file(h, b"01zz0000")).is_err());
}

#[test]
fn four_d_with_one_size_one_axis_is_a_volume() {
    let h = "NRRD0004\ntype: uchar\ndimension: 4\nspace: LPS\nsizes: 1 2 1 1\n\
             space directions: none (2,0,0) (0,3,0) (0,0,4)\nkinds: list domain domain domain\nencoding: raw\n\
             space origin: (1,2,3)\n\n";
    let v = read(&nrrd_file(h, &[5, 6])).expect("4-D");
    assert_eq!(v.dims, [2, 1, 1]);
    assert_rows(&v.lps_from_index, [[2.0, 0.0, 0.0, 1.0], [0.0, 3.0, 0.0, 2.0], [0.0, 0.0, 4.0, 3.0]]);
    // A trailing size-1 axis without a space.
    let h = "NRRD0004\ntype: uchar\ndimension: 4\nsizes: 2 1 1 1\nspacings: 1 1 1 nan\nencoding: raw\n\n";
    assert_eq!(read(&nrrd_file(h, &[5, 6])).expect("4-D spacings").dims, [2, 1, 1]);
    // Real vector data are refused.
    let h = "NRRD0004\ntype: uchar\ndimension: 4\nspace: LPS\nsizes: 3 2 1 1\n\
             space directions: none (2,0,0) (0,3,0) (0,0,4)\nencoding: raw\n\n";
    let e = read(&nrrd_file(h, &[0; 6])).expect_err("vector");
    assert!(matches!(e.kind, ErrorKind::Unsupported(_)) && e.to_string().contains("vector"), "{e}");
    let h = "NRRD0004\ntype: uchar\ndimension: 4\nsizes: 2 2 2 2\nencoding: raw\n\n";
    assert!(matches!(read(&nrrd_file(h, &[0; 16])).expect_err("4-D").kind, ErrorKind::Unsupported(_)));
    let h = "NRRD0004\ntype: uchar\ndimension: 2\nsizes: 2 2\nencoding: raw\n\n";
    assert!(matches!(read(&nrrd_file(h, &[0; 4])).expect_err("2-D").kind, ErrorKind::Unsupported(_)));
}

fn oblique() -> Transform<Lps, Index> {
    let c = 0.3f64.cos();
    let s = 0.3f64.sin();
    let m = nalgebra::Matrix3::new(0.7 * c, -0.9 * s, 0.0, 0.7 * s, 0.9 * c, 0.1, 0.0, 0.0, 3.3);
    Transform::from_linear_translation(m, [-123.456_789_012_345_67, 1.0 / 3.0, 1e-7])
}

fn roundtrip(v: &Volume, gzip: bool) -> Volume {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("out.nrrd");
    nrrd::write_with(&p, v, NrrdWriteOptions { gzip }).expect("write");
    let text = std::fs::read(&p).expect("bytes");
    assert!(text.starts_with(b"NRRD0004\n"));
    let header = String::from_utf8_lossy(&text[..text.windows(2).position(|w| w == b"\n\n").expect("blank line")]);
    assert!(header.contains("space: left-posterior-superior"), "{header}");
    assert!(header.contains(if gzip { "encoding: gzip" } else { "encoding: raw" }), "{header}");
    warpbench_io::open(&p).expect("read back")
}

#[test]
fn write_read_round_trip_is_exact() {
    let dims = [4, 3, 2];
    let datas = [
        VoxelData::U8((0..24).map(|i| (i * 11) as u8).collect()),
        VoxelData::I16((0..24).map(|i| (i * 1000 - 12_000) as i16).collect()),
        VoxelData::U16((0..24).map(|i| (i * 2500) as u16).collect()),
        VoxelData::F32((0..24).map(|i| (i as f32).sqrt() * -1e-3 + f32::EPSILON).collect()),
    ];
    for data in datas {
        let mut v = Volume::new(name(), dims, data, oblique(), GeometrySource::NrrdSpace).expect("volume");
        v.metadata.description = Some("round trip\nsecond line".into());
        for gzip in [true, false] {
            let back = roundtrip(&v, gzip);
            assert_eq!(back.dims, v.dims);
            assert_eq!(back.data, v.data, "samples must be bit-identical");
            assert!(back.lps_from_index.max_abs_diff(&v.lps_from_index) <= GEOMETRY_TOL_MM);
            assert_eq!(back.geometry_source, GeometrySource::NrrdSpace);
            assert_eq!(back.metadata.description.as_deref(), Some("round trip second line"));
        }
    }
    // The default writer compresses.
    let v = Volume::new(name(), [1, 1, 1], VoxelData::U8(vec![1]), oblique(), GeometrySource::NrrdSpace).expect("v");
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("d.nrrd");
    nrrd::write(&p, &v).expect("write");
    assert!(String::from_utf8_lossy(&std::fs::read(&p).expect("read")).contains("encoding: gzip"));
}

fn expect_kind(bytes: &[u8], what: &str, ok: impl Fn(&ErrorKind) -> bool) {
    match read(bytes) {
        Ok(v) => panic!("{what}: read a volume {v:?}"),
        Err(e) => {
            assert!(ok(&e.kind), "{what}: wrong kind: {e}");
            assert!(e.to_string().starts_with("test.nrrd: "), "{what}: the error names the file: {e}");
        }
    }
}

#[test]
fn bad_input_is_a_clear_error() {
    let good = nrrd_file(&lps_header("raw"), &i16_le(&SAMPLES));
    expect_kind(b"", "empty", |k| matches!(k, ErrorKind::BadMagic { .. }));
    expect_kind(b"NIFTI\n\n", "wrong magic", |k| matches!(k, ErrorKind::BadMagic { .. }));
    expect_kind(b"NRRD0009\n\n", "future magic", |k| matches!(k, ErrorKind::BadMagic { .. }));
    expect_kind(&good[..40], "header cut short", |k| matches!(k, ErrorKind::Invalid(_) | ErrorKind::Truncated(_)));
    expect_kind(&good[..good.len() - 1], "raw data cut short", |k| matches!(k, ErrorKind::Truncated(_)));
    let gz = nrrd_file(&lps_header("gzip"), &gzip(&i16_le(&SAMPLES)));
    expect_kind(&gz[..gz.len() - 12], "gzip cut short", |k| matches!(k, ErrorKind::Truncated(_)));
    let short_gz = nrrd_file(&lps_header("gzip"), &gzip(&i16_le(&SAMPLES[..5])));
    expect_kind(&short_gz, "gzip stream too short", |k| matches!(k, ErrorKind::Truncated(_)));
    let mut bad_gz = nrrd_file(&lps_header("gzip"), &[0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3]);
    bad_gz.extend_from_slice(&[0xff; 40]);
    expect_kind(&bad_gz, "corrupt gzip", |k| matches!(k, ErrorKind::Invalid(_) | ErrorKind::Truncated(_)));
    let nan = lps_header("raw").replace("(0,0.75,0)", "(0,nan,0)");
    expect_kind(&nrrd_file(&nan, &i16_le(&SAMPLES)), "NaN direction", |k| matches!(k, ErrorKind::Invalid(_)));
    let inf = lps_header("raw").replace("(-146,-325,-777.5)", "(inf,0,0)");
    expect_kind(&nrrd_file(&inf, &i16_le(&SAMPLES)), "infinite origin", |k| matches!(k, ErrorKind::Invalid(_)));
    let singular = lps_header("raw").replace("(0,0,2.5)", "(0,0,0)");
    expect_kind(&nrrd_file(&singular, &i16_le(&SAMPLES)), "singular", |k| matches!(k, ErrorKind::Invalid(_)));
    let zero = lps_header("raw").replace("sizes: 3 2 2", "sizes: 3 0 2");
    expect_kind(&nrrd_file(&zero, &[]), "zero size", |k| matches!(k, ErrorKind::Invalid(_)));
    let neg = lps_header("raw").replace("sizes: 3 2 2", "sizes: 3 -2 2");
    expect_kind(&nrrd_file(&neg, &[]), "negative size", |k| matches!(k, ErrorKind::Invalid(_)));
    let huge = lps_header("raw").replace("sizes: 3 2 2", "sizes: 18446744073709551615 4294967296 4294967296");
    expect_kind(&nrrd_file(&huge, &[]), "overflowing sizes", |k| matches!(k, ErrorKind::TooLarge { .. }));
    let big = lps_header("raw").replace("sizes: 3 2 2", "sizes: 100000 100000 100000");
    expect_kind(&nrrd_file(&big, &[]), "huge sizes", |k| matches!(k, ErrorKind::TooLarge { .. }));
    let bz = lps_header("bzip2");
    expect_kind(&nrrd_file(&bz, &[]), "bzip2", |k| matches!(k, ErrorKind::Unsupported(m) if m.contains("bzip2")));
    let no_type = lps_header("raw").replace("type: short\n", "");
    expect_kind(&nrrd_file(&no_type, &[]), "no type", |k| matches!(k, ErrorKind::Invalid(_)));
    let twice = lps_header("raw").replace("dimension: 3\n", "dimension: 3\ndimension: 3\n");
    expect_kind(&nrrd_file(&twice, &[]), "field twice", |k| matches!(k, ErrorKind::Invalid(_)));
    let garbage_line = lps_header("raw").replace("# a comment", "this is not a field");
    expect_kind(&nrrd_file(&garbage_line, &[]), "garbage line", |k| matches!(k, ErrorKind::Invalid(_)));
    // A header with no blank line within 1 MiB.
    let mut long = b"NRRD0004\n".to_vec();
    long.extend(
        std::iter::repeat_n(b"# xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx\n", 20_000).flatten(),
    );
    expect_kind(&long, "endless header", |k| matches!(k, ErrorKind::Invalid(m) if m.contains("blank line")));
    // Random bytes.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let random: Vec<u8> = (0..4096)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state as u8
        })
        .collect();
    assert!(read(&random).is_err());
}

#[test]
fn raw_length_is_checked_before_allocating_and_limit_applies() {
    // 1 GiB of claimed samples in a tiny file: refused as truncated, without allocating.
    let h = lps_header("raw").replace("sizes: 3 2 2", "sizes: 1024 1024 512");
    let e = read(&nrrd_file(&h, &[0; 16])).expect_err("short");
    assert!(matches!(e.kind, ErrorKind::Truncated(_)), "{e}");
    let h = lps_header("gzip").replace("sizes: 3 2 2", "sizes: 1024 1024 512");
    let e = read(&nrrd_file(&h, &gzip(&[0; 16]))).expect_err("short gzip");
    assert!(matches!(e.kind, ErrorKind::Truncated(_)), "{e}");
    // max_voxel_bytes.
    let bytes = nrrd_file(&lps_header("raw"), &i16_le(&SAMPLES));
    let e = nrrd::read_bytes(name(), &bytes, &mut LoadOptions::new().max_voxel_bytes(23)).expect_err("limit");
    assert!(matches!(e.kind, ErrorKind::TooLarge { limit: 23, .. }), "{e}");
    assert!(nrrd::read_bytes(name(), &bytes, &mut LoadOptions::new().max_voxel_bytes(24)).is_ok());
}

#[test]
fn progress_is_reported_and_can_cancel() {
    let bytes = nrrd_file(&lps_header("gzip"), &gzip(&i16_le(&SAMPLES)));
    let mut seen = Vec::new();
    let mut opts = LoadOptions::new().progress(|p| {
        seen.push((p.stage, p.done, p.total));
        ControlFlow::Continue(())
    });
    nrrd::read_bytes(name(), &bytes, &mut opts).expect("read");
    drop(opts);
    assert_eq!(seen.first(), Some(&("reading", 0, 24)));
    assert_eq!(seen.last(), Some(&("reading", 24, 24)));
    let mut cancel = LoadOptions::new().progress(|_| ControlFlow::Break(()));
    let e = nrrd::read_bytes(name(), &bytes, &mut cancel).expect_err("cancelled");
    assert!(matches!(e.kind, ErrorKind::Cancelled));
}

fn lung() -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nrrd/lung1_image.nrrd");
    p.exists().then_some(p)
}

/// data.md: 512x512x48, 0.570/0.570/5.0 mm, int16, LPS origin (-146,-325,-777.5), HU -1024..3071.
#[test]
fn lung_ct_fixture_matches_data_md() {
    let Some(p) = lung() else {
        eprintln!("tests/data/nrrd/lung1_image.nrrd is absent; skipped");
        return;
    };
    let v = warpbench_io::open(&p).expect("lung1");
    assert_eq!(v.dims, [512, 512, 48]);
    assert_eq!(v.sample_type(), warpbench_io::SampleType::I16);
    assert_eq!(v.geometry_source, GeometrySource::NrrdSpace);
    let s = v.spacing_mm();
    assert!((s[0] - 0.570).abs() < 1e-3 && (s[1] - 0.570).abs() < 1e-3 && (s[2] - 5.0).abs() < 1e-9, "{s:?}");
    let o = v.lps_from_index.translation();
    assert!((o[0] + 146.0).abs() < 1e-9 && (o[1] + 325.0).abs() < 1e-9 && (o[2] + 777.5).abs() < 1e-9, "{o:?}");
    assert_eq!(v.data.finite_range(), Some((-1024.0, 3071.0)));
    // And it survives our own writer.
    let back = roundtrip(&v, true);
    assert_eq!(back.data, v.data);
    assert!(back.lps_from_index.max_abs_diff(&v.lps_from_index) <= GEOMETRY_TOL_MM);
}

fn small_valid_file() -> Vec<u8> {
    let mut f = nrrd_file(&lps_header("gzip"), &gzip(&i16_le(&SAMPLES)));
    f.extend_from_slice(b"");
    f
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    /// Law: no mutation of a valid file makes the reader panic.
    #[test]
    fn mutated_files_never_panic(
        edits in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in any::<prop::sample::Index>(),
        raw in any::<bool>(),
    ) {
        let mut f = if raw { nrrd_file(&lps_header("raw"), &i16_le(&SAMPLES)) } else { small_valid_file() };
        for (at, byte) in edits {
            let i = at.index(f.len());
            f[i] = byte;
        }
        if cut.index(4) == 0 {
            let n = cut.index(f.len());
            f.truncate(n);
        }
        let _ = read(&f);
    }

    /// Law: write then read is the identity on samples and geometry.
    #[test]
    fn random_volumes_round_trip(
        dims in (1usize..5, 1usize..5, 1usize..4),
        seed in any::<u64>(),
        scale in (0.01f64..10.0, 0.01f64..10.0, 0.01f64..10.0),
        origin in (-1e3f64..1e3, -1e3f64..1e3, -1e3f64..1e3),
        gzip in any::<bool>(),
    ) {
        let dims = [dims.0, dims.1, dims.2];
        let n = dims[0] * dims[1] * dims[2];
        let mut s = seed | 1;
        let data: Vec<i16> = (0..n).map(|_| { s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1); (s >> 48) as i16 }).collect();
        let t = Transform::from_scale_translation([scale.0, -scale.1, scale.2], [origin.0, origin.1, origin.2]);
        let v = Volume::new(name(), dims, VoxelData::I16(data), t, GeometrySource::NrrdSpace).expect("volume");
        let back = roundtrip(&v, gzip);
        prop_assert_eq!(&back.data, &v.data);
        prop_assert!(back.lps_from_index.max_abs_diff(&v.lps_from_index) <= GEOMETRY_TOL_MM);
    }
}
