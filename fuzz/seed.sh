#!/usr/bin/env bash
# Seeds each fuzz target's corpus with the small committed fixtures (files under 2 MB), the bad-input corpus
# (tests/data/bad: truncations, corrupted headers, absurd sizes) and, for NRRD, whose one fixture is 12 MB, a few
# small files written here (one per encoding and sample type). Idempotent: files are named by content or purpose.
set -euo pipefail
cd "$(dirname "$0")"
data=../tests/data
seed() { mkdir -p "corpus/$1"; find "$data/$2" -type f -size -2M -name "$3" ! -name '*.md' -exec cp {} "corpus/$1/" \; ; }
seed nifti nifti '*.nii*'
seed nifti bad '*.nii*'
seed nifti afni_made '*.nii*'
seed nifti itk '*.nii*'
seed nrrd nrrd '*.n*'
seed nrrd bad '*.nrrd'
# DICOM fixtures often have no extension (pydicom_ct2/17106); every file under dicom/ is one.
seed dicom dicom '*'
seed dicom bad '*.dcm'
seed landmarks landmarks '*'
seed metaimage metaimage '*.mh?'
seed metaimage bad '*.mh?'
seed mgh mgh '*.mg?'
seed minc minc '*.mnc*'
seed mni mni '*.tag'
seed mni mni '*.xfm'
seed elastix elastix '*.txt'
seed itk_h5 itk '*.h5'
seed itk_tfm itk '*.tfm'
seed itk_tfm itk '*.mat'
seed dicom_reg dicom_reg '*.dcm'
seed learn2reg learn2reg '*.npz'
seed learn2reg learn2reg '*.nii*'
seed fnirt fnirt '*.nii*'
seed matrix_text fsl '*.mat'
seed lta lta '*.lta'

# AFNI: each dataset's two files in one (the .HEAD's length as a little-endian u32, the .HEAD, the .BRIK).
mkdir -p corpus/afni
for head in "$data"/afni/*.HEAD "$data"/afni_made/*.HEAD; do
    # nibabel's damaged headers come without samples: example4d's stand in.
    brik=$(find "$(dirname "$head")" -name "$(basename "${head%.HEAD}").BRIK*" | head -n 1)
    [ -n "$brik" ] || brik="$data/afni/example4d+orig.BRIK.gz"
    [ "$(stat -c %s "$brik")" -lt 2000000 ] || continue
    python3 -c 'import struct, sys; sys.stdout.buffer.write(struct.pack("<I", int(sys.argv[1])))' "$(stat -c %s "$head")" \
        >"corpus/afni/seed_$(basename "${head%.HEAD}")"
    cat "$head" "$brik" >>"corpus/afni/seed_$(basename "${head%.HEAD}")"
done

# NRRD: header lines, then the samples. `nrrd NAME HEADER-LINES... -- SAMPLES-COMMAND`.
nrrd() {
    local name=$1 && shift
    { printf 'NRRD0004\n'; while [ "$1" != -- ]; do printf '%s\n' "$1"; shift; done; printf '\n'; shift; "$@"; } \
        >"corpus/nrrd/seed_$name.nrrd"
}
bytes() { printf '\001\002\003\004\005\006\007\010\011\012\013\014\015\016\017\020'; }
lps='space: left-posterior-superior'
dirs='space directions: (0.5,0,0) (0,0.75,0) (0,0,2)'
nrrd raw_uchar 'type: uchar' 'dimension: 3' "$lps" 'sizes: 2 2 2' "$dirs" 'space origin: (-10,20,5.5)' \
    'encoding: raw' -- bytes
nrrd gzip_short 'type: short' 'dimension: 3' "$lps" 'sizes: 2 2 2' "$dirs" 'kinds: domain domain domain' \
    'endian: little' 'encoding: gzip' 'space origin: (-146,-325,-777.5)' -- sh -c 'printf "\001\002\003\004\005\006\007\010\011\012\013\014\015\016\017\020" | gzip -n'
nrrd hex_ushort_big 'type: ushort' 'dimension: 3' 'sizes: 2 2 2' 'spacings: 1 1 3' 'endian: big' 'encoding: hex' \
    -- printf '0001 0002 0003 0004\n0005 0006 0007 0008\n'
nrrd ascii_float 'type: float' 'dimension: 3' 'space: right-anterior-superior' 'sizes: 2 2 2' "$dirs" \
    'space units: "mm" "mm" "mm"' 'encoding: ascii' -- printf '1.5 -2 3e2 4\n5 6 7 8.25\n'
nrrd skip_int 'type: int' 'dimension: 3' 'sizes: 2 1 1' 'spacings: 1 1 1' 'line skip: 1' 'byte skip: 2' \
    'endian: little' 'encoding: raw' -- printf 'junk\n..\001\000\000\000\002\000\000\000'
nrrd list1_uchar 'type: uchar' 'dimension: 4' "$lps" 'sizes: 1 2 2 2' \
    'space directions: none (1,0,0) (0,1,0) (0,0,1)' 'kinds: list domain domain domain' 'encoding: raw' -- bytes
nrrd dims2_double 'type: double' 'dimension: 2' 'sizes: 2 1' 'spacings: 0.5 0.5' 'encoding: raw' -- bytes

# OME-Zarr: each fixture folder packed as the ngff target reads it (entries `PATH\0BYTES` joined by `\n##\n`).
mkdir -p corpus/ngff
python3 - "$data/ngff" corpus/ngff <<'PY'
import pathlib, sys
src, out = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
for folder in sorted(src.glob("*.zarr")):
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    packed = b"\n##\n".join(str(p.relative_to(folder)).encode() + b"\0" + p.read_bytes() for p in files)
    (out / f"seed_{folder.name}").write_bytes(packed)
PY
