//! NIfTI-1/2 reader and writer.
//!
//! Headers are built byte by byte here (both byte orders, both versions) from the layouts in
//! nifti1.h / nifti2.h, independently of the reader. Laws: the geometry method follows the codes
//! (sform > qform > pixdim); the sample type follows docs/fixture-manifest.md; write → read is the
//! identity on dims and samples (bit for bit) and on `lps_from_index` within a named tolerance;
//! bad input gives an `Err` naming the file and never panics.

// Exact float comparisons are the point here: samples must round-trip bit for bit.
#![allow(clippy::float_cmp)]

use std::io::Write as _;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Matrix4, Vector3};
use proptest::prelude::*;
use warpbench_io::geometry::{Index, Lps, Transform};
use warpbench_io::nifti::{self, WriteOptions};
use warpbench_io::{Error, ErrorKind, GeometrySource, LoadOptions, Rescale, SampleType, Volume, VoxelData};

/// NIfTI-1 stores geometry as float32: relative rounding 2^-24 of coordinates up to ~1000 mm.
const F32_GEOMETRY_TOL_MM: f64 = 1e-4;
/// NIfTI-2 stores float64: only the RAS↔LPS sign flips and the f64 arithmetic remain.
const F64_GEOMETRY_TOL_MM: f64 = 1e-9;

// ---------------------------------------------------------------------------------------------
// A hand-built header
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ver {
    V1,
    V2,
}

#[derive(Clone, Debug)]
struct Hdr {
    ver: Ver,
    big_endian: bool,
    dim: [i64; 8],
    datatype: i16,
    bitpix: i16,
    pixdim: [f64; 8],
    vox_offset: f64,
    scl_slope: f64,
    scl_inter: f64,
    qform_code: i32,
    sform_code: i32,
    quatern_bcd: [f64; 3],
    qoffset: [f64; 3],
    srow: [[f64; 4]; 3],
    magic: Option<Vec<u8>>,
}

/// Field writer in one byte order.
struct W<'a> {
    b: &'a mut [u8],
    be: bool,
}

macro_rules! put {
    ($($name:ident: $t:ty),*) => {$(
        fn $name(&mut self, off: usize, v: $t) {
            let bytes = if self.be { v.to_be_bytes() } else { v.to_le_bytes() };
            self.b[off..off + bytes.len()].copy_from_slice(&bytes);
        }
    )*};
}

impl W<'_> {
    put!(i16: i16, i32: i32, i64: i64, f32: f32, f64: f64);
}

impl Hdr {
    fn new(ver: Ver, big_endian: bool, dims: &[i64], datatype: i16, bitpix: i16) -> Self {
        let mut dim = [1i64; 8];
        dim[0] = dims.len() as i64;
        dim[1..=dims.len()].copy_from_slice(dims);
        Self {
            ver,
            big_endian,
            dim,
            datatype,
            bitpix,
            pixdim: [1.0; 8],
            vox_offset: if ver == Ver::V1 { 352.0 } else { 544.0 },
            scl_slope: 1.0,
            scl_inter: 0.0,
            qform_code: 0,
            sform_code: 0,
            quatern_bcd: [0.0; 3],
            qoffset: [0.0; 3],
            srow: [[0.0; 4]; 3],
            magic: None,
        }
    }

    fn header(&self) -> Vec<u8> {
        let size = self.vox_offset.max(if self.ver == Ver::V1 { 352.0 } else { 544.0 }) as usize;
        let mut b = vec![0u8; size];
        let mut w = W { b: &mut b, be: self.big_endian };
        match self.ver {
            Ver::V1 => {
                w.i32(0, 348);
                for i in 0..8 {
                    w.i16(40 + 2 * i, self.dim[i] as i16);
                    w.f32(76 + 4 * i, self.pixdim[i] as f32);
                }
                w.i16(70, self.datatype);
                w.i16(72, self.bitpix);
                w.f32(108, self.vox_offset as f32);
                w.f32(112, self.scl_slope as f32);
                w.f32(116, self.scl_inter as f32);
                w.b[123] = 2;
                w.i16(252, self.qform_code as i16);
                w.i16(254, self.sform_code as i16);
                for i in 0..3 {
                    w.f32(256 + 4 * i, self.quatern_bcd[i] as f32);
                    w.f32(268 + 4 * i, self.qoffset[i] as f32);
                    for c in 0..4 {
                        w.f32(280 + 16 * i + 4 * c, self.srow[i][c] as f32);
                    }
                }
                let magic = self.magic.clone().unwrap_or_else(|| b"n+1\0".to_vec());
                b[344..344 + magic.len()].copy_from_slice(&magic);
            }
            Ver::V2 => {
                w.i32(0, 540);
                w.i16(12, self.datatype);
                w.i16(14, self.bitpix);
                for i in 0..8 {
                    w.i64(16 + 8 * i, self.dim[i]);
                    w.f64(104 + 8 * i, self.pixdim[i]);
                }
                w.i64(168, self.vox_offset as i64);
                w.f64(176, self.scl_slope);
                w.f64(184, self.scl_inter);
                w.i32(344, self.qform_code);
                w.i32(348, self.sform_code);
                for i in 0..3 {
                    w.f64(352 + 8 * i, self.quatern_bcd[i]);
                    w.f64(376 + 8 * i, self.qoffset[i]);
                    for c in 0..4 {
                        w.f64(400 + 32 * i + 8 * c, self.srow[i][c]);
                    }
                }
                w.i32(500, 2);
                let magic = self.magic.clone().unwrap_or_else(|| b"n+2\0\r\n\x1a\n".to_vec());
                b[4..4 + magic.len()].copy_from_slice(&magic);
            }
        }
        b
    }

    /// The whole file: header, extension flag and padding up to vox_offset, then `data`.
    fn file(&self, data: &[u8]) -> Vec<u8> {
        let mut f = self.header();
        f.extend_from_slice(data);
        f
    }
}

/// Encodes samples in the header's byte order.
macro_rules! encode {
    ($name:ident, $t:ty) => {
        fn $name(v: &[$t], be: bool) -> Vec<u8> {
            v.iter().flat_map(|x| if be { x.to_be_bytes() } else { x.to_le_bytes() }).collect()
        }
    };
}
encode!(enc_i8, i8);
encode!(enc_i16, i16);
encode!(enc_u16, u16);
encode!(enc_i32, i32);
encode!(enc_u32, u32);
encode!(enc_i64, i64);
encode!(enc_u64, u64);
encode!(enc_f32, f32);
encode!(enc_f64, f64);

fn name() -> &'static Path {
    Path::new("hand-built.nii")
}

fn read_mem(bytes: &[u8]) -> Result<Volume, Error> {
    nifti::read_bytes(name(), bytes, &mut LoadOptions::new())
}

fn read_mem_with(bytes: &[u8], opts: &mut LoadOptions) -> Result<Volume, Error> {
    nifti::read_bytes(name(), bytes, opts)
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    e.write_all(bytes).expect("gzip into a Vec");
    e.finish().expect("gzip into a Vec")
}

fn all_orders() -> [(Ver, bool); 4] {
    [(Ver::V1, false), (Ver::V1, true), (Ver::V2, false), (Ver::V2, true)]
}

fn expect_err(r: Result<Volume, Error>, what: &str) -> Error {
    match r {
        Ok(v) => panic!("{what}: expected an error, read {:?} {:?}", v.dims, v.data),
        Err(e) => e,
    }
}

fn lps_matrix(v: &Volume) -> Matrix4<f64> {
    *v.lps_from_index.matrix()
}

fn lps_from_ras_rows(ras: [[f64; 4]; 3]) -> Matrix4<f64> {
    let mut m = Matrix4::identity();
    for (r, row) in ras.iter().enumerate() {
        let sign = if r < 2 { -1.0 } else { 1.0 };
        for (c, &v) in row.iter().enumerate() {
            m[(r, c)] = sign * v;
        }
    }
    m
}

/// A seeded splitmix64, for reproducible test data.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

// ---------------------------------------------------------------------------------------------
// Geometry
// ---------------------------------------------------------------------------------------------

#[test]
fn sform_takes_precedence_over_qform() {
    // Values exact in float32, so both versions give the same matrix.
    let srow = [[0.0, -1.5, 0.25, 90.5], [2.0, 0.0, 0.0, -126.0], [0.0, 0.5, 3.0, -72.25]];
    for (ver, be) in all_orders() {
        let mut h = Hdr::new(ver, be, &[3, 2, 2], 4, 16);
        h.sform_code = 2;
        h.srow = srow;
        h.qform_code = 1;
        h.quatern_bcd = [0.0, 0.0, 1.0];
        h.qoffset = [1.0, 2.0, 3.0];
        let data: Vec<i16> = (0..12).map(|x| x * 1000 - 5000).collect();
        let v = read_mem(&h.file(&enc_i16(&data, be))).expect("valid file");
        assert_eq!(v.geometry_source, GeometrySource::NiftiSform { code: 2 }, "{ver:?} be={be}");
        assert_eq!(v.dims, [3, 2, 2]);
        assert_eq!(v.data, VoxelData::I16(data.clone()), "{ver:?} be={be}");
        let diff = (lps_matrix(&v) - lps_from_ras_rows(srow)).abs().max();
        assert!(diff < 1e-12, "{ver:?} be={be}: {diff}");
        assert_eq!(v.rescale, Rescale::IDENTITY);
    }
}

/// The unit-quaternion rotation (nibabel `quat2mat`), an oracle written from the formula.
fn rotation_oracle(b: f64, c: f64, d: f64) -> Matrix3<f64> {
    let a = (1.0 - b * b - c * c - d * d).max(0.0).sqrt();
    let (w, x, y, z) = (a, b, c, d);
    Matrix3::new(
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    )
}

#[test]
fn qform_is_used_when_sform_code_is_zero() {
    let bcd = [0.1, -0.2, 0.3];
    let offset = [-10.5, 20.25, 30.0];
    for (ver, be) in all_orders() {
        for qfac in [1.0, -1.0, 0.0] {
            let mut h = Hdr::new(ver, be, &[2, 3, 4], 2, 8);
            h.qform_code = 1;
            h.sform_code = 0;
            h.srow = [[9.0; 4]; 3]; // ignored: sform_code is 0
            h.quatern_bcd = bcd;
            h.qoffset = offset;
            h.pixdim = [qfac, 0.5, 2.0, 3.0, 1.0, 1.0, 1.0, 1.0];
            let v = read_mem(&h.file(&[7u8; 24])).expect("valid file");
            assert_eq!(v.geometry_source, GeometrySource::NiftiQform { code: 1 });
            // qfac: -1 when pixdim[0] < 0, else (also for 0) 1.
            let k_sign = if qfac < 0.0 { -1.0 } else { 1.0 };
            let linear =
                rotation_oracle(bcd[0], bcd[1], bcd[2]) * Matrix3::from_diagonal(&Vector3::new(0.5, 2.0, 3.0 * k_sign));
            let mut ras = [[0.0; 4]; 3];
            for r in 0..3 {
                for c in 0..3 {
                    ras[r][c] = linear[(r, c)];
                }
                ras[r][3] = offset[r];
            }
            let tol = if ver == Ver::V1 { 1e-6 } else { 1e-12 };
            let diff = (lps_matrix(&v) - lps_from_ras_rows(ras)).abs().max();
            assert!(diff < tol, "{ver:?} be={be} qfac={qfac}: {diff}");
        }
    }
}

#[test]
fn qform_with_a_180_degree_turn_normalises_the_quaternion() {
    // b² + c² + d² slightly above 1 (float32 rounding): a = 0, (b, c, d) normalised.
    let mut h = Hdr::new(Ver::V1, false, &[2, 2, 2], 2, 8);
    h.qform_code = 1;
    h.quatern_bcd = [1.000_000_1, 0.0, 0.0];
    let v = read_mem(&h.file(&[0u8; 8])).expect("valid file");
    let want = Matrix4::from_diagonal(&nalgebra::Vector4::new(-1.0, 1.0, -1.0, 1.0)); // LPS of diag(1, -1, -1)
    assert!((lps_matrix(&v) - want).abs().max() < 1e-6, "{:?}", v.lps_from_index);
}

#[test]
fn pixdim_fallback_uses_magnitudes_and_zero_origin() {
    for (ver, be) in all_orders() {
        let mut h = Hdr::new(ver, be, &[2, 2, 2], 2, 8);
        h.pixdim = [0.0, -2.0, 3.0, 0.5, 0.0, 0.0, 0.0, 0.0];
        h.srow = [[5.0; 4]; 3];
        h.quatern_bcd = [0.5, 0.5, 0.5];
        let v = read_mem(&h.file(&[1u8; 8])).expect("negative pixdim is read, not a panic");
        assert_eq!(v.geometry_source, GeometrySource::NiftiPixdim);
        let want = Matrix4::from_diagonal(&nalgebra::Vector4::new(-2.0, -3.0, 0.5, 1.0));
        assert!((lps_matrix(&v) - want).abs().max() < 1e-12, "{ver:?}: {:?}", v.lps_from_index);
    }
}

#[test]
fn two_d_images_get_a_unit_slice_spacing_when_pixdim3_is_zero() {
    let mut h = Hdr::new(Ver::V1, false, &[3, 2], 2, 8);
    h.pixdim = [1.0, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0];
    let v = read_mem(&h.file(&[1u8; 6])).expect("2-D image");
    assert_eq!(v.dims, [3, 2, 1]);
    assert!((v.spacing_mm()[2] - 1.0).abs() < 1e-12);
}

// ---------------------------------------------------------------------------------------------
// Samples and rescale
// ---------------------------------------------------------------------------------------------

/// One rescale case: stored bytes, slope, intercept and the expected samples.
fn scaled(
    ver: Ver,
    be: bool,
    datatype: i16,
    bitpix: i16,
    data: &[u8],
    slope: f64,
    inter: f64,
) -> Result<Volume, Error> {
    let n = (data.len() * 8 / bitpix as usize) as i64;
    let mut h = Hdr::new(ver, be, &[n, 1, 1], datatype, bitpix);
    h.scl_slope = slope;
    h.scl_inter = inter;
    read_mem(&h.file(data))
}

#[test]
fn identity_rescale_keeps_or_widens_the_stored_type() {
    for (ver, be) in all_orders() {
        let ok = |dt, bits, data: Vec<u8>| scaled(ver, be, dt, bits, &data, 1.0, 0.0).expect("valid file");
        assert_eq!(ok(2, 8, vec![0, 255, 7]).data, VoxelData::U8(vec![0, 255, 7]));
        assert_eq!(ok(256, 8, enc_i8(&[-128, 127, 0], be)).data, VoxelData::I16(vec![-128, 127, 0]));
        assert_eq!(ok(4, 16, enc_i16(&[-32768, 32767], be)).data, VoxelData::I16(vec![-32768, 32767]));
        assert_eq!(ok(512, 16, enc_u16(&[0, 65535], be)).data, VoxelData::U16(vec![0, 65535]));
        assert_eq!(ok(16, 32, enc_f32(&[-1.5, 1e30], be)).data, VoxelData::F32(vec![-1.5, 1e30]));
        assert_eq!(ok(8, 32, enc_i32(&[-70000, 16_777_217], be)).data, VoxelData::F32(vec![-70000.0, 16_777_216.0]));
        assert_eq!(ok(768, 32, enc_u32(&[4_000_000_000], be)).data, VoxelData::F32(vec![4e9]));
        assert_eq!(ok(1024, 64, enc_i64(&[-5, 1 << 40], be)).data, VoxelData::F32(vec![-5.0, 1_099_511_627_776.0]));
        assert_eq!(ok(1280, 64, enc_u64(&[u64::MAX], be)).data, VoxelData::F32(vec![u64::MAX as f32]));
        let v = ok(64, 64, enc_f64(&[0.1, -2.5], be));
        assert_eq!(v.data, VoxelData::F32(vec![0.1f64 as f32, -2.5]));
        assert_eq!(v.rescale, Rescale::IDENTITY);
    }
}

#[test]
fn slope_zero_or_nan_means_no_scaling() {
    for (ver, be) in all_orders() {
        for slope in [0.0, f64::NAN, f64::INFINITY] {
            let v = scaled(ver, be, 2, 8, &[3, 4], slope, 100.0).expect("valid file");
            assert_eq!(v.data, VoxelData::U8(vec![3, 4]), "{ver:?} slope {slope}");
            assert_eq!(v.rescale, Rescale::IDENTITY);
        }
    }
}

#[test]
fn integer_rescale_picks_i16_then_u16_then_f32() {
    for (ver, be) in all_orders() {
        // CT-like: slope 1, intercept -1024 → i16.
        let v = scaled(ver, be, 512, 16, &enc_u16(&[0, 1024, 4095], be), 1.0, -1024.0).expect("valid");
        assert_eq!(v.data, VoxelData::I16(vec![-1024, 0, 3071]));
        assert_eq!(v.rescale, Rescale { slope: 1.0, intercept: -1024.0, applied: true });
        // Above i16 but within u16 → u16.
        let v = scaled(ver, be, 4, 16, &enc_i16(&[0, 30000], be), 2.0, 1.0).expect("valid");
        assert_eq!(v.data, VoxelData::U16(vec![1, 60001]));
        // Negative and above i16 → f32.
        let v = scaled(ver, be, 4, 16, &enc_i16(&[-1, 30000], be), 2.0, 0.0).expect("valid");
        assert_eq!(v.data, VoxelData::F32(vec![-2.0, 60000.0]));
        // u8 with an integer rescale → i16.
        let v = scaled(ver, be, 2, 8, &[0, 255], 3.0, -5.0).expect("valid");
        assert_eq!(v.data, VoxelData::I16(vec![-5, 760]));
        // Float samples that land on integers → i16; a fraction → f32.
        let v = scaled(ver, be, 16, 32, &enc_f32(&[1.5, -2.0], be), 2.0, 0.0).expect("valid");
        assert_eq!(v.data, VoxelData::I16(vec![3, -4]));
        let v = scaled(ver, be, 16, 32, &enc_f32(&[0.25], be), 2.0, 0.0).expect("valid");
        assert_eq!(v.data, VoxelData::F32(vec![0.5]));
        let v = scaled(ver, be, 16, 32, &enc_f32(&[f32::NAN], be), 2.0, 0.0).expect("valid");
        assert!(matches!(&v.data, VoxelData::F32(x) if x[0].is_nan()));
    }
}

#[test]
fn non_integer_rescale_gives_f32_from_float64_arithmetic() {
    let (slope, inter) = (0.075_406_968_593_597_41, 3_100.761_718_75); // both exact in float32
    for (ver, be) in all_orders() {
        let stored = [-100i16, 0, 12345];
        let v = scaled(ver, be, 4, 16, &enc_i16(&stored, be), slope, inter).expect("valid");
        let want: Vec<f32> = stored.iter().map(|&s| (slope * f64::from(s) + inter) as f32).collect();
        assert_eq!(v.data, VoxelData::F32(want));
        assert_eq!(v.rescale, Rescale { slope, intercept: inter, applied: true });
        let v = scaled(ver, be, 2, 8, &[1, 2], 1.0, 0.5).expect("valid");
        assert_eq!(v.data, VoxelData::F32(vec![1.5, 2.5]));
    }
}

#[test]
fn valid_slope_with_nan_intercept_is_an_error() {
    let e = expect_err(scaled(Ver::V2, false, 2, 8, &[1], 2.0, f64::NAN), "NaN scl_inter");
    assert!(e.to_string().contains("scl_inter"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// 4-D
// ---------------------------------------------------------------------------------------------

fn four_d(ver: Ver, be: bool, frames: i64) -> Vec<u8> {
    let h = Hdr::new(ver, be, &[2, 2, 1, frames], 4, 16);
    let data: Vec<i16> = (0..4 * frames as i16).collect();
    h.file(&enc_i16(&data, be))
}

#[test]
fn four_d_reads_the_chosen_frame() {
    for (ver, be) in all_orders() {
        for gz in [false, true] {
            let mut bytes = four_d(ver, be, 3);
            if gz {
                bytes = gzip(&bytes);
            }
            let e = expect_err(read_mem(&bytes), "4-D without a frame");
            let msg = e.to_string();
            assert!(msg.contains("frame") && msg.contains('3') && msg.starts_with("hand-built.nii"), "{msg}");
            for t in 0..3i16 {
                let v = read_mem_with(&bytes, &mut LoadOptions::new().frame(t as usize)).expect("frame in range");
                assert_eq!(v.dims, [2, 2, 1]);
                assert_eq!(v.data, VoxelData::I16((4 * t..4 * t + 4).collect()), "{ver:?} be={be} gz={gz} t={t}");
            }
            let e = expect_err(read_mem_with(&bytes, &mut LoadOptions::new().frame(3)), "frame 3 of 3");
            assert!(e.to_string().contains("frame 3"), "{e}");
        }
    }
}

#[test]
fn a_single_frame_needs_no_frame_option_and_accepts_frame_zero() {
    let bytes = four_d(Ver::V1, false, 1);
    assert_eq!(read_mem(&bytes).expect("nt = 1").dims, [2, 2, 1]);
    read_mem_with(&bytes, &mut LoadOptions::new().frame(0)).expect("frame 0 of a 3-D file");
    expect_err(read_mem_with(&bytes, &mut LoadOptions::new().frame(1)), "frame 1 of 1");
}

#[test]
fn dims_beyond_the_fourth_must_be_one() {
    let mut h = Hdr::new(Ver::V1, false, &[2, 1, 1, 1, 1], 2, 8);
    read_mem(&h.file(&[0; 2])).expect("5-D with dim[5] = 1");
    h.dim[5] = 2;
    let e = expect_err(read_mem(&h.file(&[0; 4])), "dim[5] = 2");
    assert!(e.to_string().contains("dim[5]"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Files, gzip, progress
// ---------------------------------------------------------------------------------------------

#[test]
fn files_and_gzip_are_read_by_content() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (ver, be) in all_orders() {
        let mut h = Hdr::new(ver, be, &[4, 3, 2], 512, 16);
        h.vox_offset = if ver == Ver::V1 { 400.0 } else { 600.0 }; // an extension-sized gap
        let data: Vec<u16> = (0..24).map(|x| x * 2000).collect();
        let bytes = h.file(&enc_u16(&data, be));
        let plain = dir.path().join("a.nii");
        let packed = dir.path().join("a.nii.gz");
        std::fs::write(&plain, &bytes).expect("write");
        std::fs::write(&packed, gzip(&bytes)).expect("write");
        for p in [&plain, &packed] {
            let v = warpbench_io::open(p).expect("open");
            assert_eq!(v.data, VoxelData::U16(data.clone()), "{ver:?} be={be} {}", p.display());
            let v2 = nifti::read_bytes(p, &std::fs::read(p).expect("read"), &mut LoadOptions::new()).expect("bytes");
            assert_eq!(v2, v);
        }
    }
}

#[test]
fn progress_is_reported_and_cancellation_propagates() {
    let h = Hdr::new(Ver::V1, false, &[256, 256, 40], 4, 16); // 5 MiB: two chunks
    let bytes = h.file(&vec![0u8; 256 * 256 * 40 * 2]);
    for bytes in [bytes.clone(), gzip(&bytes)] {
        let mut seen = Vec::new();
        let v = nifti::read_bytes(
            name(),
            &bytes,
            &mut LoadOptions::new().progress(|p| {
                seen.push((p.stage, p.done, p.total));
                ControlFlow::Continue(())
            }),
        )
        .expect("valid file");
        assert_eq!(v.dims, [256, 256, 40]);
        let frame_bytes = 256 * 256 * 40 * 2;
        assert!(seen.len() >= 3, "{seen:?}");
        let &(stage, done, total) = seen.last().expect("reports");
        assert_eq!(stage, "reading");
        assert!(done == total && total >= frame_bytes, "{seen:?}");
        assert!(seen.windows(2).all(|w| w[0].1 <= w[1].1));

        let mut calls = 0;
        let e = nifti::read_bytes(
            name(),
            &bytes,
            &mut LoadOptions::new().progress(|_| {
                calls += 1;
                if calls > 1 { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
            }),
        )
        .expect_err("cancelled");
        assert!(matches!(e.kind, ErrorKind::Cancelled), "{e}");
    }
}

// ---------------------------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------------------------

/// A realistic oblique geometry: 15° about z then 10° about x, anisotropic spacing, origin ~100 mm away.
fn oblique(improper: bool) -> Transform<Lps, Index> {
    let (a, b) = (15f64.to_radians(), 10f64.to_radians());
    let rz = Matrix3::new(a.cos(), -a.sin(), 0.0, a.sin(), a.cos(), 0.0, 0.0, 0.0, 1.0);
    let rx = Matrix3::new(1.0, 0.0, 0.0, 0.0, b.cos(), -b.sin(), 0.0, b.sin(), b.cos());
    let k = if improper { -1.2 } else { 1.2 };
    let linear = rz * rx * Matrix3::from_diagonal(&Vector3::new(0.488_281_25, 0.7, k));
    Transform::from_linear_translation(linear, [-123.456, 98.765, -301.5])
}

fn sample_data(t: SampleType, n: usize, seed: u64) -> VoxelData {
    let mut rng = Rng(seed);
    match t {
        SampleType::U8 => VoxelData::U8((0..n).map(|_| rng.next() as u8).collect()),
        SampleType::I16 => VoxelData::I16((0..n).map(|_| rng.next() as i16).collect()),
        SampleType::U16 => VoxelData::U16((0..n).map(|_| rng.next() as u16).collect()),
        SampleType::F32 => {
            let mut v: Vec<f32> = (0..n).map(|_| f32::from_bits(rng.next() as u32)).collect();
            v[0] = f32::NAN;
            v[1] = -0.0;
            VoxelData::F32(v)
        }
    }
}

fn volume(t: SampleType, dims: [usize; 3], lps_from_index: Transform<Lps, Index>) -> Volume {
    let n = dims.iter().product();
    Volume::new(Path::new("mem"), dims, sample_data(t, n, 42), lps_from_index, GeometrySource::NiftiPixdim)
        .expect("valid volume")
}

fn bits(d: &VoxelData) -> Vec<u8> {
    d.to_le_bytes()
}

#[test]
fn write_read_round_trips_every_sample_type() {
    let dir = tempfile::tempdir().expect("tempdir");
    for t in [SampleType::U8, SampleType::I16, SampleType::U16, SampleType::F32] {
        for improper in [false, true] {
            let vol = volume(t, [5, 4, 3], oblique(improper));
            for (nifti2, ext) in [(false, "nii"), (false, "nii.gz"), (true, "nii"), (true, "nii.gz")] {
                let p = dir.path().join(format!("rt-{}-{improper}-{nifti2}.{ext}", t.name()));
                nifti::write_with(&p, &vol, WriteOptions { nifti2 }).expect("write");
                let head = std::fs::read(&p).expect("read back");
                assert_eq!(head.starts_with(&[0x1f, 0x8b]), ext.ends_with("gz"));
                let back = warpbench_io::open(&p).expect("read written file");
                assert_eq!(back.dims, vol.dims);
                assert_eq!(back.sample_type(), t);
                assert_eq!(bits(&back.data), bits(&vol.data), "{} {ext} nifti2={nifti2}", t.name());
                assert_eq!(back.geometry_source, GeometrySource::NiftiSform { code: 1 });
                assert_eq!(back.rescale, Rescale::IDENTITY);
                let tol = if nifti2 { F64_GEOMETRY_TOL_MM } else { F32_GEOMETRY_TOL_MM };
                let err = back.lps_from_index.max_abs_diff(&vol.lps_from_index);
                assert!(err < tol, "{} nifti2={nifti2}: {err}", t.name());
            }
        }
    }
}

#[test]
fn default_write_is_nifti1_with_the_documented_header() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("h.nii");
    let mut vol = volume(SampleType::I16, [3, 2, 2], oblique(false));
    vol.metadata.description = Some("a description".into());
    nifti::write(&p, &vol).expect("write");
    let b = std::fs::read(&p).expect("read");
    let i16_at = |o: usize| i16::from_le_bytes([b[o], b[o + 1]]);
    let f32_at = |o: usize| f32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    assert_eq!(i32::from_le_bytes([b[0], b[1], b[2], b[3]]), 348);
    assert_eq!(&b[344..348], b"n+1\0");
    assert_eq!(b.len(), 352 + 12 * 2);
    assert_eq!(f32_at(108), 352.0);
    assert_eq!((f32_at(112), f32_at(116)), (1.0, 0.0));
    assert_eq!((i16_at(70), i16_at(72)), (4, 16));
    assert_eq!((i16_at(252), i16_at(254)), (1, 1));
    assert_eq!(b[123], 2, "xyzt_units = mm");
    assert_eq!(&b[348..352], &[0, 0, 0, 0], "no extensions");
    assert_eq!(&b[148..161], b"a description");
    assert_eq!(warpbench_io::open(&p).expect("read").metadata.description.as_deref(), Some("a description"));
}

/// Clears sform_code in a written NIfTI-1 file, so a reader must use the qform.
fn drop_sform(p: &Path) {
    let mut b = std::fs::read(p).expect("read");
    b[254] = 0;
    b[255] = 0;
    std::fs::write(p, b).expect("write");
}

#[test]
fn written_qform_matches_the_sform_for_rigid_geometry() {
    let dir = tempfile::tempdir().expect("tempdir");
    let flip = Transform::from_scale_translation([-0.9, 0.9, 1.5], [122.0, -122.0, -80.25]);
    for (i, geom) in [oblique(false), oblique(true), flip, Transform::identity()].into_iter().enumerate() {
        let p = dir.path().join(format!("q{i}.nii"));
        nifti::write(&p, &volume(SampleType::U8, [4, 4, 4], geom)).expect("write");
        drop_sform(&p);
        let back = warpbench_io::open(&p).expect("read");
        assert_eq!(back.geometry_source, GeometrySource::NiftiQform { code: 1 });
        let err = back.lps_from_index.max_abs_diff(&geom);
        assert!(err < F32_GEOMETRY_TOL_MM, "case {i}: {err} {:?} vs {geom:?}", back.lps_from_index);
    }
}

#[test]
fn sheared_geometry_keeps_an_exact_sform_and_an_approximate_qform() {
    let dir = tempfile::tempdir().expect("tempdir");
    let linear = Matrix3::new(1.0, 0.3, 0.0, 0.0, 1.0, 0.0, 0.0, 0.1, 2.0);
    let geom = Transform::from_linear_translation(linear, [10.0, 20.0, 30.0]);
    let p = dir.path().join("shear.nii.gz");
    nifti::write(&p, &volume(SampleType::F32, [3, 3, 3], geom)).expect("write");
    let back = warpbench_io::open(&p).expect("read");
    assert!(back.lps_from_index.max_abs_diff(&geom) < F32_GEOMETRY_TOL_MM);
    let p = dir.path().join("shear.nii");
    nifti::write(&p, &volume(SampleType::F32, [3, 3, 3], geom)).expect("write");
    drop_sform(&p);
    let q = warpbench_io::open(&p).expect("read qform");
    // The qform keeps the column lengths and the origin; only the shear is lost.
    assert!((q.spacing_mm()[1] - back.spacing_mm()[1]).abs() < 1e-5);
    assert!((q.lps_from_index.translation()[0] - 10.0).abs() < 1e-5);
    assert!(q.lps_from_index.max_abs_diff(&geom) > 0.01);
}

#[test]
fn nifti1_refuses_dims_over_32767_and_nifti2_takes_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    let vol = volume(SampleType::U8, [40_000, 1, 1], Transform::identity());
    let p = dir.path().join("long.nii");
    let e = nifti::write(&p, &vol).expect_err("dims over i16");
    assert!(e.to_string().contains("NIfTI-2"), "{e}");
    assert!(!p.exists());
    nifti::write_with(&p, &vol, WriteOptions { nifti2: true }).expect("NIfTI-2");
    assert_eq!(warpbench_io::open(&p).expect("read").dims, [40_000, 1, 1]);
}

#[test]
fn writing_is_atomic_and_never_touches_the_input() {
    let dir = tempfile::tempdir().expect("tempdir");
    let input = dir.path().join("in.nii.gz");
    let vol = volume(SampleType::I16, [6, 5, 4], oblique(false));
    nifti::write(&input, &vol).expect("write");
    let before = std::fs::read(&input).expect("read");
    let modified = std::fs::metadata(&input).and_then(|m| m.modified()).expect("mtime");

    let read = warpbench_io::open(&input).expect("read");
    nifti::write(&dir.path().join("out.nii"), &read).expect("write copy");
    assert_eq!(std::fs::read(&input).expect("read"), before);
    assert_eq!(std::fs::metadata(&input).and_then(|m| m.modified()).expect("mtime"), modified);

    // A missing directory: an error naming the file, nothing created.
    let missing = dir.path().join("no-such-dir").join("out.nii");
    let e = nifti::write(&missing, &vol).expect_err("missing directory");
    assert!(e.to_string().contains("out.nii"), "{e}");
    assert!(!dir.path().join("no-such-dir").exists());

    // An inconsistent volume fails before anything is written, and an existing output survives.
    let mut bad = vol.clone();
    bad.dims = [7, 5, 4];
    let out = dir.path().join("out.nii");
    let copy = std::fs::read(&out).expect("read");
    nifti::write(&out, &bad).expect_err("wrong sample count");
    assert_eq!(std::fs::read(&out).expect("read"), copy);
    let names: Vec<PathBuf> = std::fs::read_dir(dir.path()).expect("ls").map(|e| e.expect("entry").path()).collect();
    assert_eq!(names.len(), 2, "leftover files: {names:?}");
}

// ---------------------------------------------------------------------------------------------
// Bad input
// ---------------------------------------------------------------------------------------------

fn small_valid(ver: Ver, be: bool) -> Vec<u8> {
    let mut h = Hdr::new(ver, be, &[4, 3, 2], 16, 32);
    h.sform_code = 1;
    h.srow = [[1.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 2.0], [0.0, 0.0, 1.0, 3.0]];
    let data: Vec<f32> = (0..24).map(|x| x as f32 * 0.5).collect();
    h.file(&enc_f32(&data, be))
}

fn assert_names_file(e: &Error, file: &str) {
    assert!(e.to_string().starts_with(file), "error does not name {file}: {e}");
}

#[test]
fn truncated_files_fail_with_the_file_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (ver, be) in all_orders() {
        let full = small_valid(ver, be);
        let header = if ver == Ver::V1 { 348 } else { 540 };
        for cut in [0, 3, 4, 100, header - 1, header, header + 3, full.len() - 50, full.len() - 1] {
            let part = &full[..cut];
            let e = expect_err(read_mem(part), &format!("cut at {cut}"));
            assert_names_file(&e, "hand-built.nii");
            if cut >= 4 {
                assert!(matches!(e.kind, ErrorKind::Truncated(_)), "cut at {cut}: {e}");
            }
            let e = expect_err(read_mem(&gzip(part)), &format!("gzip cut at {cut}"));
            assert_names_file(&e, "hand-built.nii");
            let p = dir.path().join("cut.nii");
            std::fs::write(&p, part).expect("write");
            let e = expect_err(nifti::read(&p, &mut LoadOptions::new()), "cut file");
            assert!(e.to_string().contains("cut.nii"), "{e}");
        }
        // A gzip stream cut short (rather than a short file in a complete stream).
        let gz = gzip(&full);
        for cut in [5, 10, gz.len() / 2] {
            let e = expect_err(read_mem(&gz[..cut]), &format!("gzip stream cut at {cut}"));
            assert_names_file(&e, "hand-built.nii");
        }
    }
}

#[test]
fn random_bytes_and_wrong_magic_are_rejected() {
    let mut rng = Rng(7);
    for len in [0, 1, 100, 348, 540, 1000, 5000] {
        let bytes: Vec<u8> = (0..len).map(|_| rng.next() as u8).collect();
        assert_names_file(&expect_err(read_mem(&bytes), "random bytes"), "hand-built.nii");
    }
    for (ver, be) in all_orders() {
        let mut h = Hdr::new(ver, be, &[2, 2, 2], 2, 8);
        h.magic = Some(b"xyz\0".to_vec());
        let e = expect_err(read_mem(&h.file(&[0; 8])), "bad magic");
        assert!(e.to_string().to_lowercase().contains("not a nifti"), "{e}");
        h.magic = Some(if ver == Ver::V1 { b"ni1\0".to_vec() } else { b"ni2\0\r\n\x1a\n".to_vec() });
        let e = expect_err(read_mem(&h.file(&[0; 8])), "pair file");
        assert!(e.to_string().contains("pair"), "{e}");
    }
    let mut h = Hdr::new(Ver::V2, false, &[2, 2, 2], 2, 8);
    h.magic = Some(b"n+2\0\n\x1a\n\0".to_vec());
    let e = expect_err(read_mem(&h.file(&[0; 8])), "text-mode NIfTI-2");
    assert!(e.to_string().contains("text mode"), "{e}");
}

#[test]
fn impossible_header_fields_are_errors() {
    type Edit = fn(&mut Hdr);
    let cases: [(&str, Edit, &str); 14] = [
        ("dim[0] = 0", |h| h.dim[0] = 0, "dim[0]"),
        ("dim[0] = 8", |h| h.dim[0] = 8, "dim[0]"),
        ("dim[0] = -1", |h| h.dim[0] = -1, "dim[0]"),
        ("negative dim", |h| h.dim[2] = -3, "dim[2]"),
        ("zero dim", |h| h.dim[1] = 0, "dim[1]"),
        ("complex", |h| (h.datatype, h.bitpix) = (32, 64), "unsupported datatype 32"),
        ("rgb", |h| (h.datatype, h.bitpix) = (128, 24), "unsupported datatype 128"),
        ("bitpix", |h| h.bitpix = 16, "bitpix"),
        ("vox_offset in header", |h| h.vox_offset = 100.0, "vox_offset"),
        ("vox_offset negative", |h| h.vox_offset = -1.0, "vox_offset"),
        ("NaN in srow", |h| (h.sform_code, h.srow[1][2]) = (1, f64::NAN), "sform"),
        ("singular sform", |h| h.sform_code = 1, "singular"),
        ("NaN pixdim", |h| h.pixdim[2] = f64::NAN, "pixdim[2]"),
        ("zero pixdim", |h| h.pixdim[1] = 0.0, "pixdim[1]"),
    ];
    for (ver, be) in all_orders() {
        for (what, edit, needle) in cases {
            let mut h = Hdr::new(ver, be, &[2, 2, 2], 2, 8);
            edit(&mut h);
            let e = expect_err(read_mem(&h.file(&[0; 8])), what);
            assert_names_file(&e, "hand-built.nii");
            assert!(e.to_string().contains(needle), "{what} ({ver:?}): {e}");
        }
        let mut h = Hdr::new(ver, be, &[2, 2, 2], 2, 8);
        (h.qform_code, h.qoffset[0]) = (1, f64::INFINITY);
        let e = expect_err(read_mem(&h.file(&[0; 8])), "infinite qoffset");
        assert!(e.to_string().contains("qform"), "{e}");
    }
}

#[test]
fn huge_dims_fail_before_allocating() {
    // NIfTI-2: three dims near 2^63 overflow even u128 byte arithmetic.
    let h = Hdr::new(Ver::V2, false, &[i64::MAX, i64::MAX, i64::MAX], 64, 64);
    let e = expect_err(read_mem(&h.file(&[0; 8])), "overflowing dims");
    assert!(matches!(e.kind, ErrorKind::TooLarge { .. }), "{e}");
    // NIfTI-1: 32767³ f64 = 2.8e14 bytes, over the default limit.
    let h = Hdr::new(Ver::V1, true, &[32767, 32767, 32767], 64, 64);
    let e = expect_err(read_mem(&h.file(&[0; 8])), "32767³");
    assert!(matches!(e.kind, ErrorKind::TooLarge { .. }), "{e}");
    // A small volume over a small limit, even compressed.
    let bytes = small_valid(Ver::V1, false);
    for bytes in [bytes.clone(), gzip(&bytes)] {
        let e = expect_err(read_mem_with(&bytes, &mut LoadOptions::new().max_voxel_bytes(95)), "over the limit");
        assert!(matches!(e.kind, ErrorKind::TooLarge { .. }), "{e}");
        read_mem_with(&bytes, &mut LoadOptions::new().max_voxel_bytes(96)).expect("at the limit");
    }
    // The limit also holds for the output type when it is wider than the stored one.
    let h = Hdr::new(Ver::V1, false, &[10, 1, 1], 256, 8);
    let e = expect_err(read_mem_with(&h.file(&[0; 10]), &mut LoadOptions::new().max_voxel_bytes(15)), "i8 → i16");
    assert!(matches!(e.kind, ErrorKind::TooLarge { .. }), "{e}");
    let mut h = Hdr::new(Ver::V1, false, &[10, 1, 1], 2, 8);
    h.scl_slope = 0.5;
    let e = expect_err(read_mem_with(&h.file(&[0; 10]), &mut LoadOptions::new().max_voxel_bytes(39)), "u8 → f32");
    assert!(matches!(e.kind, ErrorKind::TooLarge { .. }), "{e}");
    read_mem_with(&h.file(&[0; 10]), &mut LoadOptions::new().max_voxel_bytes(40)).expect("f32 at the limit");
    // Dims that fit the limit but not the file: truncated, checked before allocating.
    let h = Hdr::new(Ver::V1, false, &[1000, 1000, 1000], 2, 8);
    let e = expect_err(read_mem(&h.file(&[0; 8])), "dims past EOF");
    assert!(matches!(e.kind, ErrorKind::Truncated(_)), "{e}");
}

#[test]
fn vox_offset_past_the_end_is_truncated() {
    for (ver, be) in all_orders() {
        let h = Hdr::new(ver, be, &[2, 2, 2], 2, 8);
        let mut bytes = h.file(&[0; 8]);
        let off = if ver == Ver::V1 { 108 } else { 168 };
        let mut w = W { b: &mut bytes, be };
        if ver == Ver::V1 {
            w.f32(off, 1.0e6);
        } else {
            w.i64(off, i64::MAX);
        }
        let e = expect_err(read_mem(&bytes), "vox_offset past EOF");
        assert!(matches!(e.kind, ErrorKind::Truncated(_) | ErrorKind::Invalid(_)), "{e}");
        let e = expect_err(read_mem(&gzip(&bytes)), "vox_offset past EOF, gzip");
        assert!(matches!(e.kind, ErrorKind::Truncated(_) | ErrorKind::Invalid(_)), "{e}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    /// Random byte edits of a valid file (either version, either order, plain or gzip) never panic;
    /// any error names the file.
    #[test]
    fn mutated_files_never_panic(
        which in 0usize..4,
        gz in any::<bool>(),
        edits in prop::collection::vec((0usize..700, any::<u8>()), 1..12),
        cut in prop::option::of(0usize..700),
    ) {
        let (ver, be) = all_orders()[which];
        let mut bytes = small_valid(ver, be);
        for (pos, val) in edits {
            let n = bytes.len();
            bytes[pos % n] = val;
        }
        if let Some(c) = cut {
            bytes.truncate(c.min(bytes.len()));
        }
        if gz {
            bytes = gzip(&bytes);
        }
        let r = read_mem_with(&bytes, &mut LoadOptions::new().max_voxel_bytes(1 << 20).frame(0));
        if let Err(e) = r {
            prop_assert!(e.to_string().starts_with("hand-built.nii"), "{}", e);
        }
    }

    /// Header fields set to arbitrary values in the places that drive sizes and geometry.
    #[test]
    fn arbitrary_size_and_geometry_fields_never_panic(
        which in 0usize..4,
        dim in prop::array::uniform8(any::<i64>()),
        pixdim in prop::array::uniform8(any::<f64>()),
        vox_offset in any::<f64>(),
        codes in (any::<i16>(), any::<i16>()),
        datatype in prop::sample::select(vec![2i16, 4, 8, 16, 64, 256, 512, 768, 1024, 1280, 32, 0, -1]),
        bcd in prop::array::uniform3(any::<f64>()),
    ) {
        let (ver, be) = all_orders()[which];
        let mut h = Hdr::new(ver, be, &[2, 2, 2], 2, 8);
        h.dim = if ver == Ver::V1 { dim.map(|d| i64::from(d as i16)) } else { dim };
        h.pixdim = pixdim;
        h.vox_offset = vox_offset.clamp(-1e9, 1e9);
        (h.qform_code, h.sform_code) = (i32::from(codes.0), i32::from(codes.1));
        h.datatype = datatype;
        h.bitpix = 8 * match datatype { 4 | 512 => 2, 8 | 16 | 768 => 4, 64 | 1024 | 1280 => 8, _ => 1 };
        h.quatern_bcd = bcd;
        let bytes = h.file(&[0; 64]);
        let r = read_mem_with(&bytes, &mut LoadOptions::new().max_voxel_bytes(1 << 20));
        if let Err(e) = r {
            prop_assert!(e.to_string().starts_with("hand-built.nii"), "{}", e);
        }
    }

    /// Write → read is the identity on samples and geometry, for random rigid geometries.
    #[test]
    fn round_trip_law(
        angles in prop::array::uniform3(-3.1f64..3.1),
        spacing in prop::array::uniform3(0.2f64..5.0),
        origin in prop::array::uniform3(-400.0f64..400.0),
        improper in any::<bool>(),
        nifti2 in any::<bool>(),
        seed in any::<u64>(),
    ) {
        let rot = nalgebra::Rotation3::from_euler_angles(angles[0], angles[1], angles[2]).into_inner();
        let flip = if improper { -1.0 } else { 1.0 };
        let linear = rot * Matrix3::from_diagonal(&Vector3::new(spacing[0], spacing[1], flip * spacing[2]));
        let geom = Transform::from_linear_translation(linear, origin);
        let vol = Volume::new(Path::new("mem"), [3, 2, 2], sample_data(SampleType::I16, 12, seed), geom, GeometrySource::NiftiPixdim)
            .expect("valid volume");
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("law.nii");
        nifti::write_with(&p, &vol, WriteOptions { nifti2 }).expect("write");
        let back = warpbench_io::open(&p).expect("read");
        prop_assert_eq!(&back.data, &vol.data);
        let tol = if nifti2 { F64_GEOMETRY_TOL_MM } else { F32_GEOMETRY_TOL_MM };
        prop_assert!(back.lps_from_index.max_abs_diff(&geom) < tol);
        // The qform alone reproduces rigid geometry too, except near a 180° turn: there the
        // quaternion's a = √(1 − b² − c² − d²) comes from float32 b, c, d and loses half its digits
        // (a limit of NIfTI-1 itself). The qform stores the RAS rotation diag(−1, −1, 1)·R, so that is
        // the turn to measure (a 73° turn in LPS can be a 176° turn in RAS).
        let ras_rot = Matrix3::from_diagonal(&Vector3::new(-1.0, -1.0, 1.0)) * rot;
        let cos_turn = (ras_rot.trace() - 1.0) / 2.0;
        if !nifti2 && cos_turn > (160f64).to_radians().cos() {
            drop_sform(&p);
            let q = warpbench_io::open(&p).expect("read qform");
            prop_assert!(q.lps_from_index.max_abs_diff(&geom) < F32_GEOMETRY_TOL_MM, "{:?} vs {:?}", q.lps_from_index, geom);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Sanity check against the fixtures, when present (the manifest-driven test is separate)
// ---------------------------------------------------------------------------------------------

#[test]
fn fixtures_match_the_independent_reader_when_present() {
    use sha2::Digest as _;
    use std::fmt::Write as _;
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data");
    let Ok(text) = std::fs::read_to_string(root.join("manifest.json")) else {
        eprintln!("no tests/data/manifest.json: skipped");
        return;
    };
    let manifest: serde_json::Value = serde_json::from_str(&text).expect("manifest is JSON");
    let fixtures = manifest["fixtures"].as_array().expect("fixtures array");
    let mut checked = 0;
    for f in fixtures.iter().filter(|f| f["format"] == "nifti") {
        let id = f["id"].as_str().expect("id");
        let path = root.join(f["path"].as_str().expect("path"));
        let mut opts = LoadOptions::new();
        if let Some(t) = f["options"]["frame"].as_u64() {
            opts = opts.frame(t as usize);
        }
        let r = opts.open(&path);
        if f["expect"] == "error" {
            let e = r.expect_err(id);
            let needle = f["error_contains"].as_str().expect("error_contains");
            assert!(e.to_string().to_lowercase().contains(needle), "{id}: {e}");
            checked += 1;
            continue;
        }
        let v = r.unwrap_or_else(|e| panic!("{id}: {e}"));
        let dims: Vec<usize> =
            f["dims"].as_array().expect("dims").iter().map(|d| d.as_u64().expect("dim") as usize).collect();
        assert_eq!(v.dims.to_vec(), dims, "{id}");
        assert_eq!(v.sample_type().name(), f["dtype"].as_str().expect("dtype"), "{id}");
        let want = match f["geometry_source"].as_str().expect("source") {
            "sform" => matches!(v.geometry_source, GeometrySource::NiftiSform { .. }),
            "qform" => matches!(v.geometry_source, GeometrySource::NiftiQform { .. }),
            _ => matches!(v.geometry_source, GeometrySource::NiftiPixdim),
        };
        assert!(want, "{id}: {:?}", v.geometry_source);
        let rows = v.lps_from_index.rows();
        for (r, row) in f["lps_from_index"].as_array().expect("matrix").iter().enumerate() {
            for (c, x) in row.as_array().expect("row").iter().enumerate() {
                let x = x.as_f64().expect("number");
                assert!((rows[r][c] - x).abs() < 1e-5, "{id}: [{r}][{c}] {} vs {x}", rows[r][c]);
            }
        }
        let digest = sha2::Sha256::digest(v.data.to_le_bytes());
        let hex = digest.iter().fold(String::new(), |mut s, b| {
            let _ = write!(s, "{b:02x}");
            s
        });
        assert_eq!(hex, f["sha256"].as_str().expect("sha256"), "{id}");
        let slope = f["rescale"]["slope"].as_f64().expect("slope");
        assert!((v.rescale.slope - slope).abs() < 1e-12, "{id}");
        checked += 1;
    }
    eprintln!("checked {checked} NIfTI fixtures");
}

// ---------------------------------------------------------------------------------------------
// sform and qform both set (issue 13, item 7), and the frame a 4-D file needs (item 17)
// ---------------------------------------------------------------------------------------------

/// The warning about a disagreeing sform and qform, if the volume has one.
fn sform_qform_warning(v: &Volume) -> Option<&String> {
    v.metadata.warnings.iter().find(|w| w.contains("sform") && w.contains("qform"))
}

/// The largest distance the warning reports, in mm.
fn reported_apart_mm(w: &str) -> f64 {
    let before = w.split(" mm apart").next().expect("a distance");
    before.rsplit(' ').next().expect("a number").parse().unwrap_or_else(|_| panic!("no distance in {w:?}"))
}

#[test]
fn a_sform_and_qform_that_disagree_are_a_warning_naming_both() {
    // jhu189: the qform is a left-right mirror image of the sform, ~150 mm away (ITK puts it elsewhere).
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti/jhu189.nii.gz");
    let v = warpbench_io::open(&p).expect("read jhu189");
    assert!(matches!(v.geometry_source, GeometrySource::NiftiSform { .. }), "{:?}", v.geometry_source);
    let w = sform_qform_warning(&v).unwrap_or_else(|| panic!("no warning in {:?}", v.metadata.warnings));
    assert!(w.contains("sform (code") && w.contains("qform (code"), "{w}");
    assert!(w.contains("opposite handedness") && w.contains("the sform is used"), "{w}");
    let apart = reported_apart_mm(w);
    assert!((100.0..400.0).contains(&apart), "{apart} mm: {w}");

    // Hand-built, both versions and byte orders: the same rotation, origins 5 mm apart along x.
    for (ver, be) in all_orders() {
        let mut h = Hdr::new(ver, be, &[4, 3, 2], 2, 8);
        h.sform_code = 1;
        h.qform_code = 1;
        h.srow = [[1.0, 0.0, 0.0, 10.0], [0.0, 1.0, 0.0, 20.0], [0.0, 0.0, 1.0, 30.0]];
        h.qoffset = [15.0, 20.0, 30.0];
        let v = read_mem(&h.file(&[0; 24])).expect("valid file");
        let w = sform_qform_warning(&v).unwrap_or_else(|| panic!("{ver:?} be={be}: {:?}", v.metadata.warnings));
        assert!(w.contains("same handedness"), "{w}");
        assert!((reported_apart_mm(w) - 5.0).abs() < 0.01, "{w}");
        // The sform is what the volume uses.
        assert_eq!(v.lps_from_index.translation(), [-10.0, -20.0, 30.0]);
    }
}

#[test]
fn a_sform_and_qform_that_agree_give_no_warning() {
    // Our writer stores both (code 1); for a rigid geometry they agree to float32 rounding.
    let dir = tempfile::tempdir().expect("tempdir");
    for (i, geom) in [oblique(false), oblique(true), Transform::identity()].into_iter().enumerate() {
        let p = dir.path().join(format!("both{i}.nii.gz"));
        nifti::write(&p, &volume(SampleType::U8, [64, 64, 48], geom)).expect("write");
        let v = warpbench_io::open(&p).expect("read");
        assert!(v.metadata.warnings.is_empty(), "case {i}: {:?}", v.metadata.warnings);
    }
    // Hand-built: the qform a 180° turn about z with pixdim (2, 2, 3), the sform the same matrix.
    let mut h = Hdr::new(Ver::V1, false, &[4, 3, 2], 2, 8);
    h.sform_code = 2;
    h.qform_code = 1;
    h.quatern_bcd = [0.0, 0.0, 1.0];
    h.pixdim = [1.0, 2.0, 2.0, 3.0, 1.0, 1.0, 1.0, 1.0];
    h.qoffset = [1.0, 2.0, 3.0];
    h.srow = [[-2.0, 0.0, 0.0, 1.0], [0.0, -2.0, 0.0, 2.0], [0.0, 0.0, 3.0, 3.0]];
    let v = read_mem(&h.file(&[0; 24])).expect("valid file");
    assert!(v.metadata.warnings.is_empty(), "{:?}", v.metadata.warnings);
    // Only the sform set: nothing to compare.
    h.qform_code = 0;
    h.qoffset = [100.0; 3];
    assert!(read_mem(&h.file(&[0; 24])).expect("valid file").metadata.warnings.is_empty());
}

#[test]
fn a_four_d_file_without_a_frame_says_how_many_frames_in_the_error_kind() {
    let e = expect_err(read_mem(&four_d(Ver::V1, false, 5)), "4-D without a frame");
    assert!(matches!(e.kind, ErrorKind::FrameRequired { frames: 5 }), "{e}");
    // The library's message names no API: each front end says how to choose (the CLI's --frame).
    let msg = e.to_string();
    assert!(msg.contains("5 frames") && msg.contains("0 to 4") && !msg.contains("LoadOptions"), "{msg}");
}
