//! Reader for CTranslate2's `model.bin` (binary versions 4 to 6):
//!
//! ```text
//! u32 binary_version
//! str spec_name, u32 spec_revision          (str = u16 length incl. NUL, bytes)
//! u32 n_variables, then per variable:
//!     str name, u8 rank, u32 dims[rank], u8 dtype, u32 n_bytes, bytes data
//! u32 n_aliases, then per alias: str alias, str target
//! ```
//! dtype follows CTranslate2's `DataType`: 0 f32, 1 i8, 2 i16, 3 i32, 4 f16, 5 bf16.

use std::collections::BTreeMap;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DType {
    F32,
    I8,
    I16,
    I32,
    F16,
    BF16,
}

impl DType {
    fn from_id(id: u8) -> Option<Self> {
        Some(match id {
            0 => Self::F32,
            1 => Self::I8,
            2 => Self::I16,
            3 => Self::I32,
            4 => Self::F16,
            5 => Self::BF16,
            _ => return None,
        })
    }

    pub fn size(self) -> usize {
        match self {
            Self::I8 => 1,
            Self::I16 | Self::F16 | Self::BF16 => 2,
            Self::F32 | Self::I32 => 4,
        }
    }
}

/// One stored tensor; `data` borrows the file's bytes (little-endian).
#[derive(Clone, Debug, PartialEq)]
pub struct Variable<'a> {
    pub shape: Vec<usize>,
    pub dtype: DType,
    pub data: &'a [u8],
}

impl Variable<'_> {
    /// The value of a scalar integer variable (CTranslate2 stores model
    /// options such as `num_heads` this way).
    pub fn as_int(&self) -> Option<i64> {
        if !self.shape.iter().all(|&d| d == 1) {
            return None;
        }
        let d = self.data;
        Some(match self.dtype {
            DType::I8 => d[0] as i8 as i64,
            DType::I16 => i16::from_le_bytes([d[0], d[1]]) as i64,
            DType::I32 => i32::from_le_bytes([d[0], d[1], d[2], d[3]]) as i64,
            _ => return None,
        })
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Model<'a> {
    pub binary_version: u32,
    pub spec: String,
    pub spec_revision: u32,
    pub variables: BTreeMap<String, Variable<'a>>,
    /// alias → name of the variable it stands for.
    pub aliases: BTreeMap<String, String>,
}

impl<'a> Model<'a> {
    /// A variable by name, following aliases.
    pub fn get(&self, name: &str) -> Option<&Variable<'a>> {
        self.variables.get(name).or_else(|| self.aliases.get(name).and_then(|n| self.variables.get(n)))
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum Ct2Error {
    #[error("the file ends at byte {at} while reading {what}")]
    Eof { at: usize, what: &'static str },
    #[error("binary version {0} is not supported (versions 4 to 6 are)")]
    Version(u32),
    #[error("variable {name}: unknown dtype id {id}")]
    DType { name: String, id: u8 },
    #[error("variable {name}: {bytes} bytes do not hold shape {shape:?} of {dtype:?}")]
    Size { name: String, bytes: usize, shape: Vec<usize>, dtype: DType },
    #[error("a name is not UTF-8 at byte {0}")]
    Utf8(usize),
    #[error("{0} unexpected bytes after the aliases")]
    Trailing(usize),
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], Ct2Error> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.b.len()).ok_or(Ct2Error::Eof { at: self.at, what })?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u8(&mut self, what: &'static str) -> Result<u8, Ct2Error> {
        Ok(self.take(1, what)?[0])
    }
    fn u16(&mut self, what: &'static str) -> Result<u16, Ct2Error> {
        let b = self.take(2, what)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self, what: &'static str) -> Result<u32, Ct2Error> {
        let b = self.take(4, what)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn string(&mut self, what: &'static str) -> Result<String, Ct2Error> {
        let at = self.at;
        let n = self.u16(what)? as usize;
        let raw = self.take(n, what)?;
        let raw = raw.strip_suffix(&[0]).unwrap_or(raw);
        String::from_utf8(raw.to_vec()).map_err(|_| Ct2Error::Utf8(at))
    }
}

/// Parses a whole `model.bin`.
pub fn parse(bytes: &[u8]) -> Result<Model<'_>, Ct2Error> {
    let mut r = Reader { b: bytes, at: 0 };
    let binary_version = r.u32("the binary version")?;
    if !(4..=6).contains(&binary_version) {
        return Err(Ct2Error::Version(binary_version));
    }
    let spec = r.string("the spec name")?;
    let spec_revision = r.u32("the spec revision")?;
    let n = r.u32("the variable count")?;
    let mut variables = BTreeMap::new();
    for _ in 0..n {
        let name = r.string("a variable name")?;
        let rank = r.u8("a rank")? as usize;
        let shape = (0..rank).map(|_| r.u32("a dimension").map(|d| d as usize)).collect::<Result<Vec<_>, _>>()?;
        let id = r.u8("a dtype")?;
        let dtype = DType::from_id(id).ok_or_else(|| Ct2Error::DType { name: name.clone(), id })?;
        let bytes = r.u32("a byte count")? as usize;
        if shape.iter().product::<usize>() * dtype.size() != bytes {
            return Err(Ct2Error::Size { name, bytes, shape, dtype });
        }
        let data = r.take(bytes, "variable data")?;
        variables.insert(name, Variable { shape, dtype, data });
    }
    let mut aliases = BTreeMap::new();
    let n_aliases = r.u32("the alias count")?;
    for _ in 0..n_aliases {
        let alias = r.string("an alias")?;
        let target = r.string("an alias target")?;
        aliases.insert(alias, target);
    }
    if r.at != bytes.len() {
        return Err(Ct2Error::Trailing(bytes.len() - r.at));
    }
    Ok(Model { binary_version, spec, spec_revision, variables, aliases })
}

/// Writes a `model.bin` (the inverse of [`parse`]); used to build test models.
pub fn write(
    spec: &str,
    spec_revision: u32,
    variables: &[(&str, Vec<usize>, DType, Vec<u8>)],
    aliases: &[(&str, &str)],
) -> Vec<u8> {
    fn string(out: &mut Vec<u8>, s: &str) {
        out.extend_from_slice(&((s.len() + 1) as u16).to_le_bytes());
        out.extend_from_slice(s.as_bytes());
        out.push(0);
    }
    let mut out = Vec::new();
    out.extend_from_slice(&6u32.to_le_bytes());
    string(&mut out, spec);
    out.extend_from_slice(&spec_revision.to_le_bytes());
    out.extend_from_slice(&(variables.len() as u32).to_le_bytes());
    for (name, shape, dtype, data) in variables {
        string(&mut out, name);
        out.push(shape.len() as u8);
        for d in shape {
            out.extend_from_slice(&(*d as u32).to_le_bytes());
        }
        out.push(match dtype {
            DType::F32 => 0,
            DType::I8 => 1,
            DType::I16 => 2,
            DType::I32 => 3,
            DType::F16 => 4,
            DType::BF16 => 5,
        });
        out.extend_from_slice(&(data.len() as u32).to_le_bytes());
        out.extend_from_slice(data);
    }
    out.extend_from_slice(&(aliases.len() as u32).to_le_bytes());
    for (a, t) in aliases {
        string(&mut out, a);
        string(&mut out, t);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn written_models_parse_back() {
        let bytes = write(
            "WhisperSpec",
            3,
            &[
                ("a/num_heads", vec![], DType::I16, 6i16.to_le_bytes().to_vec()),
                ("a/weight", vec![2, 3], DType::F32, (0..6).flat_map(|i| (i as f32).to_le_bytes()).collect()),
            ],
            &[("a/projection", "a/weight")],
        );
        let m = parse(&bytes).unwrap();
        assert_eq!((m.binary_version, m.spec.as_str(), m.spec_revision), (6, "WhisperSpec", 3));
        assert_eq!(m.get("a/num_heads").unwrap().as_int(), Some(6));
        let w = m.get("a/projection").unwrap();
        assert_eq!((w.shape.clone(), w.dtype, w.data.len()), (vec![2, 3], DType::F32, 24));
        assert_eq!(m.get("missing"), None);
    }

    #[test]
    fn damaged_files_are_reported_not_panicked_on() {
        let bytes = write("S", 1, &[("w", vec![4], DType::F16, vec![0; 8])], &[]);
        for cut in [0, 3, 10, 20, bytes.len() - 5, bytes.len() - 1] {
            assert!(matches!(parse(&bytes[..cut]), Err(Ct2Error::Eof { .. })), "cut at {cut}");
        }
        let mut extra = bytes.clone();
        extra.push(0);
        assert_eq!(parse(&extra), Err(Ct2Error::Trailing(1)));
        let mut old = bytes.clone();
        old[0] = 1;
        assert_eq!(parse(&old), Err(Ct2Error::Version(1)));
        let wrong_size = write("S", 1, &[("w", vec![4], DType::F16, vec![0; 6])], &[]);
        assert!(matches!(parse(&wrong_size), Err(Ct2Error::Size { .. })));
    }
}
