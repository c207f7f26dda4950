//! Hostile inputs that once hung, aborted or were accepted with an absurd geometry (issue 13, items 4 to 6).
//!
//! - Anything that is not a regular file (a named pipe, `/dev/zero`) is refused before it is opened, as a volume
//!   and as a detached NRRD data file: every read here must end within [`HANG_LIMIT`].
//! - A stream that really inflates to 2·10⁹ bytes, read under a 1 GiB address-space limit, gives an error naming
//!   the file and the size instead of aborting the process: the reader runs in a child process (this test binary,
//!   re-executed under `ulimit -v`), so an abort fails the test instead of killing it.
//! - A geometry whose spacing is infinite is refused; a spacing outside the plausible range is a warning.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::mpsc;
use std::time::Duration;

use flate2::Compression;
use flate2::write::GzEncoder;
use warpbench_io::{ErrorKind, LoadOptions, Volume};

/// A read that takes longer than this is taken to hang (the slowest of them reads a few hundred bytes).
const HANG_LIMIT: Duration = Duration::from_secs(20);

/// Runs `read` on another thread and returns its result, or fails the test when it does not end in time (the
/// stuck thread is left behind; the test process ends anyway).
fn within_limit(
    what: &str,
    read: impl FnOnce() -> warpbench_io::Result<Volume> + Send + 'static,
) -> warpbench_io::Error {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(read());
    });
    match rx.recv_timeout(HANG_LIMIT) {
        Ok(Ok(v)) => panic!("{what}: read a volume {:?}, expected a refusal", v.dims),
        Ok(Err(e)) => e,
        Err(mpsc::RecvTimeoutError::Timeout) => panic!("{what}: the read did not end within {HANG_LIMIT:?} (it hangs)"),
        Err(mpsc::RecvTimeoutError::Disconnected) => panic!("{what}: the reading thread panicked"),
    }
}

fn mkfifo(path: &Path) {
    let status = Command::new("mkfifo").arg(path).status().expect("run mkfifo");
    assert!(status.success(), "mkfifo {}", path.display());
}

#[test]
fn a_named_pipe_is_refused_before_it_is_opened() {
    let dir = tempfile::tempdir().expect("tempdir");
    // With a known extension, with the DICOM one, and without any (detection by content would read it).
    for name in ["pipe.nii", "pipe.nii.gz", "pipe.nrrd", "pipe.nhdr", "pipe.dcm", "pipe"] {
        let p = dir.path().join(name);
        mkfifo(&p);
        let q = p.clone();
        let e = within_limit(name, move || warpbench_io::open(&q));
        assert!(matches!(e.kind, ErrorKind::NotARegularFile { .. }), "{name}: {e}");
        let msg = e.to_string();
        assert!(msg.starts_with(&p.display().to_string()) && msg.contains("named pipe"), "{msg}");
    }
    let p = dir.path().join("pipe.nii");
    let q = p.clone();
    let e = within_limit("displacement field", move || {
        warpbench_io::nifti::read_displacement_field(&q).map(|_| unreachable!("a pipe holds no field"))
    });
    assert!(matches!(e.kind, ErrorKind::NotARegularFile { .. }), "{e}");
    let q = p.clone();
    let e = within_limit("DICOM file list", move || warpbench_io::dicom::read_files(&[q], &mut LoadOptions::new()));
    assert!(matches!(e.kind, ErrorKind::NotARegularFile { .. }), "{e}");
}

/// A detached header over `data_file`, with `line skip: 1`, in `encoding`.
fn detached(dir: &Path, name: &str, data_file: &Path, encoding: &str) -> PathBuf {
    let p = dir.join(name);
    let header = format!(
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 4 4\nencoding: {encoding}\nline skip: 1\ndata file: {}\n\n",
        data_file.display()
    );
    std::fs::write(&p, header).expect("write the header");
    p
}

#[test]
fn a_detached_data_file_that_is_a_pipe_or_a_device_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fifo = dir.path().join("data.fifo");
    mkfifo(&fifo);
    let dev_zero = Path::new("/dev/zero");
    for encoding in ["raw", "gzip", "hex", "ascii"] {
        for (data, what) in [(fifo.as_path(), "named pipe"), (dev_zero, "character device")] {
            let header = detached(dir.path(), &format!("{encoding}-{}.nhdr", what.replace(' ', "-")), data, encoding);
            let e = within_limit(&format!("{encoding} from a {what}"), move || warpbench_io::open(&header));
            assert!(matches!(e.kind, ErrorKind::NotARegularFile { .. }), "{encoding} {what}: {e}");
            assert_eq!(e.path, data, "the error names the data file: {e}");
            assert!(e.to_string().contains(what), "{e}");
        }
    }
}

#[test]
fn a_line_skip_longer_than_the_data_file_ends_with_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("no-newline.raw");
    std::fs::write(&data, [7u8; 64]).expect("write");
    for encoding in ["raw", "gzip", "hex", "ascii"] {
        let header = detached(dir.path(), &format!("{encoding}.nhdr"), &data, encoding);
        let e = within_limit(encoding, move || warpbench_io::open(&header));
        assert!(matches!(e.kind, ErrorKind::Truncated(_)), "{encoding}: {e}");
        assert!(e.to_string().contains("line skip"), "{e}");
    }
}

// ---------------------------------------------------------------------------------------------
// Memory
// ---------------------------------------------------------------------------------------------

/// Address space for the child that reads the inflating stream: less than the 2·10⁹ bytes it declares.
const CHILD_ADDRESS_SPACE_KIB: u64 = 1024 * 1024;
/// 2000 × 1000 × 1000 u8, as in the file.
const HUGE_DIMS: [usize; 3] = [2000, 1000, 1000];
const HUGE_BYTES: u64 = 2_000_000_000;
/// Bytes of voxel data per gzip member: one member is compressed once and written as often as needed.
const MEMBER_BYTES: usize = 16 << 20;
/// Deflate's largest expansion, the bound the readers already apply (a stream under it must be *read*).
const MAX_DEFLATE_RATIO: u64 = 1032;

fn gzip_member(bytes: &[u8]) -> Vec<u8> {
    let mut e = GzEncoder::new(Vec::new(), Compression::default());
    e.write_all(bytes).expect("gzip into a Vec");
    e.finish().expect("gzip into a Vec")
}

/// Writes `head` (uncompressed, e.g. a NRRD header), then gzip members that inflate to `first` followed by
/// [`HUGE_BYTES`] of samples. The samples are mostly zeros with a byte set every 2 KiB, so that the stream is not
/// so compressed that the compression-ratio bound refuses it. Returns the file's length.
fn write_inflating(path: &Path, head: &[u8], first: &[u8]) -> u64 {
    let mut samples = vec![0u8; MEMBER_BYTES];
    for (i, b) in samples.iter_mut().enumerate().step_by(2048) {
        *b = (i / 2048 % 251) as u8 + 1;
    }
    let member = gzip_member(&samples);
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).expect("create"));
    f.write_all(head).expect("write");
    if !first.is_empty() {
        f.write_all(&gzip_member(first)).expect("write");
    }
    for _ in 0..HUGE_BYTES.div_ceil(MEMBER_BYTES as u64) {
        f.write_all(&member).expect("write");
    }
    f.flush().expect("flush");
    drop(f);
    std::fs::metadata(path).expect("stat").len()
}

/// A NIfTI-1 header (little-endian) for [`HUGE_DIMS`] u8, pixdim 1, vox_offset 352.
fn huge_nifti_header() -> Vec<u8> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    let dim: [i16; 8] = [3, 2000, 1000, 1000, 1, 1, 1, 1];
    for (i, d) in dim.iter().enumerate() {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&d.to_le_bytes());
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&1f32.to_le_bytes());
    }
    h[70..72].copy_from_slice(&2i16.to_le_bytes()); // datatype u8
    h[72..74].copy_from_slice(&8i16.to_le_bytes()); // bitpix
    h[108..112].copy_from_slice(&352f32.to_le_bytes()); // vox_offset
    h[112..116].copy_from_slice(&1f32.to_le_bytes()); // scl_slope
    h[344..348].copy_from_slice(b"n+1\0");
    h
}

/// The child's half of [`a_stream_that_inflates_past_the_address_space_is_an_error_not_an_abort`]: reads the file
/// named in `WARPBENCH_CHILD_READ` and prints the outcome. Run alone it does nothing.
#[test]
#[ignore = "run by a_stream_that_inflates_past_the_address_space_is_an_error_not_an_abort in a child process"]
fn child_reads_the_file_named_in_the_environment() {
    let Some(path) = std::env::var_os("WARPBENCH_CHILD_READ") else { return };
    match warpbench_io::open(&path) {
        Ok(v) => println!("child outcome: read {:?}", v.dims),
        Err(e) => println!("child outcome: {e}"),
    }
}

/// The test a child runs: its full name in the io crate's test binary (`tests/main.rs`).
const CHILD_TEST: &str = "bad_inputs::child_reads_the_file_named_in_the_environment";

#[test]
fn a_stream_that_inflates_past_the_address_space_is_an_error_not_an_abort() {
    let dir = tempfile::tempdir().expect("tempdir");
    let nifti = dir.path().join("inflates.nii.gz");
    let nrrd = dir.path().join("inflates.nrrd");
    let nrrd_head = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2000 1000 1000\nspacings: 1 1 1\nencoding: gzip\n\n";
    let lens = [
        (nifti.clone(), write_inflating(&nifti, &[], &huge_nifti_header())),
        (nrrd.clone(), write_inflating(&nrrd, nrrd_head.as_bytes(), &[])),
    ];
    assert_eq!(HUGE_DIMS.iter().product::<usize>() as u64, HUGE_BYTES);
    let exe = std::env::current_exe().expect("this test binary");
    for (path, len) in lens {
        assert!(len * MAX_DEFLATE_RATIO > HUGE_BYTES + 352, "{len} bytes: the ratio bound would refuse it");
        let out = Command::new("sh")
            .arg("-c")
            .arg(format!(
                "ulimit -v {CHILD_ADDRESS_SPACE_KIB} && exec \"$0\" --ignored --exact {CHILD_TEST} --nocapture \
                 --test-threads 1"
            ))
            .arg(&exe)
            .env("WARPBENCH_CHILD_READ", &path)
            .output()
            .expect("run the child");
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        let name = path.display().to_string();
        assert!(out.status.success(), "{name}: the child failed ({:?}):\n{stdout}\n{stderr}", out.status);
        let outcome = stdout.split_once("child outcome: ").map(|(_, o)| o.lines().next().unwrap_or_default());
        let outcome = outcome.unwrap_or_default();
        assert!(
            outcome.contains(&name) && outcome.contains("not enough memory") && outcome.contains("2000000000 bytes"),
            "{name}: {outcome:?}\n{stdout}\n{stderr}"
        );
    }
}

#[test]
fn the_memory_cap_is_honoured_before_anything_is_allocated() {
    let h = "NRRD0004\ntype: short\ndimension: 3\nsizes: 100 100 100\nspacings: 1 1 1\nencoding: raw\n\n";
    let mut bytes = h.as_bytes().to_vec();
    bytes.resize(h.len() + 2_000_000, 0);
    let e =
        warpbench_io::nrrd::read_bytes(Path::new("cap.nrrd"), &bytes, &mut LoadOptions::new().max_voxel_bytes(1 << 20))
            .expect_err("over the cap");
    assert!(matches!(e.kind, ErrorKind::TooLarge { bytes: 2_000_000, limit: 1_048_576, .. }), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Geometry
// ---------------------------------------------------------------------------------------------

fn nrrd_with_directions(directions: &str) -> warpbench_io::Result<Volume> {
    let h = format!(
        "NRRD0004\ntype: uchar\ndimension: 3\nspace: left-posterior-superior\nsizes: 2 2 2\n\
         space directions: {directions}\nspace origin: (0,0,0)\nencoding: raw\n\n"
    );
    let mut bytes = h.into_bytes();
    bytes.extend([0u8; 8]);
    warpbench_io::nrrd::read_bytes(Path::new("geometry.nrrd"), &bytes, &mut LoadOptions::new())
}

#[test]
fn an_infinite_spacing_is_refused() {
    // Each entry is finite; the column lengths (the spacings) overflow to infinity.
    let e = nrrd_with_directions("(1e308,0,0) (0,1e308,0) (0,0,1e308)").expect_err("infinite spacing");
    assert!(matches!(e.kind, ErrorKind::Invalid(_)), "{e}");
    assert!(e.to_string().starts_with("geometry.nrrd") && e.to_string().contains("not finite"), "{e}");
    // The committed corpus file (tests/data/bad) is refused the same way, through `open`.
    let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/bad/spacing_infinite.nrrd");
    let e = warpbench_io::open(&corpus).expect_err("the corpus file");
    assert!(e.to_string().contains("spacing_infinite.nrrd") && e.to_string().contains("not finite"), "{e}");
    // Spacings given as `spacings` (no space) overflow the same way.
    let h = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 1 1\nspacings: 1e308 1e308 1e308\nencoding: raw\n\n";
    let mut bytes = h.as_bytes().to_vec();
    bytes.extend([0u8; 2]);
    let e = warpbench_io::nrrd::read_bytes(Path::new("spacings.nrrd"), &bytes, &mut LoadOptions::new())
        .expect_err("infinite spacings");
    assert!(e.to_string().contains("not finite"), "{e}");
}

#[test]
fn an_implausible_spacing_is_a_warning() {
    for (directions, axis, shown) in [
        ("(2e4,0,0) (0,1,0) (0,0,1)", "i", "2e4 mm"),
        ("(1,0,0) (0,1e-7,0) (0,0,1)", "j", "1e-7 mm"),
        ("(1,0,0) (0,1,0) (0,0,1e5)", "k", "1e5 mm"),
    ] {
        let v = nrrd_with_directions(directions).expect("valid, if implausible");
        let w = v.metadata.warnings.iter().find(|w| w.contains("implausible voxel spacing"));
        let w = w.unwrap_or_else(|| panic!("{directions}: no warning in {:?}", v.metadata.warnings));
        assert!(w.contains(&format!("{shown} along {axis}")), "{w}");
    }
    let v = nrrd_with_directions("(0.5,0,0) (0,0.5,0) (0,0,3)").expect("plausible");
    assert!(v.metadata.warnings.is_empty(), "{:?}", v.metadata.warnings);
}

#[test]
fn a_folder_given_to_a_file_reader_is_refused_by_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    let folder = dir.path().join("looks_like.nii");
    std::fs::create_dir(&folder).expect("mkdir");
    let e = warpbench_io::nifti::read(&folder, &mut LoadOptions::new()).expect_err("a folder");
    assert!(matches!(e.kind, ErrorKind::NotARegularFile { what: "a folder" }), "{e}");
    assert!(e.to_string().starts_with(&format!("{}: a folder, not a regular file", folder.display())), "{e}");
}

// ---------------------------------------------------------------------------------------------
// DICOM memory
// ---------------------------------------------------------------------------------------------

/// Reads `path` in a child process: this test binary re-executed under `ulimit -v kib`, running
/// [`child_reads_the_file_named_in_the_environment`]. Returns the line the child printed (the volume's dims or the
/// error); a child that aborts or fails otherwise fails the test, with its output.
fn read_in_child(path: &Path, kib: u64) -> String {
    let exe = std::env::current_exe().expect("this test binary");
    let out = Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {kib} && exec \"$0\" --ignored --exact {CHILD_TEST} --nocapture --test-threads 1"))
        .arg(&exe)
        .env("WARPBENCH_CHILD_READ", path)
        .output()
        .expect("run the child");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{}: the child failed ({:?}):\n{stdout}\n{stderr}", path.display(), out.status);
    let outcome = stdout.split_once("child outcome: ").map(|(_, o)| o.lines().next().unwrap_or_default());
    outcome.unwrap_or_else(|| panic!("{}: the child printed no outcome:\n{stdout}\n{stderr}", path.display())).into()
}

/// A single-slice, 8-bit DICOM of `rows` × `cols` in an encapsulated `transfer_syntax`, whose one fragment is
/// `head` then filler: long enough for the reader's size check (pixel data compressed at most 2048:1), not a valid
/// codestream, so the reader allocates what Rows × Columns claim before it finds out.
fn encapsulated_dicom(path: &Path, rows: u16, cols: u16, transfer_syntax: &str, head: &[u8]) {
    write_encapsulated(path, rows, cols, transfer_syntax, head, None);
}

/// [`encapsulated_dicom`], with RescaleSlope `slope` when given.
fn write_encapsulated(path: &Path, rows: u16, cols: u16, transfer_syntax: &str, head: &[u8], slope: Option<&str>) {
    use dicom_core::value::PixelFragmentSequence;
    use dicom_core::{DataElement, PrimitiveValue, VR};
    use dicom_dictionary_std::{tags, uids};
    use dicom_object::{FileMetaTableBuilder, InMemDicomObject};

    let fragment_len = (usize::from(rows) * usize::from(cols)).div_ceil(2048).next_multiple_of(2);
    let mut fragment = head.to_vec();
    fragment.resize(fragment_len.max(head.len().next_multiple_of(2)), 0);
    let ds = |v: &str| PrimitiveValue::from(v);
    let mut obj = InMemDicomObject::from_element_iter([
        DataElement::new(tags::SOP_CLASS_UID, VR::UI, ds(uids::MR_IMAGE_STORAGE)),
        DataElement::new(tags::SOP_INSTANCE_UID, VR::UI, ds("1.2.826.0.1.3680043.2.9.1")),
        DataElement::new(tags::MODALITY, VR::CS, ds("MR")),
        DataElement::new(tags::STUDY_INSTANCE_UID, VR::UI, ds("1.2.826.0.1.3680043.2.9")),
        DataElement::new(tags::SERIES_INSTANCE_UID, VR::UI, ds("1.2.826.0.1.3680043.2.9.2")),
        DataElement::new(tags::INSTANCE_NUMBER, VR::IS, ds("1")),
        DataElement::new(tags::IMAGE_POSITION_PATIENT, VR::DS, ds("0\\0\\0")),
        DataElement::new(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, ds("1\\0\\0\\0\\1\\0")),
        DataElement::new(tags::PIXEL_SPACING, VR::DS, ds("1\\1")),
        DataElement::new(tags::SLICE_THICKNESS, VR::DS, ds("1")),
        DataElement::new(tags::SAMPLES_PER_PIXEL, VR::US, PrimitiveValue::from(1u16)),
        DataElement::new(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, ds("MONOCHROME2")),
        DataElement::new(tags::ROWS, VR::US, PrimitiveValue::from(rows)),
        DataElement::new(tags::COLUMNS, VR::US, PrimitiveValue::from(cols)),
        DataElement::new(tags::BITS_ALLOCATED, VR::US, PrimitiveValue::from(8u16)),
        DataElement::new(tags::BITS_STORED, VR::US, PrimitiveValue::from(8u16)),
        DataElement::new(tags::HIGH_BIT, VR::US, PrimitiveValue::from(7u16)),
        DataElement::new(tags::PIXEL_REPRESENTATION, VR::US, PrimitiveValue::from(0u16)),
        DataElement::new(tags::PIXEL_DATA, VR::OB, PixelFragmentSequence::new(vec![], vec![fragment])),
    ]);
    if let Some(slope) = slope {
        obj.put(DataElement::new(tags::RESCALE_SLOPE, VR::DS, ds(slope)));
        obj.put(DataElement::new(tags::RESCALE_INTERCEPT, VR::DS, ds("0")));
    }
    obj.with_meta(FileMetaTableBuilder::new().transfer_syntax(transfer_syntax))
        .expect("file meta")
        .write_to_file(path)
        .expect("write DICOM");
}

#[test]
fn a_dicom_whose_pixels_cannot_be_allocated_is_an_error_not_an_abort() {
    let dir = tempfile::tempdir().expect("tempdir");
    // 65535² bytes (4 GiB) of stored pixels: more than the child's address space, under the default cap.
    let stored = dir.path().join("stored-4gib.dcm");
    encapsulated_dicom(&stored, u16::MAX, u16::MAX, "1.2.840.10008.1.2.5", &[]);
    // 25000² bytes: the stored pixels fit in the child's 1 GiB, the decoded frames as well do not.
    let rle = dir.path().join("decoded-rle.dcm");
    encapsulated_dicom(&rle, 25_000, 25_000, "1.2.840.10008.1.2.5", &[]);
    let jpeg_ls = dir.path().join("decoded-jpeg-ls.dcm");
    encapsulated_dicom(&jpeg_ls, 25_000, 25_000, "1.2.840.10008.1.2.4.80", &[]);
    // 17320² bytes stored and decoded fit; the JPEG-LS decoder's 16-bit samples of the frame (a valid header for
    // it, then filler) do not.
    let samples = dir.path().join("jpeg-ls-samples.dcm");
    let side = 17_320u16.to_be_bytes();
    let header = [
        [0xFF, 0xD8].as_slice(),                                                    // SOI
        &[0xFF, 0xF7, 0, 11, 8, side[0], side[1], side[0], side[1], 1, 1, 0x11, 0], // SOF55: P 8, Y, X, 1 component
        &[0xFF, 0xDA, 0, 8, 1, 1, 0, 0, 0, 0],                                      // SOS: 1 component, NEAR 0, ILV 0
    ]
    .concat();
    encapsulated_dicom(&samples, 17_320, 17_320, "1.2.840.10008.1.2.4.80", &header);
    for (path, what, bytes) in [
        (&stored, "the stored pixels", "4294836225 bytes"),
        (&rle, "the decoded pixel data", "625000000 bytes"),
        (&jpeg_ls, "the decoded pixel data", "625000000 bytes"),
        (&samples, "the samples of JPEG-LS frame 1", "599964800 bytes"),
    ] {
        let outcome = read_in_child(path, CHILD_ADDRESS_SPACE_KIB);
        let name = path.display().to_string();
        assert!(
            outcome.starts_with(&name) && outcome.contains(&format!("not enough memory for {what}: {bytes}")),
            "{name}: {outcome:?}"
        );
    }
}

#[test]
fn a_rescaled_copy_that_cannot_be_allocated_is_an_error_not_an_abort() {
    // 17408² u8 pixels, all 7, in valid RLE (runs of 128), with RescaleSlope 0.5: the f32 copy (4 bytes a voxel)
    // does not fit in the child's 1 GiB beside the stored pixels.
    const SIDE: u16 = 17_408;
    let pixels = usize::from(SIDE) * usize::from(SIDE);
    assert_eq!(pixels % 128, 0);
    let mut rle = vec![0u8; 64];
    rle[0..4].copy_from_slice(&1u32.to_le_bytes()); // one segment
    rle[4..8].copy_from_slice(&64u32.to_le_bytes()); // starting after the header
    for _ in 0..pixels / 128 {
        rle.extend([0x81, 7]); // PackBits: repeat the next byte 128 times
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("rescaled.dcm");
    write_encapsulated(&path, SIDE, SIDE, "1.2.840.10008.1.2.5", &rle, Some("0.5"));
    let outcome = read_in_child(&path, CHILD_ADDRESS_SPACE_KIB);
    let bytes = format!("{} bytes", pixels * 4);
    assert!(
        outcome.starts_with(&path.display().to_string())
            && outcome.contains(&format!("not enough memory for the converted samples: {bytes}")),
        "{outcome:?}"
    );
}
