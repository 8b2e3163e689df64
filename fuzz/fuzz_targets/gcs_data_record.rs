//! The data recorder's `DRR?` reply (GCS array data) as the driver reads
//! it: framed by the answer decoder, then parsed. Never panics; what it
//! accepts is consistent (columns of one length, a positive sample time)
//! and survives a write-read round trip.
#![no_main]

use libfuzzer_sys::fuzz_target;
use micropos::gcs::frame::{AnswerDecoder, AnswerItem};
use micropos::gcs::recorder::{encode_records, parse_records};

fuzz_target!(|data: &[u8]| {
    let mut d = AnswerDecoder::new();
    for item in d.push(data) {
        let AnswerItem::Answer(a) = item else {
            continue;
        };
        let Ok(r) = parse_records(&a.lines()) else {
            continue;
        };
        assert!(r.sample_time_s > 0.0 && r.sample_time_s.is_finite());
        let n = r.rows();
        assert!(r.columns.iter().all(|c| c.len() == n));
        let named: Vec<(String, Vec<f64>)> = r
            .columns
            .iter()
            .enumerate()
            .map(|(i, c)| (format!("c{i}"), c.clone()))
            .collect();
        if let Ok(again) = parse_records(&encode_records(r.sample_time_s, &named)) {
            assert_eq!(again.rows(), n);
            assert_eq!(again.columns.len(), r.columns.len());
        }
    }
    // The lines alone, as a test harness would hand them over.
    let text = String::from_utf8_lossy(data);
    let lines: Vec<String> = text.lines().map(str::to_owned).collect();
    let _ = parse_records(&lines);
});
