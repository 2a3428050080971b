//! A check of an MCAP file's record framing before the `mcap` crate reads it.
//!
//! Every MCAP record is an opcode byte, a little-endian `u64` length and that many bytes; a
//! chunk holds more records the same way. The `mcap` crate's reader (0.26) trusts the lengths:
//! one past the end of the file overflows `9 + len`, and a record that runs past the end of an
//! uncompressed chunk underflows the chunk's remaining length (debug builds panic there,
//! release builds wrap), and a string's `u32` length is allocated before its bytes are read
//! (4 GiB for a forged one). All three were found by the `recording` fuzz target. Reading
//! stops instead at the first record whose lengths do not fit, as for a file cut short.
//! Compressed chunks are never decompressed: the workspace builds `mcap` without its
//! decompressors (TES writes uncompressed chunks), so their contents are never parsed.
//!
//! The same walk checks the checksums the writer stores: each uncompressed chunk's CRC of its
//! records, before any of them is read, and the data section's CRC in the data end record. A
//! mismatch is corruption, not a cut ([`Break::corrupt`]), and so is a break in a file that
//! ends with the closing magic bytes, as only a complete file does.

/// MCAP opcodes this check looks into.
const CHUNK: u8 = 0x06;
const FOOTER: u8 = 0x02;
const DATA_END: u8 = 0x0F;
/// Where an uncompressed chunk's CRC is in its body: after the start and end times and the
/// uncompressed size.
const CHUNK_CRC_AT: usize = 8 + 8 + 8;
/// Opcode byte plus the length.
const RECORD_HEADER: usize = 9;

/// Where a file's framing first breaks: reading must stop at byte `offset`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Break {
    /// The start of the first record that does not fit.
    pub offset: usize,
    /// What is wrong with it.
    pub why: String,
    /// Whether the file was damaged (a checksum that does not match, or a break in a file
    /// that ends as a complete one does) rather than cut short.
    pub corrupt: bool,
}

/// Checks the framing of `bytes`, an MCAP file whose 8 magic bytes have been checked:
/// `Ok(())` if every top-level record, and every record inside an uncompressed chunk, fits
/// in what holds it; else where the first that does not fit starts. A file that ends within
/// a record header is left to the reader (it reports the truncation itself).
pub(crate) fn check(bytes: &[u8]) -> Result<(), Break> {
    let complete = bytes.len() >= 2 * mcap::MAGIC.len() && bytes.ends_with(mcap::MAGIC);
    match walk(bytes) {
        Ok(Walked::ToTheEnd { last }) if complete => Err(Break::corrupt(
            last,
            "the records do not lead to the footer, though the file ends with the closing \
             magic bytes as a complete file does"
                .into(),
        )),
        Ok(_) => Ok(()),
        Err(mut broken) => {
            if complete && !broken.corrupt {
                broken.corrupt = true;
                broken.why.push_str(
                    " (the file ends with the closing magic bytes, as a complete file does: it \
                     was damaged, not cut short)",
                );
            }
            Err(broken)
        }
    }
}

/// How far a sound walk went.
enum Walked {
    /// To the footer (and the closing magic, or part of it).
    ToTheFooter,
    /// To the end of the bytes without a footer; `last` is where the last record began.
    ToTheEnd { last: usize },
}

/// The walk of [`check`], every break a cut unless a checksum says otherwise.
fn walk(bytes: &[u8]) -> Result<Walked, Break> {
    let mut at = mcap::MAGIC.len();
    let mut last = at;
    let mut data_end_seen = false;
    while bytes.len() - at >= RECORD_HEADER {
        last = at;
        let (opcode, len) = header(&bytes[at..]);
        let body_start = at + RECORD_HEADER;
        let fits = usize::try_from(len)
            .ok()
            .filter(|&len| len <= bytes.len() - body_start);
        let Some(len) = fits else {
            return Err(Break::cut(
                at,
                format!(
                    "the record at byte {at} (opcode 0x{opcode:02x}) claims {len} bytes, {} are left",
                    bytes.len() - body_start
                ),
            ));
        };
        let body = &bytes[body_start..body_start + len];
        check_layout(at, opcode, body).map_err(|why| Break::cut(at, why))?;
        check_sums(bytes, at, opcode, body, data_end_seen)
            .map_err(|why| Break::corrupt(at, why))?;
        data_end_seen |= opcode == DATA_END;
        if opcode == FOOTER {
            // Only the closing magic follows; a file cut within it is left to the reader.
            let rest = &bytes[body_start + len..];
            if !mcap::MAGIC.starts_with(rest) {
                return Err(Break::corrupt(
                    at,
                    "the closing magic bytes after the footer are damaged".into(),
                ));
            }
            return Ok(Walked::ToTheFooter);
        }
        at = body_start + len;
    }
    Ok(Walked::ToTheEnd { last })
}

impl Break {
    fn cut(offset: usize, why: String) -> Self {
        Self {
            offset,
            why,
            corrupt: false,
        }
    }

    fn corrupt(offset: usize, why: String) -> Self {
        Self {
            offset,
            why,
            corrupt: true,
        }
    }
}

/// The lengths within a record at byte `at`: a chunk's records, a record's strings.
fn check_layout(at: usize, opcode: u8, body: &[u8]) -> Result<(), String> {
    if opcode == CHUNK {
        check_chunk(body).map_err(|why| format!("the chunk at byte {at}: {why}"))
    } else {
        check_strings(opcode, body)
            .map_err(|why| format!("the record at byte {at} (opcode 0x{opcode:02x}): {why}"))
    }
}

/// The checksums a record at byte `at` of `bytes` carries: a chunk's of its records, the
/// data end's of the data section, the footer's of the summary (and a footer must follow a
/// data end, whose checksum would otherwise go unchecked).
fn check_sums(
    bytes: &[u8],
    at: usize,
    opcode: u8,
    body: &[u8],
    data_end_seen: bool,
) -> Result<(), String> {
    let mismatch = match opcode {
        CHUNK => chunk_crc(body).map(|m| ("the chunk", m)),
        DATA_END => data_crc(body, &bytes[..at]).map(|m| ("the data section", m)),
        FOOTER if !data_end_seen => {
            return Err(format!(
                "the footer at byte {at} follows no data end record"
            ));
        }
        FOOTER => summary_crc(body, bytes, at).map(|m| ("the summary", m)),
        _ => None,
    };
    match mismatch {
        Some((what, (stored, computed))) => Err(format!(
            "{what} at byte {at} is corrupt: CRC-32 {stored:08x} stored, {computed:08x} computed"
        )),
        None => Ok(()),
    }
}

/// A footer at byte `at` whose CRC-32 of the summary (from its start through the footer's
/// `summary_offset_start`) is not the one stored: `(stored, computed)`; 0 stored, or no
/// summary, means none.
fn summary_crc(body: &[u8], bytes: &[u8], at: usize) -> Option<(u32, u32)> {
    let fields = body.get(..20)?;
    let start = usize::try_from(le_u64(fields)).ok()?;
    let stored = le_u32(&fields[16..]);
    let end = at + RECORD_HEADER + 16;
    if stored == 0 || start == 0 || start > at {
        return None;
    }
    let computed = crc32fast::hash(&bytes[start..end]);
    (computed != stored).then_some((stored, computed))
}

/// An uncompressed chunk whose records' CRC-32 is not the one stored: `(stored, computed)`.
/// A stored 0 means none was computed; a compressed chunk is left alone (its CRC is of the
/// records decompressed, which are never read). Called on a body [`check_chunk`] passed.
fn chunk_crc(body: &[u8]) -> Option<(u32, u32)> {
    let stored = le_u32(&body[CHUNK_CRC_AT..]);
    let name_len = le_u32(&body[CHUNK_CRC_AT + 4..]) as usize;
    let records_at = CHUNK_CRC_AT + 4 + 4 + name_len + 8;
    if stored == 0 || name_len != 0 {
        return None;
    }
    let records_len = le_u64(&body[records_at - 8..]) as usize;
    let computed = crc32fast::hash(&body[records_at..records_at + records_len]);
    (computed != stored).then_some((stored, computed))
}

/// A data end record whose CRC-32 of the data section (every byte before the record, the
/// magic included) is not the one stored: `(stored, computed)`; 0 stored means none.
fn data_crc(body: &[u8], data_section: &[u8]) -> Option<(u32, u32)> {
    let stored = le_u32(body.get(..4)?);
    let computed = crc32fast::hash(data_section);
    (stored != 0 && computed != stored).then_some((stored, computed))
}

fn header(bytes: &[u8]) -> (u8, u64) {
    let mut len = [0; 8];
    len.copy_from_slice(&bytes[1..RECORD_HEADER]);
    (bytes[0], u64::from_le_bytes(len))
}

/// A chunk's body: start and end times, uncompressed size and CRC, the compression's name,
/// the records' length, the records. An uncompressed chunk's records must tile it exactly.
fn check_chunk(body: &[u8]) -> Result<(), String> {
    let mut at = 8 + 8 + 8 + 4;
    let take = |at: &mut usize, n: usize| -> Result<usize, String> {
        let start = *at;
        *at = at
            .checked_add(n)
            .filter(|&end| end <= body.len())
            .ok_or_else(|| "its header runs past its end".to_owned())?;
        Ok(start)
    };
    let name_len = take(&mut at, 4).map(|s| le_u32(&body[s..]))?;
    let name_len = usize::try_from(name_len).map_err(|_| "its compression name is too long")?;
    let compressed = !body[take(&mut at, name_len)?..at].is_empty();
    let records_len = take(&mut at, 8).map(|s| le_u64(&body[s..]))?;
    let records_len = usize::try_from(records_len)
        .ok()
        .filter(|&n| n <= body.len() - at)
        .ok_or_else(|| {
            format!(
                "its records claim {records_len} bytes, {} are left",
                body.len() - at
            )
        })?;
    if compressed {
        // The decompressed records are the decompressor's to check.
        return Ok(());
    }
    let records = &body[at..at + records_len];
    let mut r = 0;
    while r < records.len() {
        if records.len() - r < RECORD_HEADER {
            return Err(format!(
                "a record header at byte {r} of its records is cut off"
            ));
        }
        let (opcode, len) = header(&records[r..]);
        let left = records.len() - r - RECORD_HEADER;
        match usize::try_from(len).ok().filter(|&len| len <= left) {
            Some(len) => {
                let body = &records[r + RECORD_HEADER..r + RECORD_HEADER + len];
                check_strings(opcode, body).map_err(|why| {
                    format!("the record at byte {r} of its records (opcode 0x{opcode:02x}): {why}")
                })?;
                r += RECORD_HEADER + len;
            }
            None => {
                return Err(format!(
                    "the record at byte {r} of its records (opcode 0x{opcode:02x}) claims {len} bytes, {left} are left"
                ));
            }
        }
    }
    Ok(())
}

/// The fields of a record before (and around) its strings, as the MCAP spec lays them out.
#[derive(Clone, Copy)]
enum Field {
    /// Fixed-size bytes.
    Skip(usize),
    /// A `u32` length and that many bytes of UTF-8.
    Str,
    /// A `u32` length in bytes, then string pairs until that many are consumed.
    StrMap,
    /// A `u32` length in bytes, then fixed-size entries of this size until consumed.
    FixedMap(usize),
}

/// The fields up to each record's last string, by opcode; records without strings are `&[]`.
fn layout(opcode: u8) -> &'static [Field] {
    use Field::*;
    match opcode {
        0x01 => &[Str, Str],                             // header: profile, library
        0x03 => &[Skip(2), Str, Str],                    // schema: id, name, encoding
        0x04 => &[Skip(4), Str, Str, StrMap],            // channel: ids, topic, encoding, metadata
        0x08 => &[Skip(32), FixedMap(10), Skip(8), Str], // chunk index: .., compression
        0x09 => &[Skip(16), Str, Str],                   // attachment: times, name, media type
        0x0A => &[Skip(40), Str, Str],                   // attachment index
        0x0C => &[Str, StrMap],                          // metadata: name, map
        0x0D => &[Skip(16), Str],                        // metadata index: offset, length, name
        _ => &[],
    }
}

/// Every string of a record of `opcode` fits in what is left of its `body` (the `mcap` crate
/// allocates a string's claimed length before reading it). A record too short for its fixed
/// fields is left to the crate, which refuses it.
fn check_strings(opcode: u8, body: &[u8]) -> Result<(), String> {
    let mut at = 0usize;
    let string = |at: &mut usize| -> Result<bool, String> {
        let Some(prefix) = body.get(*at..*at + 4) else {
            return Ok(false);
        };
        let len = le_u32(prefix);
        let left = body.len() - *at - 4;
        if usize::try_from(len).map_or(true, |len| len > left) {
            return Err(format!(
                "a string at byte {at} claims {len} bytes, {left} are left"
            ));
        }
        *at += 4 + len as usize;
        Ok(true)
    };
    for field in layout(opcode) {
        match *field {
            Field::Skip(n) => at += n,
            Field::Str => {
                if !string(&mut at)? {
                    return Ok(());
                }
            }
            Field::StrMap | Field::FixedMap(_) => {
                let Some(prefix) = body.get(at..at + 4) else {
                    return Ok(());
                };
                let map_len = le_u32(prefix) as usize;
                at += 4;
                let start = at;
                while at - start < map_len && at < body.len() {
                    if let Field::FixedMap(entry) = *field {
                        at += entry;
                    } else if !(string(&mut at)? && string(&mut at)?) {
                        return Ok(());
                    }
                }
            }
        }
        if at > body.len() {
            return Ok(());
        }
    }
    Ok(())
}

fn le_u32(b: &[u8]) -> u32 {
    u32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

fn le_u64(b: &[u8]) -> u64 {
    let mut v = [0; 8];
    v.copy_from_slice(&b[..8]);
    u64::from_le_bytes(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
        let mut r = vec![opcode];
        r.extend_from_slice(&(body.len() as u64).to_le_bytes());
        r.extend_from_slice(body);
        r
    }

    fn chunk(compression: &str, records: &[u8], claimed: u64) -> Vec<u8> {
        let mut body = vec![0; 28];
        body.extend_from_slice(&(compression.len() as u32).to_le_bytes());
        body.extend_from_slice(compression.as_bytes());
        body.extend_from_slice(&claimed.to_le_bytes());
        body.extend_from_slice(records);
        record(CHUNK, &body)
    }

    fn file(records: &[Vec<u8>]) -> Vec<u8> {
        let mut f = mcap::MAGIC.to_vec();
        for r in records {
            f.extend_from_slice(r);
        }
        f
    }

    #[test]
    fn sound_records_and_chunks_pass() {
        let inner = [record(0x05, b"message"), record(0x04, b"")].concat();
        let f = file(&[
            header_record(),
            chunk("", &inner, inner.len() as u64),
            chunk("zstd", b"opaque", 6),
            record(DATA_END, &[0; 4]),
            record(FOOTER, &[0; 20]),
        ]);
        assert_eq!(check(&f), Ok(()));
        // Cut within a record header: the reader's own truncation.
        assert_eq!(check(&f[..f.len() - 25]), Ok(()));
    }

    fn header_record() -> Vec<u8> {
        record(0x01, &[string("profile"), string("library")].concat())
    }

    fn string(s: &str) -> Vec<u8> {
        [
            (s.len() as u32).to_le_bytes().to_vec(),
            s.as_bytes().to_vec(),
        ]
        .concat()
    }

    #[test]
    fn records_with_sound_strings_pass_and_a_forged_string_length_breaks_the_file() {
        let map = [string("k"), string("v")].concat();
        let channel = [
            vec![1, 0, 1, 0],
            string("/tes/command"),
            string("json"),
            (map.len() as u32).to_le_bytes().to_vec(),
            map,
        ]
        .concat();
        let metadata = [string("tes.run"), 0u32.to_le_bytes().to_vec()].concat();
        let sound = file(&[
            record(0x01, &[string("profile"), string("library")].concat()),
            record(0x04, &channel),
            chunk("", &record(0x0C, &metadata), (9 + metadata.len()) as u64),
        ]);
        assert_eq!(check(&sound), Ok(()));

        // The fuzzer's header: a profile claiming u32::MAX bytes (a 4 GiB allocation).
        let forged = [0xff, 0xff, 0xff, 0xff, b'x'].to_vec();
        let f = file(&[record(0x01, &forged)]);
        let broken = check(&f).unwrap_err();
        assert_eq!(broken.offset, 8);
        assert!(
            broken.why.contains("claims 4294967295 bytes, 1 are left"),
            "{broken:?}"
        );
        // The same inside an uncompressed chunk, and a map's value.
        let inner = record(0x0C, &forged);
        let f = file(&[chunk("", &inner, inner.len() as u64)]);
        assert!(check(&f).is_err());
        let mut bad_map = channel.clone();
        let n = bad_map.len();
        bad_map[n - 5] = 0xff; // the value's length
        let f = file(&[record(0x04, &bad_map)]);
        assert!(
            check(&f).unwrap_err().why.contains("a string at byte"),
            "{:?}",
            check(&f)
        );
    }

    #[test]
    fn a_length_past_the_end_breaks_the_file_there() {
        // The fuzzer's input: an opcode and a length of u64::MAX right after the magic.
        let mut f = file(&[header_record()]);
        let at = f.len();
        f.push(0x89);
        f.extend_from_slice(&u64::MAX.to_le_bytes());
        let broken = check(&f).unwrap_err();
        assert_eq!(broken.offset, at);
        assert!(
            broken.why.contains("claims 18446744073709551615 bytes"),
            "{broken:?}"
        );
    }

    #[test]
    fn a_record_overrunning_its_uncompressed_chunk_breaks_the_file_at_the_chunk() {
        let mut inner = record(0x05, b"message");
        inner[1] = 200; // claims 200 bytes inside a chunk that has 7
        let f = file(&[header_record(), chunk("", &inner, inner.len() as u64)]);
        let broken = check(&f).unwrap_err();
        assert_eq!(broken.offset, 8 + 31);
        assert!(
            broken
                .why
                .starts_with("the chunk at byte 39: the record at byte 0"),
            "{broken:?}"
        );
        // A chunk whose records claim more than it holds.
        let f = file(&[chunk("", b"", 1000)]);
        assert!(
            check(&f)
                .unwrap_err()
                .why
                .contains("its records claim 1000 bytes")
        );
        // A chunk too short for its own header.
        let f = file(&[record(CHUNK, &[0; 10])]);
        assert!(
            check(&f)
                .unwrap_err()
                .why
                .contains("its header runs past its end")
        );
    }
}
