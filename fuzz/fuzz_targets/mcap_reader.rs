//! Bytes -> the MCAP reading path: every record walked (summary included), every message handed
//! to its topic's decoder, as `pipeline logs info` and `read_decoded` do for an MCAP file
//! (`read_mcap_file` is `read_messages` over the opened file). A second pass reads with a time
//! range, a topic filter and a small record limit, which takes the chunk-skipping paths.
//!
//! Any outcome is fine except a panic, an abort, a hang or an allocation past libFuzzer's
//! limits; the reader's own bookkeeping is checked too.

#![no_main]

use std::collections::BTreeSet;
use std::ops::ControlFlow;
use std::path::Path;

use logs::mcap_read::{Limits, McapFacts, read_messages};
use logs::{Codec, ReadOptions};
use libfuzzer_sys::fuzz_target;

fn read(data: &[u8], options: &ReadOptions) {
    let mut codecs: Vec<Option<Result<Codec, String>>> = Vec::new();
    let mut passed = 0u64;
    let mut facts = McapFacts::default();
    let result = read_messages(
        data,
        data.len() as u64,
        Path::new("fuzz.mcap"),
        options,
        &mut facts,
        |topic, m| {
            passed += 1;
            assert!(options.accepts(&topic.name, m.log_time));
            if codecs.len() <= m.topic {
                codecs.resize(m.topic + 1, None);
            }
            if let Ok(codec) = codecs[m.topic].get_or_insert_with(|| Codec::for_topic(topic)) {
                let _ = codec.decode(m.data);
            }
            ControlFlow::Continue(())
        },
    );
    if let Ok(report) = result {
        assert_eq!(report.messages, passed);
        let names: BTreeSet<&str> = report.topics.iter().map(|t| t.name.as_str()).collect();
        assert!(names.len() <= report.topics.len());
    }
}

fuzz_target!(|data: &[u8]| {
    read(
        data,
        &ReadOptions {
            read_summary: true,
            ..Default::default()
        },
    );
    read(
        data,
        &ReadOptions {
            // Inside the Husky drive's span, and small values for the generated seeds.
            start_ns: Some(3),
            end_ns: Some(1_432_235_700_000_000_000),
            topics: Some(["/fix", "/tf", "/a"].map(String::from).into()),
            limits: Limits {
                max_record_bytes: 64 * 1024,
            },
            read_summary: false,
        },
    );
});
