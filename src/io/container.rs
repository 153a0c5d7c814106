//! The checksummed container of edpm's binary data files (analysis
//! snapshots, checkpoints such as `final_state.bin`): a fixed header that
//! names the kind of file, its format version and the run that wrote it,
//! a table of CRC-32s of the payload in [`CHUNK_BYTES`] chunks, then the
//! payload (bincode, fixed-int, little-endian). A damaged or truncated file
//! is refused with the byte offset of the damage (to within a chunk).
//! The bytes are described in docs/data-files.md.
//!
//! ```text
//! offset  size  field
//!  0       8    magic (names the kind, e.g. "EDPMSNAP")
//!  8       4    format version of the payload, u32
//! 12       4    chunk size C, u32 (4096)
//! 16       8    payload length L, u64
//! 24       8    run id, u64
//! 32       4    number of chunks ceil(L / C), u32
//! 36       4    reserved, zero
//! 40       4    CRC-32 of the chunk table
//! 44       4    CRC-32 of bytes 0..44
//! 48      4·n   CRC-32 of each chunk of the payload
//! 48+4n    L    payload
//! ```

use std::io::Read;
use std::path::Path;

use anyhow::Context;
use serde::Serialize;
use serde::de::DeserializeOwned;

/// Size of the fixed header (bytes).
pub const HEADER_BYTES: usize = 48;
/// Payload bytes covered by one CRC-32.
pub const CHUNK_BYTES: usize = 4096;

/// One kind of data file.
#[derive(Clone, Debug)]
pub struct Kind {
    pub magic: [u8; 8],
    /// What the file is, in messages ("snapshot").
    pub what: &'static str,
    /// Payload format version this build writes and reads.
    pub version: u32,
    /// Versions written by older builds without this container (their
    /// first 4 bytes were the version, 1 up to this), refused with a plain
    /// message.
    pub legacy_up_to: u32,
}

/// The header of a data file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    pub version: u32,
    pub payload_len: u64,
    pub run_id: u64,
    pub chunks: u32,
}

impl Header {
    /// Byte offset of the payload.
    pub fn payload_offset(&self) -> usize {
        HEADER_BYTES + 4 * self.chunks as usize
    }
}

type Config = bincode::config::Configuration<
    bincode::config::LittleEndian,
    bincode::config::Fixint,
    bincode::config::NoLimit,
>;

fn bincode_config() -> Config {
    bincode::config::standard()
        .with_little_endian()
        .with_fixed_int_encoding()
}

/// `value` encoded as a data file of `kind` written by run `run_id`.
pub fn encode<T: Serialize>(kind: &Kind, run_id: u64, value: &T) -> anyhow::Result<Vec<u8>> {
    let payload = bincode::serde::encode_to_vec(value, bincode_config())
        .with_context(|| format!("encoding {}", kind.what))?;
    encode_payload(kind, run_id, &payload)
}

/// An encoded payload wrapped as a data file of `kind` (header, chunk
/// checksums, payload).
pub fn encode_payload(kind: &Kind, run_id: u64, payload: &[u8]) -> anyhow::Result<Vec<u8>> {
    let chunks = u32::try_from(payload.len().div_ceil(CHUNK_BYTES))
        .with_context(|| format!("{} exceeds 16 TiB", kind.what))?;
    let mut out = Vec::with_capacity(HEADER_BYTES + 4 * chunks as usize + payload.len());
    out.extend_from_slice(&kind.magic);
    out.extend_from_slice(&kind.version.to_le_bytes());
    out.extend_from_slice(&(CHUNK_BYTES as u32).to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&run_id.to_le_bytes());
    out.extend_from_slice(&chunks.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    let table: Vec<u8> = payload
        .chunks(CHUNK_BYTES)
        .flat_map(|c| crc32fast::hash(c).to_le_bytes())
        .collect();
    out.extend_from_slice(&crc32fast::hash(&table).to_le_bytes());
    let header_crc = crc32fast::hash(&out[..44]);
    out.extend_from_slice(&header_crc.to_le_bytes());
    out.extend_from_slice(&table);
    out.extend_from_slice(payload);
    Ok(out)
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}

/// Checks and decodes the fixed header from the first bytes of a file
/// (`file_len` is the whole file's length); `name` names the file in
/// messages.
pub fn decode_header(kind: &Kind, name: &str, b: &[u8], file_len: u64) -> anyhow::Result<Header> {
    let what = kind.what;
    let magic = String::from_utf8_lossy(&kind.magic[..7]);
    let n = b.len().min(8);
    if b[..n] != kind.magic[..n] {
        let old = if b.len() >= 4 { u32_at(b, 0) } else { 0 };
        if (1..=kind.legacy_up_to).contains(&old) {
            anyhow::bail!(
                "{name}: an edpm {what} of format version {old}, written by an older edpm without checksums; \
                 this edpm reads version {} only: run the scenario again to write it",
                kind.version
            );
        }
        anyhow::bail!("{name}: not an edpm {what}: bytes 0..8 are not the magic \"{magic}\\0\"");
    }
    if b.len() < HEADER_BYTES {
        anyhow::bail!(
            "{name}: truncated at byte offset {}: an edpm {what} starts with a {HEADER_BYTES}-byte header",
            b.len()
        );
    }
    if crc32fast::hash(&b[..44]) != u32_at(b, 44) {
        anyhow::bail!(
            "{name}: checksum mismatch in the header (byte offsets 0..44): the {what} is damaged"
        );
    }
    let header = Header {
        version: u32_at(b, 8),
        payload_len: u64_at(b, 16),
        run_id: u64_at(b, 24),
        chunks: u32_at(b, 32),
    };
    if header.version != kind.version {
        anyhow::bail!(
            "{name}: {what} format version {} is not supported (this edpm reads version {})",
            header.version,
            kind.version
        );
    }
    if u32_at(b, 12) as usize != CHUNK_BYTES
        || header.payload_len.div_ceil(CHUNK_BYTES as u64) != header.chunks as u64
    {
        anyhow::bail!(
            "{name}: malformed header (chunk size {}, {} chunks for a payload of {} bytes)",
            u32_at(b, 12),
            header.chunks,
            header.payload_len
        );
    }
    let expected = header.payload_offset() as u64 + header.payload_len;
    if file_len < expected {
        anyhow::bail!(
            "{name}: truncated at byte offset {file_len}: the header announces {expected} bytes"
        );
    }
    if file_len > expected {
        anyhow::bail!(
            "{name}: {} unexpected bytes after the end of the {what} at byte offset {expected}",
            file_len - expected
        );
    }
    Ok(header)
}

/// Reads only the header of the data file at `path` (for its run id).
pub fn read_header(kind: &Kind, path: &Path) -> anyhow::Result<Header> {
    let name = path.display().to_string();
    let mut f = std::fs::File::open(path).with_context(|| format!("reading {name}"))?;
    let len = f
        .metadata()
        .with_context(|| format!("reading {name}"))?
        .len();
    let mut b = Vec::with_capacity(HEADER_BYTES);
    f.by_ref()
        .take(HEADER_BYTES as u64)
        .read_to_end(&mut b)
        .with_context(|| format!("reading {name}"))?;
    decode_header(kind, &name, &b, len)
}

/// Checks a whole data file's bytes and decodes its payload; `name` names
/// the file in messages.
pub fn decode<T: DeserializeOwned>(
    kind: &Kind,
    name: &str,
    b: &[u8],
) -> anyhow::Result<(Header, T)> {
    let header = decode_header(kind, name, b, b.len() as u64)?;
    let table = &b[HEADER_BYTES..header.payload_offset()];
    if crc32fast::hash(table) != u32_at(b, 40) {
        anyhow::bail!(
            "{name}: checksum mismatch in the chunk table (byte offsets {HEADER_BYTES}..{}): the {} is damaged",
            header.payload_offset(),
            kind.what
        );
    }
    let payload = &b[header.payload_offset()..];
    for (k, chunk) in payload.chunks(CHUNK_BYTES).enumerate() {
        if crc32fast::hash(chunk) != u32_at(table, 4 * k) {
            let start = header.payload_offset() + k * CHUNK_BYTES;
            anyhow::bail!(
                "{name}: checksum mismatch at byte offsets {start}..{}: the {} is damaged there",
                start + chunk.len(),
                kind.what
            );
        }
    }
    let value = decode_bounded(payload).map_err(|e| {
        anyhow::anyhow!(
            "{name}: the {} payload does not decode at byte offset {}: {}",
            kind.what,
            header.payload_offset() + failure_offset::<T>(payload),
            plain_decode_error(&e)
        )
    })?;
    if value.1 != payload.len() {
        anyhow::bail!(
            "{name}: {} unexpected bytes inside the {} payload at byte offset {}",
            payload.len() - value.1,
            kind.what,
            header.payload_offset() + value.1
        );
    }
    Ok((header, value.0))
}

/// Reads and decodes the data file at `path`.
pub fn read<T: DeserializeOwned>(kind: &Kind, path: &Path) -> anyhow::Result<(Header, T)> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    decode(kind, &path.display().to_string(), &bytes)
}

/// Decodes with bincode's allocation limit set to a power of two of at
/// least twice the payload's length. bincode allocates a string's or a
/// vector's memory before reading it, so without a limit a damaged or
/// forged length prefix aborts the process with an allocation of up to
/// 2⁶⁴ bytes; with it, the decoder never claims more than the payload can
/// hold (the limit is a compile-time constant in bincode 2, hence the
/// steps). Returns the value and the bytes used.
pub fn decode_bounded<T: DeserializeOwned>(
    payload: &[u8],
) -> Result<(T, usize), bincode::error::DecodeError> {
    fn limited<T: DeserializeOwned, const N: usize>(
        payload: &[u8],
    ) -> Result<(T, usize), bincode::error::DecodeError> {
        let config = bincode_config().with_limit::<N>();
        bincode::serde::decode_from_slice(payload, config)
    }
    match 2 * payload.len() as u64 {
        n if n <= 1 << 16 => limited::<T, { 1 << 16 }>(payload),
        n if n <= 1 << 20 => limited::<T, { 1 << 20 }>(payload),
        n if n <= 1 << 24 => limited::<T, { 1 << 24 }>(payload),
        n if n <= 1 << 28 => limited::<T, { 1 << 28 }>(payload),
        n if n <= 1 << 30 => limited::<T, { 1 << 30 }>(payload),
        n if n <= 1 << 32 => limited::<T, { 1 << 32 }>(payload),
        n if n <= 1 << 36 => limited::<T, { 1 << 36 }>(payload),
        _ => limited::<T, { 1 << 40 }>(payload),
    }
}

/// Bytes of `payload` the decoder had consumed when it failed: the payload
/// decoded again through a reader that counts (only on the error path).
fn failure_offset<T: DeserializeOwned>(payload: &[u8]) -> usize {
    struct Counting<'a> {
        inner: &'a [u8],
        used: usize,
    }
    impl Read for Counting<'_> {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let n = self.inner.read(buf)?;
            self.used += n;
            Ok(n)
        }
    }
    let mut r = Counting {
        inner: payload,
        used: 0,
    };
    let config = bincode_config().with_limit::<{ 1 << 40 }>();
    let _ = bincode::serde::decode_from_std_read::<T, _, _>(&mut r, config);
    r.used
}

/// A bincode decoding error in plain words (its `Display` is Rust debug
/// text).
pub fn plain_decode_error(e: &bincode::error::DecodeError) -> String {
    use bincode::error::DecodeError as E;
    match e {
        E::UnexpectedEnd { additional } => {
            format!("the data ends early ({additional} more bytes needed)")
        }
        E::LimitExceeded => "a length field claims more bytes than the file holds".into(),
        E::UnexpectedVariant { found, .. } => format!("unknown enum variant {found}"),
        E::Utf8 { .. } => "a text field is not valid UTF-8".into(),
        E::InvalidBooleanValue(v) => format!("{v} is not a boolean (0 or 1)"),
        E::OutsideUsizeRange(v) => format!("the length {v} is out of range"),
        _ => "the bytes do not match the layout of this format version".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEST: Kind = Kind {
        magic: *b"EDPMTEST",
        what: "test file",
        version: 3,
        legacy_up_to: 2,
    };

    #[test]
    fn round_trips_and_locates_damage_to_its_chunk() {
        let value: Vec<f64> = (0..2000).map(|k| k as f64 * 0.5).collect();
        let bytes = encode(&TEST, 0xabc, &value).unwrap();
        let (h, back): (Header, Vec<f64>) = decode(&TEST, "t.bin", &bytes).unwrap();
        assert_eq!((h.run_id, back), (0xabc, value));
        // 8 + 16000 payload bytes: 4 chunks, payload at 48 + 16.
        assert_eq!(h.payload_offset(), 64);
        let mut bad = bytes.clone();
        bad[64 + 5000] ^= 4;
        let e = decode::<Vec<f64>>(&TEST, "t.bin", &bad).unwrap_err();
        assert_eq!(
            e.to_string(),
            "t.bin: checksum mismatch at byte offsets 4160..8256: the test file is damaged there"
        );
    }
}
