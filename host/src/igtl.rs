//! The OpenIGTLink wire format (protocol 3.0, header versions 1 and 2): what navigation software
//! (3D Slicer with SlicerIGT, PLUS, and others) reads.
//!
//! Written from the protocol's documents (header, transform, status, tracking data, query and
//! timestamp pages) rather than taken from a crate: `openigtlink-rust` 0.4 writes header version
//! 2 on messages that have no extended header (which a header-1 client such as the OpenIGTLink
//! library 1.x cannot read, and the specification does not allow), encodes metadata values as
//! character set 0 (not an IANA character set) and pulls in tokio and rustls for what is a
//! 58-byte header and a few fixed layouts. Checked against pyigtl and the OpenIGTLink C++
//! library in `tests/tests/igtl_peers.rs`.
//!
//! A message is a 58-byte header (big endian: version u16, type `char[12]`, device name `char[20]`,
//! timestamp u64, body size u64, CRC-64 of the body u64) and a body. With header version 2 the
//! body is an extended header (its size u16 = 12, metadata header size u16, metadata size u32,
//! message id u32), the content, then the metadata: a header (count u16, then per entry key size
//! u16, value encoding u16, value size u32) and the keys and values. The CRC is ECMA-182
//! (polynomial 0x42F0E1EBA9EA3693, not reflected, initial value and final XOR 0). Timestamps
//! are seconds since 1970 in 32.32 fixed point.

use std::io::Read;

/// Size of the header, bytes.
pub const HEADER_BYTES: usize = 58;
/// Size of the extended header of header version 2, bytes.
pub const EXT_HEADER_BYTES: usize = 12;
/// The port OpenIGTLink servers listen on by default (Slicer's and PLUS's).
pub const DEFAULT_PORT: u16 = 18944;
/// Longest device name, bytes.
pub const MAX_NAME_BYTES: usize = 20;
/// IANA character set number of US-ASCII, the encoding of the metadata values written here.
pub const US_ASCII: u16 = 3;
/// Largest body accepted from a peer, bytes (queries and status messages are tiny).
pub const MAX_INCOMING_BODY: u64 = 1 << 20;
/// Size of a TRANSFORM content, bytes.
pub const TRANSFORM_BYTES: usize = 48;
/// Size of one TDATA element, bytes.
pub const TDATA_ELEMENT_BYTES: usize = 70;
/// TDATA instrument type of a 6-DoF instrument.
pub const TDATA_6D_INSTRUMENT: u8 = 2;

/// STATUS codes used here (the protocol's list).
pub mod status {
    /// OK (the default status).
    pub const OK: u16 = 1;
    /// Hardware failure.
    pub const HARDWARE_FAILURE: u16 = 18;
}

const CRC64: crc::Crc<u64> = crc::Crc::<u64>::new(&crc::CRC_64_ECMA_182);

/// The header version a message is written with.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum HeaderVersion {
    /// Protocol versions 1 and 2: the body is the content.
    V1 = 1,
    /// Protocol version 3: extended header, content, metadata.
    V2 = 2,
}

/// Why bytes from a peer are not an OpenIGTLink message.
#[derive(Debug, thiserror::Error)]
pub enum IgtlError {
    /// The connection failed or closed.
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// A header version this side does not know.
    #[error("header version {0} (1 and 2 are defined)")]
    Version(u16),
    /// A body larger than any message this side takes.
    #[error("{kind} message of {size} bytes (at most {MAX_INCOMING_BODY} taken)")]
    TooLarge {
        /// Message type.
        kind: String,
        /// Body size, bytes.
        size: u64,
    },
    /// The body's layout does not add up.
    #[error("{kind} message: {what}")]
    Layout {
        /// Message type.
        kind: String,
        /// What is wrong.
        what: String,
    },
}

/// ECMA-182 CRC-64 of `bytes`, as in the header.
pub fn crc64(bytes: &[u8]) -> u64 {
    CRC64.checksum(bytes)
}

/// The protocol's conversion of nanoseconds to a binary fraction of a second (bit by bit).
fn nanos_to_fraction(mut nanos: u32) -> u32 {
    let (mut base, mut mask, mut fraction) = (1_000_000_000u32, 0x8000_0000u32, 0u32);
    while mask != 0 {
        base = (base + 1) >> 1;
        if nanos >= base {
            fraction |= mask;
            nanos -= base;
        }
        mask >>= 1;
    }
    fraction
}

/// Its inverse.
fn fraction_to_nanos(fraction: u32) -> u32 {
    let (mut base, mut mask, mut nanos) = (1_000_000_000u32, 0x8000_0000u32, 0u32);
    while mask != 0 {
        base = (base + 1) >> 1;
        if fraction & mask != 0 {
            nanos += base;
        }
        mask >>= 1;
    }
    nanos
}

/// Seconds since 1970 as a header timestamp (32.32 fixed point, nanosecond resolution).
pub fn timestamp(unix_s: f64) -> u64 {
    let unix_s = unix_s.clamp(0.0, u32::MAX as f64);
    let seconds = unix_s.floor();
    let nanos = ((unix_s - seconds) * 1e9).round().min(999_999_999.0) as u32;
    ((seconds as u64) << 32) | nanos_to_fraction(nanos) as u64
}

/// A header timestamp as seconds since 1970.
pub fn unix_seconds(timestamp: u64) -> f64 {
    (timestamp >> 32) as f64 + fraction_to_nanos(timestamp as u32) as f64 * 1e-9
}

/// Whether `name` can be a device name: 1 to 20 printable ASCII characters.
pub fn valid_name(name: &str) -> bool {
    (1..=MAX_NAME_BYTES).contains(&name.len()) && name.bytes().all(|b| b.is_ascii_graphic())
}

/// A message ready to send: `kind` (e.g. `TRANSFORM`) named `device`, stamped `timestamp`, with
/// `content`; with header version 2 also the extended header (message id `id`) and `metadata`
/// (US-ASCII values; header version 1 has no place for them and drops them).
pub fn encode(
    version: HeaderVersion,
    kind: &str,
    device: &str,
    timestamp: u64,
    content: &[u8],
    metadata: &[(&str, &str)],
    id: u32,
) -> Vec<u8> {
    let mut body = Vec::with_capacity(EXT_HEADER_BYTES + content.len() + 64);
    if version == HeaderVersion::V2 {
        let meta_header = 2 + 8 * metadata.len();
        let meta_size: usize = metadata.iter().map(|(k, v)| k.len() + v.len()).sum();
        body.extend_from_slice(&(EXT_HEADER_BYTES as u16).to_be_bytes());
        body.extend_from_slice(&(meta_header as u16).to_be_bytes());
        body.extend_from_slice(&(meta_size as u32).to_be_bytes());
        body.extend_from_slice(&id.to_be_bytes());
        body.extend_from_slice(content);
        body.extend_from_slice(&(metadata.len() as u16).to_be_bytes());
        for (key, value) in metadata {
            body.extend_from_slice(&(key.len() as u16).to_be_bytes());
            body.extend_from_slice(&US_ASCII.to_be_bytes());
            body.extend_from_slice(&(value.len() as u32).to_be_bytes());
        }
        for (key, value) in metadata {
            body.extend_from_slice(key.as_bytes());
            body.extend_from_slice(value.as_bytes());
        }
    } else {
        body.extend_from_slice(content);
    }
    let mut out = Vec::with_capacity(HEADER_BYTES + body.len());
    out.extend_from_slice(&(version as u16).to_be_bytes());
    out.extend_from_slice(&fixed::<12>(kind));
    out.extend_from_slice(&fixed::<MAX_NAME_BYTES>(device));
    out.extend_from_slice(&timestamp.to_be_bytes());
    out.extend_from_slice(&(body.len() as u64).to_be_bytes());
    out.extend_from_slice(&crc64(&body).to_be_bytes());
    out.extend_from_slice(&body);
    out
}

/// `text` in a zero-padded field of `N` bytes (cut at `N`).
fn fixed<const N: usize>(text: &str) -> [u8; N] {
    let mut out = [0u8; N];
    for (o, b) in out.iter_mut().zip(text.bytes()) {
        *o = b;
    }
    out
}

/// The text of a zero-padded field.
fn text_of(field: &[u8]) -> String {
    let end = field.iter().position(|&b| b == 0).unwrap_or(field.len());
    String::from_utf8_lossy(&field[..end]).into_owned()
}

/// The upper three rows of a 4×4 transform as TRANSFORM content (column by column: R11 R21 R31
/// R12 … R33, then TX TY TZ in mm).
pub fn transform_content(rows: &[[f32; 4]; 3]) -> [u8; TRANSFORM_BYTES] {
    let mut out = [0u8; TRANSFORM_BYTES];
    for (row, values) in rows.iter().enumerate() {
        for (col, value) in values.iter().enumerate() {
            let at = (col * 3 + row) * 4;
            out[at..at + 4].copy_from_slice(&value.to_be_bytes());
        }
    }
    out
}

/// The rows of TRANSFORM content (the inverse of [`transform_content`]).
pub fn transform_rows(content: &[u8]) -> Option<[[f32; 4]; 3]> {
    if content.len() != TRANSFORM_BYTES {
        return None;
    }
    let value = |k: usize| {
        f32::from_be_bytes([content[4 * k], content[4 * k + 1], content[4 * k + 2], content[4 * k + 3]])
    };
    Some(std::array::from_fn(|row| std::array::from_fn(|col| value(col * 3 + row))))
}

/// STATUS content: `code`, a device-specific `sub_code`, a short `error_name` (≤ 20 bytes) and a
/// message (written with its terminating zero, as the C++ library does).
pub fn status_content(code: u16, sub_code: i64, error_name: &str, message: &str) -> Vec<u8> {
    let mut out = Vec::with_capacity(31 + message.len());
    out.extend_from_slice(&code.to_be_bytes());
    out.extend_from_slice(&sub_code.to_be_bytes());
    out.extend_from_slice(&fixed::<20>(error_name));
    out.extend_from_slice(message.as_bytes());
    out.push(0);
    out
}

/// A STATUS content read back: code, sub-code, error name, message.
pub fn status_fields(content: &[u8]) -> Option<(u16, i64, String, String)> {
    if content.len() < 30 {
        return None;
    }
    let code = u16::from_be_bytes([content[0], content[1]]);
    let sub = i64::from_be_bytes(content[2..10].try_into().ok()?);
    Some((code, sub, text_of(&content[10..30]), text_of(&content[30..])))
}

/// One TDATA element: instrument `name`, type [`TDATA_6D_INSTRUMENT`], its transform rows.
pub fn tdata_element(name: &str, rows: &[[f32; 4]; 3]) -> [u8; TDATA_ELEMENT_BYTES] {
    let mut out = [0u8; TDATA_ELEMENT_BYTES];
    out[..20].copy_from_slice(&fixed::<20>(name));
    out[20] = TDATA_6D_INSTRUMENT;
    out[22..].copy_from_slice(&transform_content(rows));
    out
}

/// A message as received.
#[derive(Clone, Debug, PartialEq)]
pub struct Incoming {
    /// Header version.
    pub version: u16,
    /// Message type, e.g. `STT_TDATA`.
    pub kind: String,
    /// Device name.
    pub device: String,
    /// Timestamp (32.32 fixed point; 0: unused).
    pub timestamp: u64,
    /// The body's CRC matches the header's (when not, `content` is the whole body, uninterpreted).
    pub crc_ok: bool,
    /// The content (without extended header and metadata).
    pub content: Vec<u8>,
    /// Metadata (header version 2), key and value.
    pub metadata: Vec<(String, String)>,
}

/// Read one message from `reader` (blocking until it is complete).
pub fn read_message(reader: &mut impl Read) -> Result<Incoming, IgtlError> {
    let mut header = [0u8; HEADER_BYTES];
    reader.read_exact(&mut header)?;
    let version = u16::from_be_bytes([header[0], header[1]]);
    let kind = text_of(&header[2..14]);
    let device = text_of(&header[14..34]);
    let be64 = |at: usize| u64::from_be_bytes(header[at..at + 8].try_into().unwrap_or([0; 8]));
    let (timestamp, size, crc) = (be64(34), be64(42), be64(50));
    if size > MAX_INCOMING_BODY {
        return Err(IgtlError::TooLarge { kind, size });
    }
    let mut body = vec![0u8; size as usize];
    reader.read_exact(&mut body)?;
    if crc64(&body) != crc {
        // Damaged: nothing in it is interpreted.
        return Ok(Incoming {
            version,
            kind,
            device,
            timestamp,
            crc_ok: false,
            content: body,
            metadata: Vec::new(),
        });
    }
    let layout = |what: String| IgtlError::Layout { kind: kind.clone(), what };
    let (content, metadata) = match version {
        1 => (body, Vec::new()),
        2 => {
            if body.len() < EXT_HEADER_BYTES {
                return Err(layout(format!("{} body bytes, shorter than the extended header", body.len())));
            }
            let ext = u16::from_be_bytes([body[0], body[1]]) as usize;
            let meta_header = u16::from_be_bytes([body[2], body[3]]) as usize;
            let meta_size = u32::from_be_bytes([body[4], body[5], body[6], body[7]]) as usize;
            let content_end = body.len().checked_sub(meta_header + meta_size).filter(|&e| e >= ext);
            let Some(content_end) = content_end.filter(|_| ext >= EXT_HEADER_BYTES) else {
                return Err(layout(format!(
                    "extended header {ext} B, metadata {meta_header} + {meta_size} B do not fit a body of {} B",
                    body.len()
                )));
            };
            let metadata = read_metadata(&body[content_end..], meta_header).map_err(layout)?;
            (body[ext..content_end].to_vec(), metadata)
        }
        v => return Err(IgtlError::Version(v)),
    };
    Ok(Incoming { version, kind, device, timestamp, crc_ok: true, content, metadata })
}

/// The metadata section: its header (`header_bytes` long) then keys and values.
fn read_metadata(bytes: &[u8], header_bytes: usize) -> Result<Vec<(String, String)>, String> {
    if header_bytes < 2 {
        return Ok(Vec::new());
    }
    let count = u16::from_be_bytes([bytes[0], bytes[1]]) as usize;
    if 2 + 8 * count > header_bytes {
        return Err(format!("{count} metadata entries do not fit a metadata header of {header_bytes} B"));
    }
    let mut at = header_bytes;
    let mut out = Vec::with_capacity(count);
    for k in 0..count {
        let e = &bytes[2 + 8 * k..10 + 8 * k];
        let key_len = u16::from_be_bytes([e[0], e[1]]) as usize;
        let value_len = u32::from_be_bytes([e[4], e[5], e[6], e[7]]) as usize;
        let Some(kv) = bytes.get(at..at + key_len + value_len) else {
            return Err(format!("metadata entry {k} runs past the body"));
        };
        out.push((text_of(&kv[..key_len]), text_of(&kv[key_len..])));
        at += key_len + value_len;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The CRC is ECMA-182 (its check value over "123456789"), as the protocol's igtl_util.c.
    #[test]
    fn the_crc_is_ecma_182() {
        assert_eq!(crc64(b"123456789"), 0x6C40_DF5F_0B49_7347);
        assert_eq!(crc64(b""), 0);
    }

    /// Timestamps: seconds in the high word, the fraction converted bit by bit as the protocol's
    /// reference code does; a nanosecond survives the round trip.
    #[test]
    fn timestamps_are_32_32_fixed_point() {
        assert_eq!(timestamp(1000.5), (1000 << 32) | 0x8000_0000);
        assert_eq!(timestamp(7.0), 7 << 32);
        for t in [1_790_000_000.123_456_7, 12.999_999_999, 0.000_000_001] {
            assert!((unix_seconds(timestamp(t)) - t).abs() < 2e-9, "{t}");
        }
        // The reference conversion of 0.25 s and of 1 ns.
        assert_eq!(nanos_to_fraction(250_000_000), 0x4000_0000);
        assert_eq!(fraction_to_nanos(nanos_to_fraction(1)), 1);
    }

    /// Header version 1: the layout of the protocol's header page byte by byte.
    #[test]
    fn a_version_1_transform_is_laid_out_as_the_header_page_says() {
        let rows = [[1.0, 0.0, 0.0, 10.5], [0.0, 0.0, -1.0, -20.0], [0.0, 1.0, 0.0, 300.25]];
        let msg = encode(
            HeaderVersion::V1,
            "TRANSFORM",
            "ToolToArmBase",
            0x0102_0304_0506_0708,
            &transform_content(&rows),
            &[("TransformStatus", "OK")],
            7,
        );
        assert_eq!(msg.len(), HEADER_BYTES + TRANSFORM_BYTES, "version 1 has no metadata");
        assert_eq!(&msg[0..2], &[0, 1]);
        assert_eq!(&msg[2..14], b"TRANSFORM\0\0\0");
        assert_eq!(&msg[14..34], b"ToolToArmBase\0\0\0\0\0\0\0");
        assert_eq!(&msg[34..42], &[1, 2, 3, 4, 5, 6, 7, 8]);
        assert_eq!(u64::from_be_bytes(msg[42..50].try_into().unwrap()), 48);
        assert_eq!(u64::from_be_bytes(msg[50..58].try_into().unwrap()), crc64(&msg[58..]));
        // Column-major: R11 R21 R31 first, the translation last.
        let f = |k: usize| f32::from_be_bytes(msg[58 + 4 * k..62 + 4 * k].try_into().unwrap());
        assert_eq!([f(0), f(1), f(2)], [1.0, 0.0, 0.0]);
        assert_eq!([f(6), f(7), f(8)], [0.0, -1.0, 0.0]);
        assert_eq!([f(9), f(10), f(11)], [10.5, -20.0, 300.25]);
        let back = read_message(&mut &msg[..]).unwrap();
        assert!(back.crc_ok && back.kind == "TRANSFORM" && back.device == "ToolToArmBase");
        assert_eq!(transform_rows(&back.content), Some(rows));
    }

    /// Header version 2: extended header, content, metadata header (with its count), then keys
    /// and values; the sizes as the C++ library writes them.
    #[test]
    fn a_version_2_message_carries_its_metadata() {
        let content = status_content(status::HARDWARE_FAILURE, 4, "POSE INVALID", "joint 3 not read");
        let meta = [("TransformStatus", "INVALID"), ("Joint", "3")];
        let msg = encode(HeaderVersion::V2, "STATUS", "ToolToArmBase", 0, &content, &meta, 42);
        let body = &msg[HEADER_BYTES..];
        assert_eq!(&body[0..2], &12u16.to_be_bytes());
        assert_eq!(&body[2..4], &(2u16 + 16).to_be_bytes());
        assert_eq!(&body[4..8], &((15 + 7 + 5 + 1) as u32).to_be_bytes());
        assert_eq!(&body[8..12], &42u32.to_be_bytes());
        assert_eq!(&body[12..12 + content.len()], &content[..]);
        let meta_at = 12 + content.len();
        assert_eq!(&body[meta_at..meta_at + 2], &2u16.to_be_bytes());
        assert_eq!(&body[meta_at + 2..meta_at + 10], &[0, 15, 0, 3, 0, 0, 0, 7]);
        assert!(body.ends_with(b"TransformStatusINVALIDJoint3"));
        let back = read_message(&mut &msg[..]).unwrap();
        assert!(back.crc_ok);
        assert_eq!(back.content, content);
        assert_eq!(
            back.metadata,
            [("TransformStatus".to_string(), "INVALID".to_string()), ("Joint".into(), "3".into())]
        );
        let (code, sub, name, text) = status_fields(&back.content).unwrap();
        assert_eq!((code, sub, name.as_str(), text.as_str()), (18, 4, "POSE INVALID", "joint 3 not read"));
    }

    #[test]
    fn bad_messages_are_errors_not_panics() {
        let good = encode(HeaderVersion::V2, "GET_STATUS", "", 0, &[], &[], 0);
        let mut corrupt = good.clone();
        *corrupt.last_mut().unwrap() ^= 1;
        assert!(!read_message(&mut &corrupt[..]).unwrap().crc_ok);
        let mut huge = good.clone();
        huge[42..50].copy_from_slice(&(MAX_INCOMING_BODY + 1).to_be_bytes());
        assert!(matches!(read_message(&mut &huge[..]), Err(IgtlError::TooLarge { .. })));
        let mut lying = good.clone();
        lying[HEADER_BYTES + 4..HEADER_BYTES + 8].copy_from_slice(&1000u32.to_be_bytes());
        let crc = crc64(&lying[HEADER_BYTES..]);
        lying[50..58].copy_from_slice(&crc.to_be_bytes());
        assert!(matches!(read_message(&mut &lying[..]), Err(IgtlError::Layout { .. })));
        let mut v9 = good;
        v9[1] = 9;
        assert!(matches!(read_message(&mut &v9[..]), Err(IgtlError::Version(9))));
        assert!(matches!(read_message(&mut &[0u8; 10][..]), Err(IgtlError::Io(_))));
        assert!(
            valid_name("ToolToArmBase")
                && !valid_name("")
                && !valid_name("a b")
                && !valid_name(&"x".repeat(21))
        );
    }
}
