//! The logs reader on a malformed corpus made here from the real files (never
//! stored) gives clear errors or counted skips, never a panic or an unbounded allocation.
//!
//! Skips with a printed notice when `../shared/data` is absent.

#![allow(clippy::print_stdout, clippy::unwrap_used)]

mod common;

use std::collections::BTreeMap;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};

use logs::cdr::WireFormat;
use logs::mcap_read::{Limits, McapFacts, read_messages};
use logs::msgs::{self, NavSatFix};
use logs::{DecodeError, Log, LogError, ReadOptions, ReadReport, read_decoded};

fn logs_dir() -> Option<PathBuf> {
    common::shared_data("logs")
}

/// Reads MCAP bytes in memory, counting messages.
fn read_bytes(bytes: &[u8], limits: Limits) -> Result<(u64, ReadReport), LogError> {
    let options = ReadOptions {
        limits,
        ..Default::default()
    };
    let mut n = 0;
    let report = read_messages(
        bytes,
        bytes.len() as u64,
        Path::new("corpus.mcap"),
        &options,
        &mut McapFacts::default(),
        |_, _| {
            n += 1;
            ControlFlow::Continue(())
        },
    )?;
    Ok((n, report))
}

/// Offset where the data section ends (the DataEnd record) in a file with a summary.
fn data_end_offset(bytes: &[u8]) -> usize {
    let footer = mcap::read::footer(bytes).unwrap();
    // DataEnd is opcode 0x0f, length 4, crc 4: 13 bytes right before the summary.
    footer.summary_start as usize - 13
}

#[test]
fn truncated_mcap_at_many_offsets() {
    let Some(dir) = logs_dir() else { return };
    for name in ["husky/husky.mcap", "husky/husky_mcap/husky_mcap.mcap"] {
        let bytes = std::fs::read(dir.join(name)).unwrap();
        let data_end = data_end_offset(&bytes);
        let mut errors = 0;
        let mut cuts: Vec<usize> = (0..64).collect();
        cuts.extend((0..400).map(|i| i * bytes.len() / 400));
        cuts.extend([data_end - 1, data_end, data_end + 13, bytes.len() - 1]);
        for &cut in &cuts {
            match read_bytes(&bytes[..cut], Limits::default()) {
                Err(e) => {
                    let text = e.to_string();
                    assert!(text.starts_with("corpus.mcap: "), "{text}");
                    assert!(
                        text.contains("truncated") || text.contains("magic"),
                        "cut {cut}: {text}"
                    );
                    errors += 1;
                }
                Ok((n, _)) => {
                    // Only a cut after the data section leaves every message readable.
                    assert!(
                        cut >= data_end + 13,
                        "cut {cut} read {n} messages without error"
                    );
                    assert_eq!(n, 16_806);
                }
            }
        }
        println!("{name}: {} cuts, {errors} clear errors", cuts.len());
        assert!(errors > 400);
    }
}

#[test]
fn flipped_byte_in_a_chunk_skips_that_chunk_only() {
    let Some(dir) = logs_dir() else { return };
    for name in ["husky/husky.mcap", "husky/husky_mcap/husky_mcap.mcap"] {
        let mut bytes = std::fs::read(dir.join(name)).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        let chunk = &summary.chunk_indexes[3];
        let at = (chunk.chunk_start_offset + chunk.chunk_length / 2) as usize;
        bytes[at] ^= 0x40;
        let (n, report) = read_bytes(&bytes, Limits::default()).unwrap();
        assert_eq!(
            report.skipped_chunks.len(),
            1,
            "{name}: {:?}",
            report.skipped_chunks
        );
        assert!(n > 12_000 && n < 16_806, "{name}: {n}");
        println!("{name}: skipped chunk: {}", report.skipped_chunks[0]);
    }
}

#[test]
fn zero_and_huge_record_lengths() {
    let Some(dir) = logs_dir() else { return };
    let bytes = std::fs::read(dir.join("husky/husky.mcap")).unwrap();
    // The Header record starts right after the 8 magic bytes: opcode, then its u64 length.
    for len in [0u64, 1, u64::MAX, u64::MAX / 2, 1 << 40, bytes.len() as u64] {
        let mut b = bytes.clone();
        b[9..17].copy_from_slice(&len.to_le_bytes());
        let e = read_bytes(&b, Limits::default()).unwrap_err().to_string();
        println!("header length {len}: {e}");
        assert!(e.starts_with("corpus.mcap: "));
    }
    // A chunk whose header declares a huge uncompressed size: skipped before allocating.
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let chunk = summary.chunk_indexes[0].chunk_start_offset as usize;
    // Chunk body: start time (8), end time (8), uncompressed size (8) after opcode + length.
    let size_at = chunk + 9 + 16;
    for size in [u64::MAX, 1 << 40, 0] {
        let mut b = bytes.clone();
        b[size_at..size_at + 8].copy_from_slice(&size.to_le_bytes());
        let (_, report) = read_bytes(&b, Limits::default()).unwrap();
        assert_eq!(report.skipped_chunks.len(), 1, "size {size}");
        println!("chunk size {size}: {}", report.skipped_chunks[0]);
    }
    // A record length past the chunk's end inside an uncompressed chunk.
    let conformance = dir.join("mcap-conformance/TenMessages/TenMessages-ch-chx-mx-st-sum.mcap");
    let bytes = std::fs::read(conformance).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let ci = &summary.chunk_indexes[0];
    assert_eq!(ci.compression, "");
    // First record inside: after opcode, length, 3 × u64, crc u32, compression "" (u32), u64.
    let first = ci.chunk_start_offset as usize + 9 + 24 + 4 + 4 + 8;
    for len in [u64::MAX, 1 << 33, 0] {
        let mut b = bytes.clone();
        b[first + 1..first + 9].copy_from_slice(&len.to_le_bytes());
        let (n, report) = read_bytes(&b, Limits::default()).unwrap();
        assert_eq!(
            (n, report.skipped_chunks.len()),
            (0, 1),
            "record length {len}"
        );
        println!("record length {len}: {}", report.skipped_chunks[0]);
    }
    // A limit smaller than a record: a clear error naming the file, no allocation of the
    // record (the reader's documented behaviour: records over the limit end the read).
    let e = read_bytes(
        &std::fs::read(dir.join("husky/husky.mcap")).unwrap(),
        Limits {
            max_record_bytes: 1000,
        },
    )
    .unwrap_err()
    .to_string();
    println!("limit 1000: {e}");
    assert!(
        e.starts_with("corpus.mcap: ") && e.contains("larger than the limit"),
        "{e}"
    );
}

#[test]
fn cdr_length_fields_and_empty_payloads() {
    let Some(dir) = logs_dir() else { return };
    let log = Log::open(&dir.join("husky/husky.mcap")).unwrap();
    let mut fix_payload = None;
    log.for_each_message(&ReadOptions::default(), |t, m| {
        if t.name == "/fix" {
            fix_payload = Some(m.data.to_vec());
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    })
    .unwrap();
    let payload = fix_payload.unwrap();
    assert!(msgs::decode::<NavSatFix>(&payload, WireFormat::Cdr).is_ok());
    // frame_id's length sits after the 4-byte encapsulation and the 8-byte stamp.
    for len in [u32::MAX, 1 << 20, 0] {
        let mut p = payload.clone();
        p[12..16].copy_from_slice(&len.to_le_bytes());
        let e = msgs::decode::<NavSatFix>(&p, WireFormat::Cdr).unwrap_err();
        println!("frame_id length {len}: {e}");
        assert!(matches!(
            e,
            DecodeError::LengthTooLarge { .. }
                | DecodeError::Truncated { .. }
                | DecodeError::Invalid(_)
        ));
    }
    for cut in 0..payload.len() {
        assert!(msgs::decode::<NavSatFix>(&payload[..cut], WireFormat::Cdr).is_err());
    }
}

#[test]
fn wrong_schema_is_counted_not_fatal() {
    let Some(dir) = logs_dir() else { return };
    // The /fix payloads under a channel that claims they are Odometry.
    let source = Log::open(&dir.join("husky/husky.mcap")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("wrong_schema.mcap");
    let mut writer = mcap::Writer::new(std::io::BufWriter::new(
        std::fs::File::create(&path).unwrap(),
    ))
    .unwrap();
    let schema = writer
        .add_schema("nav_msgs/msg/Odometry", "ros2msg", b"")
        .unwrap();
    let channel = writer
        .add_channel(schema, "/fix", "cdr", &BTreeMap::new())
        .unwrap();
    let mut written = 0u32;
    source
        .for_each_message(&ReadOptions::default(), |t, m| {
            if t.name == "/fix" {
                writer
                    .write_to_known_channel(
                        &mcap::records::MessageHeader {
                            channel_id: channel,
                            sequence: written,
                            log_time: m.log_time,
                            publish_time: m.log_time,
                        },
                        m.data,
                    )
                    .unwrap();
                written += 1;
            }
            ControlFlow::Continue(())
        })
        .unwrap();
    writer.finish().unwrap();
    drop(writer);
    let decoded = read_decoded(&Log::open(&path).unwrap(), &ReadOptions::default()).unwrap();
    let undecoded = &decoded.undecoded["/fix"];
    assert_eq!(undecoded.count + decoded.messages.len() as u64, 989);
    assert!(undecoded.count > 900, "{undecoded:?}");
    println!("wrong schema: {undecoded:?}");
}

#[test]
fn db3_with_missing_tables_and_broken_rows() {
    let Some(dir) = logs_dir() else { return };
    let original = dir.join("husky/husky_db3/husky_db3.db3");
    let tmp = tempfile::tempdir().unwrap();
    for table in ["messages", "topics"] {
        let path = tmp.path().join(format!("no_{table}.db3"));
        std::fs::copy(&original, &path).unwrap();
        let conn = rusqlite::Connection::open(&path).unwrap();
        conn.execute_batch(&format!("DROP TABLE {table}")).unwrap();
        drop(conn);
        let e = Log::open(&path)
            .and_then(|log| read_decoded(&log, &ReadOptions::default()))
            .unwrap_err()
            .to_string();
        println!("{e}");
        assert!(e.contains(&format!("table `{table}` is missing")), "{e}");
    }
    // A row for an undefined topic and a NULL payload are counted, the rest is read.
    let path = tmp.path().join("bad_rows.db3");
    std::fs::copy(&original, &path).unwrap();
    let conn = rusqlite::Connection::open(&path).unwrap();
    conn.execute_batch(
        "INSERT INTO messages (topic_id, timestamp, data) VALUES (99, 1432235500000000000, x'00010000');
         UPDATE messages SET data = x'' WHERE id = 5;",
    )
    .unwrap();
    drop(conn);
    let decoded = read_decoded(&Log::open(&path).unwrap(), &ReadOptions::default()).unwrap();
    assert_eq!(decoded.report.messages_without_channel, 1);
    assert_eq!(decoded.messages.len(), 16_805);
    assert_eq!(decoded.undecoded.values().map(|u| u.count).sum::<u64>(), 1);
    // Garbage instead of a database, and a bag folder whose metadata lists a missing file.
    let garbage = tmp.path().join("garbage.db3");
    std::fs::write(&garbage, b"SQLite format 3\0 but then nothing").unwrap();
    assert!(
        Log::open(&garbage)
            .and_then(|log| read_decoded(&log, &ReadOptions::default()))
            .is_err()
    );
    let bag = tmp.path().join("bag");
    std::fs::create_dir(&bag).unwrap();
    std::fs::copy(
        dir.join("husky/husky_db3/metadata.yaml"),
        bag.join("metadata.yaml"),
    )
    .unwrap();
    let e = Log::open(&bag).unwrap_err().to_string();
    assert!(e.contains("husky_db3.db3, which is missing"), "{e}");
    std::fs::write(
        bag.join("metadata.yaml"),
        "rosbag2_bagfile_information: [1, 2",
    )
    .unwrap();
    let e = Log::open(&bag).unwrap_err().to_string();
    assert!(e.contains("metadata.yaml"), "{e}");
}

/// Regression, found by the `mcap_reader` fuzz target (fuzz/): an Attachment record whose
/// fields end less than 4 bytes before the record's end (no room for its CRC) made the `mcap`
/// crate's `parse_record` panic on a slice index. Now it is an error naming the file outside a
/// chunk, and a skipped chunk inside one. Needs no shared data.
#[test]
fn attachment_without_room_for_its_crc() {
    fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
        let mut r = vec![opcode];
        r.extend((body.len() as u64).to_le_bytes());
        r.extend(body);
        r
    }
    fn file(data_records: &[u8]) -> Vec<u8> {
        let mut f = logs::source::MCAP_MAGIC.to_vec();
        f.extend(record(0x01, &[0; 8])); // Header: profile "", library ""
        f.extend(data_records);
        f.extend(record(0x0f, &[0; 4])); // DataEnd, CRC not computed
        f.extend(record(0x02, &[0; 20])); // Footer without a summary
        f.extend(logs::source::MCAP_MAGIC);
        f
    }
    // log_time, create_time, name "", media_type "", data_len 0; then `crc_bytes` of a CRC.
    let attachment = |crc_bytes: usize| {
        let mut body = vec![0u8; 16 + 4 + 4 + 8];
        body.extend(vec![0u8; crc_bytes]);
        record(0x09, &body)
    };
    for crc_bytes in 0..4 {
        let e = read_bytes(&file(&attachment(crc_bytes)), Limits::default())
            .unwrap_err()
            .to_string();
        println!("attachment with {crc_bytes} CRC bytes: {e}");
        assert!(
            e.starts_with("corpus.mcap: ") && e.contains("too short for its fields, data and CRC"),
            "{e}"
        );
    }
    let (n, report) = read_bytes(&file(&attachment(4)), Limits::default()).unwrap();
    assert_eq!((n, report.has_skips()), (0, false));

    // The same record inside an uncompressed chunk: the chunk is skipped, the read goes on.
    let records = attachment(2);
    let mut chunk = Vec::new();
    chunk.extend(0u64.to_le_bytes()); // message_start_time
    chunk.extend(0u64.to_le_bytes()); // message_end_time
    chunk.extend((records.len() as u64).to_le_bytes()); // uncompressed_size
    chunk.extend(0u32.to_le_bytes()); // uncompressed_crc (not computed)
    chunk.extend(0u32.to_le_bytes()); // compression ""
    chunk.extend((records.len() as u64).to_le_bytes()); // compressed_size
    chunk.extend(&records);
    let (n, report) = read_bytes(&file(&record(0x06, &chunk)), Limits::default()).unwrap();
    assert_eq!((n, report.skipped_chunks.len()), (0, 1));
    assert!(
        report.skipped_chunks[0].contains("too short for its fields"),
        "{:?}",
        report.skipped_chunks
    );
}
