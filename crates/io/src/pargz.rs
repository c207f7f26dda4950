//! gzip written on every core: one gzip member whose deflate stream is cut into independently compressed pieces, as
//! `pigz --independent` writes it.
//!
//! The input is buffered in pieces of [`PIECE_BYTES`]; a batch of pieces (two per thread) is deflated in parallel,
//! each as raw deflate ended by a sync flush (an empty stored block, which ends on a byte boundary), so the pieces
//! concatenate into one valid deflate stream; the last piece ends the stream instead. The CRC-32 of each piece is
//! combined in order. The result is an ordinary single-member gzip file that every reader (zlib's `gzread`, ITK's and
//! FSL's znzlib, Python's `gzip`, nibabel, flate2's `GzDecoder`) reads, at zlib's default level; each piece forgets
//! its predecessor's 32 KiB window, which costs well under 1 % of the size at a piece of 1 MiB.

use std::io::{self, Write};

use flate2::{Compress, Compression, Crc, FlushCompress, Status};
use rayon::prelude::*;

/// The uncompressed bytes of one piece.
pub const PIECE_BYTES: usize = 1 << 20;

/// gzip's fixed header: magic, deflate, no flags, no time, no extra flags, OS unknown (255), as `GzEncoder` leaves
/// the time and flags.
const HEADER: [u8; 10] = [0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 255];

/// A writer of one gzip member, deflated in parallel (module docs). Call [`ParGzWriter::finish`] to end the stream;
/// dropping it without does not.
pub struct ParGzWriter<W: Write> {
    inner: W,
    level: Compression,
    /// Whole pieces waiting for a batch, and the piece being filled (the last of them).
    pending: Vec<Vec<u8>>,
    crc: Crc,
    wrote_header: bool,
}

impl<W: Write> ParGzWriter<W> {
    /// A writer of a gzip member to `inner` at `level`.
    pub fn new(inner: W, level: Compression) -> Self {
        Self { inner, level, pending: vec![Vec::with_capacity(PIECE_BYTES)], crc: Crc::new(), wrote_header: false }
    }

    /// How many whole pieces make a batch: two per thread, so that the threads stay busy.
    fn batch() -> usize {
        2 * rayon::current_num_threads().max(1)
    }

    /// Deflates `pieces` in parallel (the last one ending the stream when `last`) and writes them in order.
    fn flush_pieces(&mut self, pieces: &[Vec<u8>], last: bool) -> io::Result<()> {
        if !self.wrote_header {
            self.inner.write_all(&HEADER)?;
            self.wrote_header = true;
        }
        let n = pieces.len();
        let level = self.level;
        let done: Vec<io::Result<(Vec<u8>, Crc)>> = pieces
            .par_iter()
            .enumerate()
            .map(|(i, piece)| {
                let mut crc = Crc::new();
                crc.update(piece);
                Ok((deflate(piece, level, last && i + 1 == n)?, crc))
            })
            .collect();
        for piece in done {
            let (bytes, crc) = piece?;
            self.crc.combine(&crc);
            self.inner.write_all(&bytes)?;
        }
        Ok(())
    }

    /// Ends the stream: the remaining pieces, the last one ending the deflate stream, then gzip's trailer (CRC-32 and
    /// the length modulo 2³²). Returns the inner writer.
    ///
    /// # Errors
    /// What the inner writer returns.
    pub fn finish(mut self) -> io::Result<W> {
        let pieces = std::mem::take(&mut self.pending);
        self.flush_pieces(&pieces, true)?;
        self.inner.write_all(&self.crc.sum().to_le_bytes())?;
        self.inner.write_all(&self.crc.amount().to_le_bytes())?;
        Ok(self.inner)
    }
}

impl<W: Write> Write for ParGzWriter<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let filling = self.pending.last_mut().expect("a piece being filled");
        let n = buf.len().min(PIECE_BYTES - filling.len());
        filling.extend_from_slice(&buf[..n]);
        if filling.len() == PIECE_BYTES {
            if self.pending.len() == Self::batch() {
                let pieces = std::mem::take(&mut self.pending);
                self.flush_pieces(&pieces, false)?;
            }
            self.pending.push(Vec::with_capacity(PIECE_BYTES));
        }
        Ok(n)
    }

    /// Writes nothing early: a piece is deflated when it is whole, or at [`ParGzWriter::finish`].
    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

/// `data` as raw deflate at `level`, ended by a sync flush, or ending the stream when `last`.
fn deflate(data: &[u8], level: Compression, last: bool) -> io::Result<Vec<u8>> {
    let mut c = Compress::new(level, false);
    let mut out = Vec::with_capacity(data.len() / 2 + 1024);
    let flush = if last { FlushCompress::Finish } else { FlushCompress::Sync };
    loop {
        if out.capacity() - out.len() < 1024 {
            out.reserve(out.capacity().max(1 << 16));
        }
        let consumed = usize::try_from(c.total_in()).map_err(io::Error::other)?;
        let status = c.compress_vec(&data[consumed..], &mut out, flush).map_err(io::Error::other)?;
        let all_in = usize::try_from(c.total_in()).map_err(io::Error::other)? == data.len();
        match status {
            Status::StreamEnd => return Ok(out),
            // A sync flush is complete once all the input is in and zlib left room in the output (zlib's rule:
            // avail_out > 0 after the call).
            Status::Ok | Status::BufError if !last && all_in && out.len() < out.capacity() => return Ok(out),
            Status::Ok | Status::BufError => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use std::io::Read;

    use flate2::read::GzDecoder;

    use super::*;

    fn compress(data: &[u8], writes: usize) -> Vec<u8> {
        let mut w = ParGzWriter::new(Vec::new(), Compression::default());
        for part in data.chunks(writes.max(1)) {
            w.write_all(part).expect("write");
        }
        w.finish().expect("finish")
    }

    /// Data that compresses some but not entirely: a slow ramp with noise.
    fn data(n: usize) -> Vec<u8> {
        let mut x = 12345u32;
        (0..n)
            .map(|i| {
                x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
                #[allow(clippy::cast_possible_truncation, reason = "bytes of a test pattern")]
                let b = ((i / 4000) as u8).wrapping_add((x >> 28) as u8);
                b
            })
            .collect()
    }

    #[test]
    fn one_gzip_member_that_a_single_member_reader_reads_back_exactly() {
        let batch = 2 * rayon::current_num_threads().max(1);
        for n in
            [0, 1, 1000, PIECE_BYTES - 1, PIECE_BYTES, PIECE_BYTES + 1, 3 * PIECE_BYTES + 17, batch * PIECE_BYTES + 5]
        {
            let original = data(n);
            for writes in [7919, PIECE_BYTES, 5 * PIECE_BYTES] {
                let gz = compress(&original, writes);
                // GzDecoder reads one member and checks its CRC-32 and length.
                let mut back = Vec::new();
                GzDecoder::new(&gz[..]).read_to_end(&mut back).expect("a valid gzip member");
                assert!(back == original, "{n} bytes written {writes} at a time");
                let trailing = &gz[gz.len() - 8..];
                let len = u32::try_from(n % (1 << 32)).expect("fits");
                assert_eq!(trailing[4..], len.to_le_bytes(), "ISIZE");
            }
        }
    }

    #[test]
    fn the_size_is_within_one_percent_of_one_stream() {
        let original = data(6 * PIECE_BYTES);
        let parallel = compress(&original, 65536).len();
        let mut one = flate2::write::GzEncoder::new(Vec::new(), Compression::default());
        one.write_all(&original).expect("write");
        let serial = one.finish().expect("finish").len();
        #[allow(clippy::cast_precision_loss, reason = "sizes of a few MB")]
        let ratio = parallel as f64 / serial as f64;
        assert!(ratio < 1.01, "{parallel} bytes against {serial}");
    }
}
