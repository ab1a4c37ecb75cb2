//! What a learner stamps into a policy's ONNX file (`ModelProto.metadata_props`): the physics
//! engine it trained on, so an evaluation runs on it unless asked otherwise (decision record
//! 0026).
//!
//! Only field 14 of the ModelProto is decoded (prost skips the rest without building it), so
//! reading the stamp from a client's bytes costs one pass over them and no graph.

use prost::Message;

use crate::PolicyError;

/// The key of the physics engine a policy trained on ("rapier" or "articulated").
pub const PHYSICS_ENGINE_KEY: &str = "unigait.physics_engine";

/// onnx.proto `ModelProto`, its metadata alone.
#[derive(Clone, PartialEq, Message)]
struct ModelMetadata {
    #[prost(message, repeated, tag = "14")]
    metadata_props: Vec<StringStringEntry>,
}

/// onnx.proto `StringStringEntryProto`.
#[derive(Clone, PartialEq, Message)]
struct StringStringEntry {
    #[prost(string, tag = "1")]
    key: String,
    #[prost(string, tag = "2")]
    value: String,
}

/// The `metadata_props` of an ONNX model, in file order.
pub fn metadata(bytes: &[u8]) -> Result<Vec<(String, String)>, PolicyError> {
    let decoded = ModelMetadata::decode(bytes).map_err(|e| PolicyError::Parse {
        len: bytes.len(),
        message: e.to_string(),
    })?;
    Ok(decoded
        .metadata_props
        .into_iter()
        .map(|e| (e.key, e.value))
        .collect())
}

/// The physics engine the policy says it trained on; None when it says nothing (exported
/// before the stamp existed, or by another tool). The last entry wins, as in a protobuf map.
pub fn trained_engine(bytes: &[u8]) -> Result<Option<String>, PolicyError> {
    Ok(metadata(bytes)?
        .into_iter()
        .rev()
        .find(|(k, _)| k == PHYSICS_ENGINE_KEY)
        .map(|(_, v)| v))
}

/// `bytes` with one more metadata entry. Appending a repeated field to a serialised message
/// is valid protobuf: the graph's bytes stay as they were.
pub fn with_metadata(bytes: &[u8], key: &str, value: &str) -> Vec<u8> {
    let entry = ModelMetadata {
        metadata_props: vec![StringStringEntry {
            key: key.into(),
            value: value.into(),
        }],
    };
    let mut out = bytes.to_vec();
    out.extend(entry.encode_to_vec());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ModelProto with ir_version 8 and a producer name: fields other than 14.
    fn bare_model() -> Vec<u8> {
        let mut b = vec![0x08, 0x08, 0x12, 0x04];
        b.extend(b"test");
        b
    }

    #[test]
    fn a_stamped_engine_is_read_back_and_the_last_stamp_wins() {
        let bare = bare_model();
        assert_eq!(trained_engine(&bare).expect("decodes"), None);
        let once = with_metadata(&bare, PHYSICS_ENGINE_KEY, "rapier");
        assert_eq!(
            &once[..bare.len()],
            &bare[..],
            "the model's own bytes are kept"
        );
        let other = with_metadata(&once, "producer_note", "x");
        assert_eq!(
            trained_engine(&other).expect("decodes").as_deref(),
            Some("rapier")
        );
        let twice = with_metadata(&other, PHYSICS_ENGINE_KEY, "articulated");
        assert_eq!(
            trained_engine(&twice).expect("decodes").as_deref(),
            Some("articulated")
        );
        assert_eq!(metadata(&twice).expect("decodes").len(), 3);
    }

    #[test]
    fn bytes_that_are_not_protobuf_are_a_parse_error() {
        // Field 14 as a length-delimited entry claiming 100 bytes of 2.
        let err = trained_engine(&[0x72, 100, 0x0a, 0x00]).expect_err("truncated");
        assert!(matches!(err, PolicyError::Parse { len: 4, .. }), "{err}");
    }
}
