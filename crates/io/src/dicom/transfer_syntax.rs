//! [`TransferSyntax`]: the encodings this reader decodes, classified once from the UID in the file meta group.
//! Every decision that depends on the encoding (how the length walker reads element headers, whether a file's
//! pixel bytes are copied straight, which codec decodes them, how many pixels a file of a given size can hold)
//! asks the enum, never the UID string.

use std::path::Path;

use crate::error::{Error, Result};

/// A transfer syntax this reader decodes (PS3.5 Section 10 and Annex A).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransferSyntax {
    ImplicitVrLittleEndian,
    ExplicitVrLittleEndian,
    ExplicitVrBigEndian,
    DeflatedExplicitVrLittleEndian,
    EncapsulatedUncompressed,
    RleLossless,
    JpegBaseline,
    JpegExtended,
    JpegLossless,
    JpegLosslessSv1,
    JpegLsLossless,
    JpegLsNearLossless,
    Jpeg2000Lossless,
    Jpeg2000,
    HtJpeg2000Lossless,
    HtJpeg2000LosslessRpcl,
    HtJpeg2000,
    DeflatedImageFrame,
}

/// How the pixel data of a transfer syntax are turned into samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Codec {
    /// Native pixel data (not encapsulated) in PixelData itself.
    Native,
    /// RLE Lossless, decoded here.
    Rle,
    /// JPEG-LS, decoded by [`crate::jpegls`].
    JpegLs,
    /// JPEG, decoded by dicom-pixeldata after its frame headers are checked.
    Jpeg,
    /// JPEG 2000 (and HTJ2K), decoded by dicom-pixeldata after its SIZ segments are checked.
    Jpeg2000,
    /// Other encapsulated data that dicom-pixeldata decodes with nothing to check first.
    Pixeldata,
}

impl TransferSyntax {
    /// Every transfer syntax this reader decodes, in the order of [`SUPPORTED_TRANSFER_SYNTAXES`].
    pub const ALL: [Self; 18] = [
        Self::ImplicitVrLittleEndian,
        Self::ExplicitVrLittleEndian,
        Self::ExplicitVrBigEndian,
        Self::DeflatedExplicitVrLittleEndian,
        Self::EncapsulatedUncompressed,
        Self::RleLossless,
        Self::JpegBaseline,
        Self::JpegExtended,
        Self::JpegLossless,
        Self::JpegLosslessSv1,
        Self::JpegLsLossless,
        Self::JpegLsNearLossless,
        Self::Jpeg2000Lossless,
        Self::Jpeg2000,
        Self::HtJpeg2000Lossless,
        Self::HtJpeg2000LosslessRpcl,
        Self::HtJpeg2000,
        Self::DeflatedImageFrame,
    ];

    /// The transfer syntax of `uid` (compared exactly: callers pass it trimmed), or `None` when this reader does
    /// not decode it.
    #[must_use]
    pub fn from_uid(uid: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.uid() == uid)
    }

    #[must_use]
    pub const fn uid(self) -> &'static str {
        match self {
            Self::ImplicitVrLittleEndian => "1.2.840.10008.1.2",
            Self::ExplicitVrLittleEndian => "1.2.840.10008.1.2.1",
            Self::ExplicitVrBigEndian => "1.2.840.10008.1.2.2",
            Self::DeflatedExplicitVrLittleEndian => "1.2.840.10008.1.2.1.99",
            Self::EncapsulatedUncompressed => "1.2.840.10008.1.2.1.98",
            Self::RleLossless => "1.2.840.10008.1.2.5",
            Self::JpegBaseline => "1.2.840.10008.1.2.4.50",
            Self::JpegExtended => "1.2.840.10008.1.2.4.51",
            Self::JpegLossless => "1.2.840.10008.1.2.4.57",
            Self::JpegLosslessSv1 => "1.2.840.10008.1.2.4.70",
            Self::JpegLsLossless => "1.2.840.10008.1.2.4.80",
            Self::JpegLsNearLossless => "1.2.840.10008.1.2.4.81",
            Self::Jpeg2000Lossless => "1.2.840.10008.1.2.4.90",
            Self::Jpeg2000 => "1.2.840.10008.1.2.4.91",
            Self::HtJpeg2000Lossless => "1.2.840.10008.1.2.4.201",
            Self::HtJpeg2000LosslessRpcl => "1.2.840.10008.1.2.4.202",
            Self::HtJpeg2000 => "1.2.840.10008.1.2.4.203",
            Self::DeflatedImageFrame => "1.2.840.10008.1.2.8.1",
        }
    }

    /// The name PS3.6 gives it.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::ImplicitVrLittleEndian => "Implicit VR Little Endian",
            Self::ExplicitVrLittleEndian => "Explicit VR Little Endian",
            Self::ExplicitVrBigEndian => "Explicit VR Big Endian",
            Self::DeflatedExplicitVrLittleEndian => "Deflated Explicit VR Little Endian",
            Self::EncapsulatedUncompressed => "Encapsulated Uncompressed Explicit VR Little Endian",
            Self::RleLossless => "RLE Lossless",
            Self::JpegBaseline => "JPEG Baseline (Process 1)",
            Self::JpegExtended => "JPEG Extended (Process 2 & 4)",
            Self::JpegLossless => "JPEG Lossless, Non-Hierarchical (Process 14)",
            Self::JpegLosslessSv1 => "JPEG Lossless, Non-Hierarchical, First-Order Prediction (Process 14, SV1)",
            Self::JpegLsLossless => "JPEG-LS Lossless",
            Self::JpegLsNearLossless => "JPEG-LS Lossy (Near-Lossless)",
            Self::Jpeg2000Lossless => "JPEG 2000 Image Compression (Lossless Only)",
            Self::Jpeg2000 => "JPEG 2000 Image Compression",
            Self::HtJpeg2000Lossless => "High-Throughput JPEG 2000 Image Compression (Lossless Only)",
            Self::HtJpeg2000LosslessRpcl => {
                "High-Throughput JPEG 2000 with RPCL Options Image Compression (Lossless Only)"
            }
            Self::HtJpeg2000 => "High-Throughput JPEG 2000 Image Compression",
            Self::DeflatedImageFrame => "Deflated Image Frame Compression",
        }
    }

    pub(super) const fn codec(self) -> Codec {
        match self {
            Self::ImplicitVrLittleEndian
            | Self::ExplicitVrLittleEndian
            | Self::ExplicitVrBigEndian
            | Self::DeflatedExplicitVrLittleEndian => Codec::Native,
            Self::RleLossless => Codec::Rle,
            Self::JpegLsLossless | Self::JpegLsNearLossless => Codec::JpegLs,
            Self::JpegBaseline | Self::JpegExtended | Self::JpegLossless | Self::JpegLosslessSv1 => Codec::Jpeg,
            Self::Jpeg2000Lossless
            | Self::Jpeg2000
            | Self::HtJpeg2000Lossless
            | Self::HtJpeg2000LosslessRpcl
            | Self::HtJpeg2000 => Codec::Jpeg2000,
            Self::EncapsulatedUncompressed | Self::DeflatedImageFrame => Codec::Pixeldata,
        }
    }

    /// Native little-endian pixels, whose bytes are copied straight from the file (the data set is neither
    /// deflated nor big-endian).
    pub(super) const fn pixels_are_file_bytes(self) -> bool {
        matches!(self, Self::ImplicitVrLittleEndian | Self::ExplicitVrLittleEndian)
    }

    /// Pixels stored at their decoded size, so a file holds at most its own length of them.
    pub(super) const fn is_uncompressed(self) -> bool {
        matches!(
            self,
            Self::ImplicitVrLittleEndian
                | Self::ExplicitVrLittleEndian
                | Self::ExplicitVrBigEndian
                | Self::EncapsulatedUncompressed
        )
    }
}

/// Transfer syntaxes this reader decodes, as (UID, name): [`TransferSyntax::ALL`].
pub const SUPPORTED_TRANSFER_SYNTAXES: &[(&str, &str)] = &{
    let mut table = [("", ""); TransferSyntax::ALL.len()];
    let mut i = 0;
    while i < table.len() {
        table[i] = (TransferSyntax::ALL[i].uid(), TransferSyntax::ALL[i].name());
        i += 1;
    }
    table
};

/// Names of transfer syntaxes we know but do not decode, for error messages.
const UNSUPPORTED_TRANSFER_SYNTAXES: &[(&str, &str)] = &[
    ("1.2.840.10008.1.2.4.92", "JPEG 2000 Part 2 Multi-component (Lossless Only)"),
    ("1.2.840.10008.1.2.4.93", "JPEG 2000 Part 2 Multi-component"),
    ("1.2.840.10008.1.2.4.94", "JPIP Referenced"),
    ("1.2.840.10008.1.2.4.95", "JPIP Referenced Deflate"),
    ("1.2.840.10008.1.2.4.110", "JPEG XL Lossless"),
    ("1.2.840.10008.1.2.4.111", "JPEG XL JPEG Recompression"),
    ("1.2.840.10008.1.2.4.112", "JPEG XL"),
    ("1.2.840.10008.1.2.4.100", "MPEG2 Main Profile / Main Level"),
    ("1.2.840.10008.1.2.4.101", "MPEG2 Main Profile / High Level"),
    ("1.2.840.10008.1.2.4.102", "MPEG-4 AVC/H.264 High Profile"),
    ("1.2.840.10008.1.2.4.103", "MPEG-4 AVC/H.264 BD-compatible High Profile"),
    ("1.2.840.10008.1.2.4.107", "HEVC/H.265 Main Profile"),
    ("1.2.840.10008.1.2.4.108", "HEVC/H.265 Main 10 Profile"),
];

/// The transfer syntax of `uid`, or an error naming `path`, the syntax (when we know its name) and the UID.
pub(super) fn decodable(path: &Path, uid: &str) -> Result<TransferSyntax> {
    TransferSyntax::from_uid(uid).ok_or_else(|| {
        let name = UNSUPPORTED_TRANSFER_SYNTAXES.iter().find(|(u, _)| *u == uid).map_or("(unknown)", |(_, n)| *n);
        Error::unsupported(path, format!("unsupported transfer syntax {name} ({uid})"))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_syntax_is_found_by_its_own_uid_and_the_table_lists_each_once() {
        for t in TransferSyntax::ALL {
            assert_eq!(TransferSyntax::from_uid(t.uid()), Some(t), "{t:?}");
        }
        let mut uids: Vec<&str> = SUPPORTED_TRANSFER_SYNTAXES.iter().map(|(u, _)| *u).collect();
        uids.sort_unstable();
        uids.dedup();
        assert_eq!(uids.len(), TransferSyntax::ALL.len());
        assert_eq!(SUPPORTED_TRANSFER_SYNTAXES[5], ("1.2.840.10008.1.2.5", "RLE Lossless"));
    }

    #[test]
    fn an_undecoded_syntax_is_named_in_the_error() {
        let e = decodable(Path::new("x.dcm"), "1.2.840.10008.1.2.4.110").expect_err("JPEG XL");
        assert_eq!(
            e.to_string(),
            "x.dcm: unsupported: unsupported transfer syntax JPEG XL Lossless (1.2.840.10008.1.2.4.110)"
        );
        let e = decodable(Path::new("x.dcm"), "1.2.3").expect_err("unknown");
        assert!(e.to_string().contains("(unknown) (1.2.3)"), "{e}");
        assert!(TransferSyntax::from_uid("1.2.840.10008.1.2.4.92").is_none());
    }
}
