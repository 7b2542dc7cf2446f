//! MCAP reading: the `mcap` crate's sans-io [`LinearReader`] walks the file's records from
//! any byte source while we feed it; chunks come out whole and are checked and unpacked
//! here, so that one bad chunk (bad CRC, broken compression, a record running past its end)
//! is skipped and counted instead of ending the read, and the messages of chunks outside a
//! time range are not parsed at all.
//!
//! Bounded allocation: the reader never asks for more bytes than the file still has (a length
//! beyond that is a truncated or corrupt file and an error at once), no record may exceed
//! [`Limits::max_record_bytes`], and a chunk's declared uncompressed size is checked against the
//! same limit before its buffer is allocated.

use std::borrow::Cow;
use std::collections::HashMap;
use std::fs::File;
use std::io::Read;
use std::ops::ControlFlow;
use std::path::Path;

use mcap::records::{self, ChunkHeader, Record, op};
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::error::{LogError, LogResult};
use crate::raw::{RawMessage, ReadOptions, ReadReport, Topic};

pub use crate::raw::Limits;

/// Bytes read from the source per step when the reader asks for less (one system call per
/// record would be slow; more only costs buffer memory).
const READ_BLOCK: usize = 256 * 1024;

/// What [`read_records`] hands its visitor.
#[derive(Debug)]
pub enum McapEvent<'a> {
    /// A record in file order; records inside a chunk come in place of the chunk, with
    /// `in_chunk` set. Message indexes and chunks themselves are not passed on.
    Record { record: Record<'a>, in_chunk: bool },
    /// A chunk begins (its records follow, unless it is skipped).
    Chunk { compression: &'a str },
    /// A chunk that was dropped with everything in it.
    ChunkSkipped { reason: String },
    /// A chunk whose time range lies outside the requested one: only its schemas and channels
    /// are passed on.
    ChunkOutsideRange,
}

/// How [`read_records`] walks a file.
#[derive(Debug, Clone, Default)]
pub struct RecordOptions {
    pub limits: Limits,
    /// Stop after the data section (messages need nothing from the summary).
    pub stop_at_data_end: bool,
    /// Pass on no messages of chunks whose messages all lie outside `[start, end)`
    /// (nanoseconds); their schemas and channels still are.
    pub time_range: Option<(u64, u64)>,
}

/// Walks every record of an MCAP byte stream of `total_len` bytes.
///
/// `path` only names the file in errors. Errors that end the read: not an MCAP file,
/// truncated, a record larger than the limits, a broken record outside chunks, a data-section
/// CRC mismatch when no chunk was skipped.
pub fn read_records<R: Read>(
    mut source: R,
    total_len: u64,
    path: &Path,
    options: &RecordOptions,
    mut visit: impl FnMut(McapEvent<'_>) -> ControlFlow<()>,
) -> LogResult<()> {
    let limit = options.limits.max_record_bytes;
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_emit_chunks(true)
            .with_validate_data_section_crc(true)
            .with_record_length_limit(limit),
    );
    let mut fed: u64 = 0;
    let mut chunk_buffer = Vec::new();
    let mut skipped_chunks = 0usize;
    let fail = |message: String| LogError::format(path, message);

    while let Some(event) = reader.next_event() {
        let event = match event {
            Ok(event) => event,
            Err(mcap::McapError::BadDataCrc { .. }) if skipped_chunks > 0 => {
                // Expected: the skipped chunks' bytes are what the CRC disagrees with.
                break;
            }
            Err(e) => return Err(fail(describe_mcap_error(&e, fed, total_len))),
        };
        match event {
            LinearReadEvent::ReadRequest(need) => {
                let remaining = total_len.saturating_sub(fed);
                if need as u64 > remaining {
                    return Err(fail(if remaining == 0 {
                        format!("truncated: the file ends at byte {total_len} inside a record")
                    } else {
                        format!(
                            "truncated or corrupt: a record needs {need} more bytes after byte \
                             {fed}, but the file ends at byte {total_len}"
                        )
                    }));
                }
                let want = need.max(READ_BLOCK).min(remaining as usize);
                let buf = reader.insert(want);
                let n = read_some(&mut source, buf).map_err(|e| LogError::io(path, e))?;
                if n == 0 {
                    return Err(fail(format!(
                        "truncated: the file ends at byte {fed} (expected {total_len} bytes)"
                    )));
                }
                reader.notify_read(n);
                fed += n as u64;
            }
            LinearReadEvent::Record { data, opcode } => {
                if opcode == op::CHUNK {
                    let flow = visit_chunk(data, options, &mut chunk_buffer, &mut visit);
                    match flow {
                        ChunkOutcome::Skipped => skipped_chunks += 1,
                        ChunkOutcome::Break => return Ok(()),
                        ChunkOutcome::Read => {}
                    }
                    continue;
                }
                if opcode == op::MESSAGE_INDEX {
                    continue;
                }
                let record = parse_record(opcode, data).map_err(|e| {
                    fail(format!(
                        "bad {} record before byte {fed}: {e}",
                        opcode_name(opcode)
                    ))
                })?;
                let at_data_end = opcode == op::DATA_END;
                if visit(McapEvent::Record {
                    record,
                    in_chunk: false,
                })
                .is_break()
                    || (at_data_end && options.stop_at_data_end)
                {
                    return Ok(());
                }
            }
        }
    }
    Ok(())
}

enum ChunkOutcome {
    Read,
    Skipped,
    Break,
}

/// Checks, decompresses and walks one chunk record.
fn visit_chunk(
    data: &[u8],
    options: &RecordOptions,
    buffer: &mut Vec<u8>,
    visit: &mut impl FnMut(McapEvent<'_>) -> ControlFlow<()>,
) -> ChunkOutcome {
    let skip = |visit: &mut dyn FnMut(McapEvent<'_>) -> ControlFlow<()>, reason: String| {
        if visit(McapEvent::ChunkSkipped { reason }).is_break() {
            ChunkOutcome::Break
        } else {
            ChunkOutcome::Skipped
        }
    };
    let (header, compressed) = match mcap::parse_record(op::CHUNK, data) {
        Ok(Record::Chunk { header, data }) => (header, data),
        Ok(_) => return skip(visit, "chunk record did not parse as a chunk".into()),
        Err(e) => return skip(visit, format!("bad chunk header: {e}")),
    };
    if visit(McapEvent::Chunk {
        compression: &header.compression,
    })
    .is_break()
    {
        return ChunkOutcome::Break;
    }
    // A chunk outside the time range is still unpacked for the schemas and channels it may
    // define (later messages can refer to them), but its messages are not parsed.
    let outside_range = options.time_range.is_some_and(|(start, end)| {
        header.message_end_time < start || header.message_start_time >= end
    });
    if outside_range && visit(McapEvent::ChunkOutsideRange).is_break() {
        return ChunkOutcome::Break;
    }
    let records = match unpack_chunk(&header, &compressed, options.limits, buffer) {
        Ok(records) => records,
        Err(reason) => return skip(visit, reason),
    };
    // Parse everything first: a chunk is dropped whole or read whole, never half.
    let mut parsed = Vec::new();
    if let Err(reason) = split_records(records, |opcode, body| {
        if opcode == op::MESSAGE_INDEX
            || (outside_range && opcode != op::SCHEMA && opcode != op::CHANNEL)
        {
            return Ok(());
        }
        let record = parse_record(opcode, body)
            .map_err(|e| format!("bad {} record inside the chunk: {e}", opcode_name(opcode)))?;
        parsed.push(record);
        Ok(())
    }) {
        return skip(visit, reason);
    }
    for record in parsed {
        if visit(McapEvent::Record {
            record,
            in_chunk: true,
        })
        .is_break()
        {
            return ChunkOutcome::Break;
        }
    }
    ChunkOutcome::Read
}

/// The chunk's records, decompressed into `buffer` if needed, with the CRC checked.
fn unpack_chunk<'a>(
    header: &ChunkHeader,
    compressed: &'a [u8],
    limits: Limits,
    buffer: &'a mut Vec<u8>,
) -> Result<&'a [u8], String> {
    let size = usize::try_from(header.uncompressed_size)
        .ok()
        .filter(|&s| s <= limits.max_record_bytes)
        .ok_or_else(|| {
            format!(
                "chunk declares {} uncompressed bytes, more than the limit of {}",
                header.uncompressed_size, limits.max_record_bytes
            )
        })?;
    let records: &[u8] = match header.compression.as_str() {
        "" => compressed,
        "zstd" => {
            buffer.clear();
            buffer.reserve(size);
            zstd::bulk::Decompressor::new()
                .and_then(|mut d| d.decompress_to_buffer(compressed, buffer))
                .map_err(|e| format!("zstd chunk does not decompress: {e}"))?;
            buffer
        }
        "lz4" => {
            buffer.clear();
            buffer.reserve(size);
            let decoder = lz4::Decoder::new(compressed)
                .map_err(|e| format!("lz4 chunk does not decompress: {e}"))?;
            // One byte more than declared, to notice a chunk that holds more.
            decoder
                .take(size as u64 + 1)
                .read_to_end(buffer)
                .map_err(|e| format!("lz4 chunk does not decompress: {e}"))?;
            buffer
        }
        other => return Err(format!("unsupported chunk compression `{other}`")),
    };
    if records.len() != size {
        return Err(format!(
            "chunk holds {} bytes, its header says {size}",
            records.len()
        ));
    }
    if header.uncompressed_crc != 0 {
        let crc = crc32fast::hash(records);
        if crc != header.uncompressed_crc {
            return Err(format!(
                "chunk CRC mismatch (stored {:#010x}, computed {crc:#010x})",
                header.uncompressed_crc
            ));
        }
    }
    Ok(records)
}

/// [`mcap::parse_record`], with the record layouts it would panic on turned into errors.
///
/// mcap 0.26 slices an Attachment body as if its trailing 4-byte CRC were always there
/// (`body[header_len..body.len() - 4]`), so an Attachment whose fields end less than 4 bytes
/// before the record's end panics there (found by the `mcap_reader` fuzz target).
pub fn parse_record(opcode: u8, body: &[u8]) -> Result<Record<'_>, String> {
    if opcode == op::ATTACHMENT {
        check_attachment_layout(body)?;
    }
    mcap::parse_record(opcode, body).map_err(|e| e.to_string())
}

/// An Attachment body must hold log_time, create_time, name, media_type, data_len, the data
/// and a CRC, in that order (bytes after the CRC are padding).
fn check_attachment_layout(body: &[u8]) -> Result<(), String> {
    fn take<'a>(rest: &mut &'a [u8], n: usize) -> Option<&'a [u8]> {
        let (head, tail) = rest.split_at_checked(n)?;
        *rest = tail;
        Some(head)
    }
    fn u32_le(rest: &mut &[u8]) -> Option<u32> {
        let (bytes, tail) = rest.split_first_chunk::<4>()?;
        *rest = tail;
        Some(u32::from_le_bytes(*bytes))
    }
    fn u64_le(rest: &mut &[u8]) -> Option<u64> {
        let (bytes, tail) = rest.split_first_chunk::<8>()?;
        *rest = tail;
        Some(u64::from_le_bytes(*bytes))
    }
    let mut rest = body;
    let fits = (|| {
        take(&mut rest, 16)?; // log_time, create_time
        for _ in 0..2 {
            // name, media_type
            let len = u32_le(&mut rest)?;
            take(&mut rest, usize::try_from(len).ok()?)?;
        }
        let data_len = u64_le(&mut rest)?;
        take(&mut rest, usize::try_from(data_len).ok()?)?;
        u32_le(&mut rest) // crc
    })();
    fits.map(|_| ()).ok_or_else(|| {
        format!(
            "attachment record of {} bytes is too short for its fields, data and CRC",
            body.len()
        )
    })
}

/// Splits a run of `opcode, u64 length, body` records.
fn split_records<'a>(
    mut bytes: &'a [u8],
    mut each: impl FnMut(u8, &'a [u8]) -> Result<(), String>,
) -> Result<(), String> {
    while !bytes.is_empty() {
        let Some((&opcode, rest)) = bytes.split_first() else {
            break;
        };
        let Some((len, rest)) = rest.split_first_chunk::<8>() else {
            return Err("record header runs past the end of the chunk".into());
        };
        let len = u64::from_le_bytes(*len);
        if len > rest.len() as u64 {
            return Err(format!(
                "{} record of {len} bytes runs past the end of the chunk ({} bytes left)",
                opcode_name(opcode),
                rest.len()
            ));
        }
        let (body, rest) = rest.split_at(len as usize);
        each(opcode, body)?;
        bytes = rest;
    }
    Ok(())
}

fn read_some<R: Read>(source: &mut R, buf: &mut [u8]) -> std::io::Result<usize> {
    loop {
        match source.read(buf) {
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            other => return other,
        }
    }
}

fn describe_mcap_error(e: &mcap::McapError, fed: u64, total_len: u64) -> String {
    match e {
        mcap::McapError::BadMagic => "not an MCAP file (bad magic bytes)".into(),
        mcap::McapError::UnexpectedEof => {
            format!("truncated: the file ends at byte {total_len} inside a record")
        }
        mcap::McapError::RecordTooLarge { opcode, len } => format!(
            "{} record of {len} bytes before byte {fed} is larger than the limit",
            opcode_name(*opcode)
        ),
        other => format!("{other} (before byte {fed})"),
    }
}

/// The MCAP name of a record opcode.
pub fn opcode_name(opcode: u8) -> &'static str {
    match opcode {
        op::HEADER => "Header",
        op::FOOTER => "Footer",
        op::SCHEMA => "Schema",
        op::CHANNEL => "Channel",
        op::MESSAGE => "Message",
        op::CHUNK => "Chunk",
        op::MESSAGE_INDEX => "MessageIndex",
        op::CHUNK_INDEX => "ChunkIndex",
        op::ATTACHMENT => "Attachment",
        op::ATTACHMENT_INDEX => "AttachmentIndex",
        op::STATISTICS => "Statistics",
        op::METADATA => "Metadata",
        op::METADATA_INDEX => "MetadataIndex",
        op::SUMMARY_OFFSET => "SummaryOffset",
        op::DATA_END => "DataEnd",
        _ => "unknown",
    }
}

/// What the records of one MCAP file said about it, besides its messages.
#[derive(Debug, Clone, Default)]
pub struct McapFacts {
    pub profile: String,
    pub library: String,
    /// Compression of each chunk seen (`""` = none), with counts.
    pub chunk_compressions: std::collections::BTreeMap<String, u64>,
    pub chunks_outside_range: u64,
    pub attachments: u64,
    /// Names of Metadata records.
    pub metadata: Vec<String>,
    pub statistics: Option<records::Statistics>,
    pub has_summary: bool,
}

/// Turns MCAP records into topics and messages.
#[derive(Debug, Default)]
struct Channels {
    schemas: HashMap<u16, (String, String, Vec<u8>)>,
    channel_topics: HashMap<u16, usize>,
    topics: Vec<Topic>,
}

impl Channels {
    fn add_channel(&mut self, channel: &records::Channel, report: &mut ReadReport) {
        if self.channel_topics.contains_key(&channel.id) {
            return; // repeated (chunks, summary): the first one stands
        }
        let (type_name, schema_encoding, schema) = if channel.schema_id == 0 {
            (String::new(), String::new(), Vec::new())
        } else {
            match self.schemas.get(&channel.schema_id) {
                Some(s) => s.clone(),
                None => {
                    report.warnings.push(format!(
                        "channel {} (`{}`) names schema {}, which does not precede it",
                        channel.id, channel.topic, channel.schema_id
                    ));
                    (String::new(), String::new(), Vec::new())
                }
            }
        };
        self.channel_topics.insert(channel.id, self.topics.len());
        self.topics.push(Topic {
            name: channel.topic.clone(),
            type_name,
            encoding: channel.message_encoding.clone(),
            schema_encoding,
            schema,
            channel_id: Some(channel.id),
        });
    }
}

/// Reads the messages of an MCAP byte stream in file order, calling `each` for those that
/// pass `options` (time range, topics).
pub fn read_messages<R: Read>(
    source: R,
    total_len: u64,
    path: &Path,
    options: &ReadOptions,
    facts: &mut McapFacts,
    mut each: impl FnMut(&Topic, RawMessage<'_>) -> ControlFlow<()>,
) -> LogResult<ReadReport> {
    let mut report = ReadReport::default();
    let mut channels = Channels::default();
    let record_options = RecordOptions {
        limits: options.limits,
        stop_at_data_end: !options.read_summary,
        time_range: options.time_range(),
    };
    read_records(source, total_len, path, &record_options, |event| {
        let record = match event {
            McapEvent::Record { record, .. } => record,
            McapEvent::ChunkSkipped { reason } => {
                report.skipped_chunks.push(reason);
                return ControlFlow::Continue(());
            }
            McapEvent::Chunk { compression } => {
                *facts
                    .chunk_compressions
                    .entry(compression.to_owned())
                    .or_default() += 1;
                return ControlFlow::Continue(());
            }
            McapEvent::ChunkOutsideRange => {
                facts.chunks_outside_range += 1;
                return ControlFlow::Continue(());
            }
        };
        match record {
            Record::Header(h) => {
                facts.profile = h.profile;
                facts.library = h.library;
            }
            Record::Schema { header, data } if header.id != 0 => {
                channels
                    .schemas
                    .entry(header.id)
                    .or_insert_with(|| (header.name, header.encoding, Cow::into_owned(data)));
            }
            Record::Channel(c) => channels.add_channel(&c, &mut report),
            Record::Message { header, data } => {
                let Some(&index) = channels.channel_topics.get(&header.channel_id) else {
                    report.messages_without_channel += 1;
                    return ControlFlow::Continue(());
                };
                let topic = &channels.topics[index];
                if !options.accepts(&topic.name, header.log_time) {
                    return ControlFlow::Continue(());
                }
                report.messages += 1;
                return each(
                    topic,
                    RawMessage {
                        topic: index,
                        log_time: header.log_time,
                        publish_time: header.publish_time,
                        sequence: header.sequence,
                        data: &data,
                    },
                );
            }
            Record::Attachment { .. } => facts.attachments += 1,
            Record::Metadata(m) => facts.metadata.push(m.name),
            Record::Statistics(s) => facts.statistics = Some(s),
            Record::Footer(f) => facts.has_summary = f.summary_start != 0,
            _ => {}
        }
        ControlFlow::Continue(())
    })?;
    report.topics = channels.topics;
    Ok(report)
}

/// Reads one MCAP file from disk.
pub fn read_mcap_file(
    path: &Path,
    options: &ReadOptions,
    facts: &mut McapFacts,
    each: impl FnMut(&Topic, RawMessage<'_>) -> ControlFlow<()>,
) -> LogResult<ReadReport> {
    let file = File::open(path).map_err(|e| LogError::io(path, e))?;
    let len = file.metadata().map_err(|e| LogError::io(path, e))?.len();
    read_messages(file, len, path, options, facts, each)
}
