"""`Warp.to_dicom`: the same DICOM registration objects as `warpbench transform --format dicom`, between the CT and
the MR of pydicom's test files: a Spatial Registration for a rigid fit (its matrix the CLI's, and carrying each
moving landmark onto its fixed one), a Deformable Spatial Registration for a TPS (its vectors the CLI's); volumes
that are not DICOM are refused with a Python exception; plastimatch's objects read back as a field and a starting
transform."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

import warpbench as wb
from conftest import DATA, T1, run_cli

CT = DATA / "dicom" / "pydicom_ct5n"
MR = DATA / "dicom" / "mixed_ct5n_mr_small" / "MR_small.dcm"
PAIRS = DATA / "dicom_reg" / "pairs.csv"


def element(path: Path, tag: bytes, vr: bytes) -> bytes:
    """The value of the first element `tag` (group, element, little-endian) of VR `vr` in an Explicit VR Little
    Endian file: enough to read the matrix and the vectors back without a DICOM library."""
    data = path.read_bytes()
    at = data.find(tag + vr)
    assert at > 0, f"{tag!r} not in {path}"
    if vr in (b"OF", b"OB", b"SQ", b"UN", b"OD", b"UT"):
        n = struct.unpack("<I", data[at + 8 : at + 12])[0]
        return data[at + 12 : at + 12 + n]
    n = struct.unpack("<H", data[at + 6 : at + 8])[0]
    return data[at + 8 : at + 8 + n]


MATRIX = b"\x06\x30\xc6\x00"  # (3006,00C6) Frame of Reference Transformation Matrix
VECTORS = b"\x64\x00\x09\x00"  # (0064,0009) Vector Grid Data


def matrices(path: Path) -> list[np.ndarray]:
    data = path.read_bytes()
    found, at = [], 0
    while (at := data.find(MATRIX + b"DS", at + 1)) > 0:
        n = struct.unpack("<H", data[at + 6 : at + 8])[0]
        found.append(np.array([float(v) for v in data[at + 8 : at + 8 + n].decode().split("\\")]).reshape(4, 4))
    return found


def test_a_rigid_fit_is_the_clis_spatial_registration(tmp_path: Path) -> None:
    fixed, moving = wb.read_volume(CT), wb.read_volume(MR)
    pairs = wb.read_landmarks(PAIRS)
    warp = wb.fit(pairs, "rigid", fixed=fixed, moving=moving)
    ours = tmp_path / "py.dcm"
    assert warp.to_dicom(ours) == "RIGID"
    cli = tmp_path / "cli.dcm"
    run_cli("transform", "--fixed", CT, "--moving", MR, "--landmarks", PAIRS, "--method", "rigid", "--format",
            "dicom", "--out", cli, "--quiet")
    (identity, m), (_, m_cli) = matrices(ours), matrices(cli)
    np.testing.assert_array_equal(identity, np.eye(4))
    np.testing.assert_allclose(m, m_cli, rtol=0, atol=1e-12)
    # M maps each moving landmark where the rigid fit puts it: onto the fixed one, within the fit's residual.
    mapped = (m[:3, :3] @ pairs.moving.T).T + m[:3, 3]
    np.testing.assert_allclose(mapped, warp.forward(pairs.moving), rtol=0, atol=1e-9)


def test_a_tps_is_the_clis_deformable_registration(tmp_path: Path) -> None:
    fixed, moving = wb.read_volume(CT), wb.read_volume(MR)
    warp = wb.fit(wb.read_landmarks(PAIRS), "tps", fixed=fixed, moving=moving)
    ours = tmp_path / "py.dcm"
    assert warp.to_dicom(ours) == "DEFORMABLE"
    cli = tmp_path / "cli.dcm"
    run_cli("transform", "--fixed", CT, "--moving", MR, "--landmarks", PAIRS, "--method", "tps", "--format",
            "dicom", "--out", cli, "--quiet")
    v = np.frombuffer(element(ours, VECTORS, b"OF"), "<f4")
    np.testing.assert_array_equal(v, np.frombuffer(element(cli, VECTORS, b"OF"), "<f4"))
    field = warp.field(fixed)
    np.testing.assert_array_equal(v.reshape(-1, 3), field.transpose(2, 1, 0, 3).reshape(-1, 3))


def test_volumes_that_are_not_dicom_are_refused(tmp_path: Path) -> None:
    head = wb.read_volume(T1)
    warp = wb.fit(wb.read_landmarks(PAIRS), "rigid", fixed=wb.read_volume(CT), moving=wb.read_volume(MR))
    with pytest.raises(Exception, match="T1"):
        warp.to_dicom(tmp_path / "x.dcm", moving=head)
    with pytest.raises(ValueError, match=r"\.dcm"):
        warp.to_dicom(tmp_path / "x.tfm")
    assert not (tmp_path / "x.dcm").exists()


def test_the_objects_read_back_as_a_field_and_a_starting_transform(tmp_path: Path) -> None:
    fixed, moving = wb.read_volume(CT), wb.read_volume(MR)
    warp = wb.fit(wb.read_landmarks(PAIRS), "tps", fixed=fixed, moving=moving)
    dsr = DATA / "dicom_reg" / "plastimatch_dsr.dcm"
    field = wb.read_field(dsr)
    assert field.source == "dicom" and field.direction == "pullback"
    np.testing.assert_array_equal(field.array, warp.field(fixed))
    # plastimatch's REG of start.tfm starts a fit with too few pairs as start.tfm does (its 6 decimals: 6e-4 mm).
    two = tmp_path / "two.csv"
    two.write_text('"Pt-0","true","-71","-88","6.64","-70.5","-140","6.94"\n'
                   '"Pt-1","true","-66","-88","6.64","-65.5","-140","6.94"\n')
    points = np.array([[-70.0, -140.0, 5.0], [-65.0, -136.0, 0.0]])
    mapped = [wb.fit(wb.read_landmarks(two), "rigid", fixed=fixed, moving=moving, initial=start).pullback(points)
              for start in (DATA / "dicom_reg" / "plastimatch_reg.dcm", DATA / "dicom_reg" / "start.tfm")]
    np.testing.assert_allclose(mapped[0], mapped[1], rtol=0, atol=6e-4)
