//! `train --tensorboard`: each iteration's scalars as TensorBoard events beside the stage's
//! `progress.csv`, with the CSV's names as tags and the iteration as step (as the Python
//! learner's `--tensorboard`).
//!
//! An event file is a sequence of records: the payload's length (u64 LE), the length's masked
//! CRC-32C, the payload, the payload's masked CRC-32C; each payload an `Event` protobuf (the
//! subset declared here, field numbers from TensorFlow's event.proto and summary.proto).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use prost::Message;

use crate::Result;

/// event.proto `Event` (the fields written).
#[derive(Clone, PartialEq, Message)]
pub struct Event {
    /// Seconds since the epoch.
    #[prost(double, tag = "1")]
    pub wall_time: f64,
    /// The iteration.
    #[prost(int64, tag = "2")]
    pub step: i64,
    /// The first event of a file: "brain.Event:2".
    #[prost(string, optional, tag = "3")]
    pub file_version: Option<String>,
    /// Scalars.
    #[prost(message, optional, tag = "5")]
    pub summary: Option<Summary>,
}

/// summary.proto `Summary`.
#[derive(Clone, PartialEq, Message)]
pub struct Summary {
    /// One per scalar.
    #[prost(message, repeated, tag = "1")]
    pub value: Vec<SummaryValue>,
}

/// summary.proto `Summary.Value`, a simple scalar.
#[derive(Clone, PartialEq, Message)]
pub struct SummaryValue {
    /// The scalar's name.
    #[prost(string, tag = "1")]
    pub tag: String,
    /// Its value. In summary.proto a member of the `value` oneof, so it is written even when
    /// 0 (a proto3 plain float of 0 is left out, and TensorBoard then drops the tag).
    #[prost(float, optional, tag = "2")]
    pub simple_value: Option<f32>,
}

/// TFRecord's masked CRC-32C.
pub fn masked_crc(bytes: &[u8]) -> u32 {
    let crc = crc32c::crc32c(bytes);
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// One TFRecord.
pub fn record(payload: &[u8]) -> Vec<u8> {
    let len = (payload.len() as u64).to_le_bytes();
    let mut out = Vec::with_capacity(payload.len() + 16);
    out.extend_from_slice(&len);
    out.extend_from_slice(&masked_crc(&len).to_le_bytes());
    out.extend_from_slice(payload);
    out.extend_from_slice(&masked_crc(payload).to_le_bytes());
    out
}

fn now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// An event file of one stage.
pub struct EventWriter {
    path: PathBuf,
    file: BufWriter<File>,
}

impl EventWriter {
    /// A new file in `dir` (a resumed stage writes another beside the first: TensorBoard reads
    /// every file of a folder).
    pub fn create(dir: &Path) -> Result<Self> {
        let start = now();
        let name = format!(
            "events.out.tfevents.{}.unigait-learner.{}",
            start as u64,
            std::process::id()
        );
        let path = dir.join(name);
        let mut w = Self {
            file: BufWriter::new(File::create(&path)?),
            path,
        };
        let first = Event {
            wall_time: start,
            file_version: Some("brain.Event:2".into()),
            ..Default::default()
        };
        w.file.write_all(&record(&first.encode_to_vec()))?;
        w.file.flush()?;
        Ok(w)
    }

    /// Where the events go.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// One iteration's scalars (NaN ones too: TensorBoard draws a gap).
    pub fn log(&mut self, step: u64, scalars: &[(String, f64)]) -> Result<()> {
        let event = Event {
            wall_time: now(),
            step: step as i64,
            file_version: None,
            summary: Some(Summary {
                value: scalars
                    .iter()
                    .map(|(tag, v)| SummaryValue {
                        tag: tag.clone(),
                        simple_value: Some(*v as f32),
                    })
                    .collect(),
            }),
        };
        self.file.write_all(&record(&event.encode_to_vec()))?;
        self.file.flush()?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_and_its_mask_match_the_reference_values() {
        // CRC-32C's check value, and TFRecord's mask of it: rotated right by 15 bits plus
        // 0xa282ead8 (worked out by hand).
        assert_eq!(crc32c::crc32c(b"123456789"), 0xe306_9283);
        assert_eq!(masked_crc(b"123456789"), 0xc78a_b0e5);
    }

    #[test]
    fn records_read_back_with_their_checksums() {
        let dir = std::env::temp_dir().join(format!("unigait-tb-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut w = EventWriter::create(&dir).unwrap();
        w.log(7, &[("kl".into(), 0.25), ("biped_share".into(), 0.0)])
            .unwrap();
        let bytes = std::fs::read(w.path()).unwrap();
        let mut events = Vec::new();
        let mut at = 0;
        while at < bytes.len() {
            let len_bytes = &bytes[at..at + 8];
            let len = u64::from_le_bytes(len_bytes.try_into().unwrap()) as usize;
            let crc = u32::from_le_bytes(bytes[at + 8..at + 12].try_into().unwrap());
            assert_eq!(crc, masked_crc(len_bytes));
            let payload = &bytes[at + 12..at + 12 + len];
            let crc = u32::from_le_bytes(bytes[at + 12 + len..at + 16 + len].try_into().unwrap());
            assert_eq!(crc, masked_crc(payload));
            events.push(Event::decode(payload).unwrap());
            at += 16 + len;
        }
        assert_eq!(events.len(), 2);
        assert_eq!(events[0].file_version.as_deref(), Some("brain.Event:2"));
        assert_eq!(events[1].step, 7);
        let values = &events[1].summary.as_ref().unwrap().value;
        assert_eq!(values[0].tag, "kl");
        assert_eq!(values[0].simple_value, Some(0.25));
        // A zero is written, not left out as a proto3 default.
        assert_eq!(values[1].tag, "biped_share");
        assert_eq!(values[1].simple_value, Some(0.0));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
