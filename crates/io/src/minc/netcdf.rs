//! The netCDF classic format (`CDF` 1, and 2 with 64-bit offsets), which MINC 1 files are: a big-endian header of
//! dimensions, global attributes and variables (each with its dimensions, attributes, type and the offset of its
//! values), then the values. Written here rather than taken from the `netcdf3` crate, which allocates what a header
//! claims before checking it against the file (fuzzing found a 30 GB request in a 300-byte file): every count and
//! extent is checked against the bytes present before anything is allocated.

/// A netCDF external type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum NcType {
    Byte,
    Char,
    Short,
    Int,
    Float,
    Double,
}

impl NcType {
    fn of(code: u32) -> Option<Self> {
        Some(match code {
            1 => Self::Byte,
            2 => Self::Char,
            3 => Self::Short,
            4 => Self::Int,
            5 => Self::Float,
            6 => Self::Double,
            _ => return None,
        })
    }

    pub(super) const fn size(self) -> usize {
        match self {
            Self::Byte | Self::Char => 1,
            Self::Short => 2,
            Self::Int | Self::Float => 4,
            Self::Double => 8,
        }
    }
}

/// An attribute's values.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Values {
    Text(String),
    Numbers(Vec<f64>),
}

#[derive(Clone, Debug)]
pub(super) struct Dim {
    pub name: String,
    /// Its length; the record dimension's is the file's record count.
    pub len: u64,
    pub record: bool,
}

#[derive(Clone, Debug)]
pub(super) struct Var {
    pub name: String,
    pub dims: Vec<usize>,
    pub attrs: Vec<(String, Values)>,
    pub nc_type: NcType,
    /// Bytes of one record's slab (of the whole variable when it has no record dimension), as the header says.
    vsize: u64,
    begin: u64,
}

impl Var {
    pub(super) fn attr(&self, key: &str) -> Option<&Values> {
        self.attrs.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }

    pub(super) fn text(&self, key: &str) -> Option<String> {
        match self.attr(key)? {
            Values::Text(s) => Some(s.trim_end_matches('\0').to_string()),
            Values::Numbers(_) => None,
        }
    }

    pub(super) fn numbers(&self, key: &str) -> Option<&[f64]> {
        match self.attr(key)? {
            Values::Numbers(v) => Some(v),
            Values::Text(_) => None,
        }
    }
}

/// A parsed netCDF classic file over its bytes.
#[derive(Debug)]
pub(super) struct NcFile {
    bytes: Vec<u8>,
    pub dims: Vec<Dim>,
    pub vars: Vec<Var>,
    records: u64,
}

/// What went wrong, for the caller to name the file.
pub(super) type Fault = String;

struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize, what: &str) -> Result<&[u8], Fault> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let Some(end) = end else { return Err(format!("the header ends inside {what}")) };
        let out = &self.bytes[self.at..end];
        self.at = end;
        Ok(out)
    }

    fn u32(&mut self, what: &str) -> Result<u32, Fault> {
        let b = self.take(4, what)?;
        Ok(u32::from_be_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self, what: &str) -> Result<u64, Fault> {
        let b = self.take(8, what)?;
        Ok(u64::from_be_bytes(std::array::from_fn(|k| b[k])))
    }

    fn left(&self) -> usize {
        self.bytes.len() - self.at
    }

    /// A count of items each at least `min_bytes` long, checked against the bytes left.
    fn count(&mut self, min_bytes: usize, what: &str) -> Result<usize, Fault> {
        let n = self.u32(what)? as usize;
        if n.saturating_mul(min_bytes) > self.left() {
            return Err(format!("the header claims {n} {what}, more than its {} bytes hold", self.left()));
        }
        Ok(n)
    }

    /// `n` bytes and the padding to a multiple of 4.
    fn padded(&mut self, n: usize, what: &str) -> Result<&[u8], Fault> {
        let pad = (4 - n % 4) % 4;
        let out_at = self.at;
        self.take(n.checked_add(pad).ok_or_else(|| format!("{what} is too long"))?, what)?;
        Ok(&self.bytes[out_at..out_at + n])
    }

    fn name(&mut self, what: &str) -> Result<String, Fault> {
        let n = self.count(1, what)?;
        let b = self.padded(n, what)?;
        String::from_utf8(b.to_vec()).map_err(|_| format!("a name in {what} is not UTF-8"))
    }

    /// A list's tag and count: ABSENT (two zeros) or `tag` and the number of items.
    fn list(&mut self, tag: u32, min_item: usize, what: &str) -> Result<usize, Fault> {
        let t = self.u32(what)?;
        let n = self.count(min_item, what)?;
        match t {
            0 if n == 0 => Ok(0),
            t if t == tag => Ok(n),
            t => Err(format!("the {what} list has tag {t}, not {tag}")),
        }
    }

    fn attrs(&mut self, what: &str) -> Result<Vec<(String, Values)>, Fault> {
        let n = self.list(0x0C, 12, what)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            let name = self.name(what)?;
            let code = self.u32(what)?;
            let nc_type = NcType::of(code).ok_or_else(|| format!("attribute {name} has type {code}"))?;
            let count = self.count(nc_type.size(), &format!("values of attribute {name}"))?;
            let b = self.padded(count * nc_type.size(), &format!("attribute {name}"))?;
            let values = match nc_type {
                NcType::Char => Values::Text(String::from_utf8_lossy(b).into_owned()),
                t => Values::Numbers(decode(t, b).collect()),
            };
            out.push((name, values));
        }
        Ok(out)
    }
}

/// The values of `bytes`, big-endian of type `t`, as doubles.
fn decode(t: NcType, bytes: &[u8]) -> impl Iterator<Item = f64> + '_ {
    bytes.chunks_exact(t.size()).map(move |b| match t {
        NcType::Byte => f64::from(b[0] as i8),
        NcType::Char => f64::from(b[0]),
        NcType::Short => f64::from(i16::from_be_bytes([b[0], b[1]])),
        NcType::Int => f64::from(i32::from_be_bytes([b[0], b[1], b[2], b[3]])),
        NcType::Float => f64::from(f32::from_be_bytes([b[0], b[1], b[2], b[3]])),
        NcType::Double => f64::from_be_bytes(std::array::from_fn(|k| b[k])),
    })
}

impl NcFile {
    /// Parses the header of `bytes`, a netCDF classic file.
    pub(super) fn parse(bytes: Vec<u8>) -> Result<Self, Fault> {
        let mut c = Cursor { bytes: &bytes, at: 0 };
        let magic = c.take(4, "the magic number")?;
        let wide = match magic {
            b"CDF\x01" => false,
            b"CDF\x02" => true,
            _ => return Err("it does not start with CDF 1 or CDF 2".to_string()),
        };
        let records = u64::from(c.u32("the record count")?);
        let n = c.list(0x0A, 8, "dimensions")?;
        let mut dims = Vec::with_capacity(n);
        for _ in 0..n {
            let name = c.name("dimensions")?;
            let len = c.u32("dimensions")?;
            dims.push(Dim { name, len: if len == 0 { records } else { u64::from(len) }, record: len == 0 });
        }
        if dims.iter().filter(|d| d.record).count() > 1 {
            return Err("it has more than one record dimension".to_string());
        }
        c.attrs("global attributes")?;
        let n = c.list(0x0B, 24, "variables")?;
        let mut vars = Vec::with_capacity(n);
        for _ in 0..n {
            let name = c.name("variables")?;
            let rank = c.count(4, &format!("dimensions of variable {name}"))?;
            let mut ids = Vec::with_capacity(rank);
            for _ in 0..rank {
                let id = c.u32("variables")? as usize;
                if id >= dims.len() || (dims[id].record && !ids.is_empty()) {
                    return Err(format!("variable {name} names dimension {id}, which is not one it may have"));
                }
                ids.push(id);
            }
            let attrs = c.attrs(&format!("attributes of variable {name}"))?;
            let code = c.u32("variables")?;
            let nc_type = NcType::of(code).ok_or_else(|| format!("variable {name} has type {code}"))?;
            let vsize = u64::from(c.u32("variables")?);
            let begin = if wide { c.u64("variables")? } else { u64::from(c.u32("variables")?) };
            vars.push(Var { name, dims: ids, attrs, nc_type, vsize, begin });
        }
        Ok(Self { bytes, dims, vars, records })
    }

    pub(super) fn var(&self, name: &str) -> Option<&Var> {
        self.vars.iter().find(|v| v.name == name)
    }

    /// The raw big-endian bytes of `var`'s values, records in order, after checking they lie inside the file.
    pub(super) fn raw(&self, var: &Var) -> Result<Vec<u8>, Fault> {
        let size = var.nc_type.size() as u64;
        let record = var.dims.first().is_some_and(|&d| self.dims[d].record);
        let per_record =
            var.dims.iter().skip(usize::from(record)).try_fold(1u64, |a, &d| a.checked_mul(self.dims[d].len));
        let slab = per_record.and_then(|n| n.checked_mul(size)).ok_or("its size overflows")?;
        let (records, stride) = if record {
            // The record stride is the sum of every record variable's slab (one variable's, unpadded, alone).
            let record_vars: Vec<&Var> =
                self.vars.iter().filter(|v| v.dims.first().is_some_and(|&d| self.dims[d].record)).collect();
            let stride = if record_vars.len() == 1 {
                slab
            } else {
                record_vars.iter().try_fold(0u64, |a, v| a.checked_add(v.vsize)).ok_or("the record size overflows")?
            };
            (self.records, stride)
        } else {
            (1, slab)
        };
        let total = slab.checked_mul(records).ok_or("its size overflows")?;
        if total > self.bytes.len() as u64 {
            return Err(format!(
                "variable {} holds {total} bytes, more than the file's {}",
                var.name,
                self.bytes.len()
            ));
        }
        let mut out = Vec::with_capacity(total as usize);
        for r in 0..records {
            let start = r.checked_mul(stride).and_then(|o| o.checked_add(var.begin));
            let end = start.and_then(|s| s.checked_add(slab)).filter(|&e| e <= self.bytes.len() as u64);
            let (Some(start), Some(end)) = (start, end) else {
                return Err(format!("variable {}'s values end past the end of the file", var.name));
            };
            out.extend_from_slice(&self.bytes[start as usize..end as usize]);
        }
        Ok(out)
    }

    /// `var`'s values as doubles (for the small variables: image-min, image-max).
    pub(super) fn numbers(&self, var: &Var) -> Result<Vec<f64>, Fault> {
        if var.nc_type == NcType::Char {
            return Err(format!("variable {} holds characters, not numbers", var.name));
        }
        Ok(decode(var.nc_type, &self.raw(var)?).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_beyond_the_bytes_are_refused_before_allocating() {
        // CDF 1, no records, a dimension list claiming 2^31 entries.
        let mut b = b"CDF\x01\0\0\0\0\0\0\0\x0a\x80\0\0\0".to_vec();
        b.extend_from_slice(&[0; 16]);
        let e = NcFile::parse(b).expect_err("too many");
        assert!(e.contains("more than its"), "{e}");
        let e = NcFile::parse(b"CDF\x05".to_vec()).expect_err("CDF 5");
        assert!(e.contains("CDF 1 or CDF 2"), "{e}");
    }
}
