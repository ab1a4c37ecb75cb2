//! The ONNX loader against the committed test policies of `tests/data/` (written by
//! `tests/data/make_test_policy.py`): outputs match the independent numpy forward pass within
//! 1e-5 at batch 1 and 1024, the per-batch-size plans (and chunking) agree with it at any batch
//! and in any order, a fixed-batch export runs at any batch, and malformed or mismatched graphs
//! are refused with a clear error.

use std::collections::HashMap;
use std::path::PathBuf;

use unigait_policy::{OnnxPolicy, Policy, PolicyError, PolicySpec};

const EXPECTED_BATCH: usize = 1024;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(name)
}

/// `x[b, k] = ((b * 53 + k * 17) % 101) / 50 - 1`, as `history_inputs` in the Python script.
fn inputs(batch: usize) -> Vec<f32> {
    let w = PolicySpec::default().input_width();
    (0..batch)
        .flat_map(|b| (0..w).map(move |k| ((b * 53 + k * 17) % 101) as f32 / 50.0 - 1.0))
        .collect()
}

fn expected() -> Vec<f32> {
    let bytes = std::fs::read(data("test_policy_expected.f32")).expect("expected outputs");
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// The reference actions for `inputs(batch)`, any batch: the inputs repeat every 101 rows
/// (`b * 53 mod 101`), so row `b` is reference row `b % 101`.
fn expected_rows(expected: &[f32], batch: usize) -> Vec<f32> {
    (0..batch)
        .flat_map(|b| &expected[(b % 101) * 12..(b % 101 + 1) * 12])
        .copied()
        .collect()
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn matches_numpy_reference_at_batch_1_and_1024() {
    let policy = OnnxPolicy::from_path(data("test_policy.onnx"), PolicySpec::default())
        .expect("test policy loads");
    assert_eq!(policy.fixed_batch(), None);
    let expected = expected();
    assert_eq!(expected.len(), EXPECTED_BATCH * 12);

    let one = policy.act_vec(&inputs(1), 1).expect("batch 1 runs");
    let err1 = max_abs_diff(&one, &expected[..12]);
    assert!(err1 < 1e-5, "batch 1: max abs diff {err1}");

    let all = policy
        .act_vec(&inputs(EXPECTED_BATCH), EXPECTED_BATCH)
        .expect("batch 1024 runs");
    let err = max_abs_diff(&all, &expected);
    assert!(err < 1e-5, "batch 1024: max abs diff {err}");
    // Not a trivial output.
    assert!(all.iter().any(|v| v.abs() > 1e-3));
}

#[test]
fn per_batch_plans_match_the_reference_at_any_batch_in_any_order() {
    let policy = OnnxPolicy::from_path(data("test_policy.onnx"), PolicySpec::default()).unwrap();
    let expected = expected();
    let chunk = OnnxPolicy::CHUNK_ROWS;
    assert!(
        policy.cached_plan_sizes().is_empty(),
        "plans are built on first use"
    );
    // Small batches, whole chunks, chunks plus a remainder, and sizes coming back after others.
    let batches = [
        1,
        7,
        1024,
        4096,
        7,
        1,
        chunk + 1,
        chunk - 1,
        chunk,
        4096,
        3 * chunk + 44,
        1024,
    ];
    let mut first: HashMap<usize, Vec<f32>> = HashMap::new();
    for batch in batches {
        let out = policy.act_vec(&inputs(batch), batch).expect("runs");
        let err = max_abs_diff(&out, &expected_rows(&expected, batch));
        assert!(err < 1e-5, "batch {batch}: max abs diff {err}");
        match first.get(&batch) {
            // The cached plan again: the very same values.
            Some(before) => assert_eq!(before, &out, "batch {batch} changed on a later call"),
            None => {
                first.insert(batch, out);
            }
        }
    }
    // A row's actions do not depend on the batch size (plan) it was computed with.
    let whole = &first[&4096];
    for (batch, out) in &first {
        let err = max_abs_diff(out, &whole[..out.len()]);
        assert!(err < 1e-5, "batch {batch} vs 4096: max abs diff {err}");
    }
    // One plan per row count run: the small batches, the chunk, and the remainders.
    let mut sizes = vec![1, 7, chunk, chunk - 1, 44];
    sizes.sort_unstable();
    assert_eq!(policy.cached_plan_sizes(), sizes);
}

#[test]
fn concurrent_callers_at_different_batches_get_the_reference() {
    let policy = OnnxPolicy::from_path(data("test_policy.onnx"), PolicySpec::default()).unwrap();
    let expected = expected();
    std::thread::scope(|scope| {
        for batch in [1, 7, 300, 1024, 4096, 7, 300] {
            let (policy, expected) = (&policy, &expected);
            scope.spawn(move || {
                for _ in 0..3 {
                    let out = policy.act_vec(&inputs(batch), batch).expect("runs");
                    let err = max_abs_diff(&out, &expected_rows(expected, batch));
                    assert!(err < 1e-5, "batch {batch}: max abs diff {err}");
                }
            });
        }
    });
}

#[test]
fn plan_cache_is_bounded_and_extra_sizes_still_run() {
    let policy = OnnxPolicy::from_path(data("test_policy.onnx"), PolicySpec::default()).unwrap();
    let expected = expected();
    let max = OnnxPolicy::MAX_CACHED_PLANS;
    for batch in 1..=max + 4 {
        let out = policy.act_vec(&inputs(batch), batch).expect("runs");
        let err = max_abs_diff(&out, &expected_rows(&expected, batch));
        assert!(err < 1e-5, "batch {batch}: max abs diff {err}");
    }
    assert_eq!(
        policy.cached_plan_sizes(),
        (1..=max).collect::<Vec<_>>(),
        "the first sizes are kept, the later ones run on the symbolic plan"
    );
}

#[test]
fn fixed_batch_export_runs_at_any_batch() {
    let bytes = std::fs::read(data("test_policy_fixed_batch.onnx")).expect("file");
    let policy = OnnxPolicy::from_bytes(&bytes, PolicySpec::default()).expect("loads");
    let expected = expected();
    for batch in [1, 7, 1024, 4096] {
        let out = policy.act_vec(&inputs(batch), batch).expect("runs");
        let err = max_abs_diff(&out, &expected_rows(&expected, batch));
        assert!(err < 1e-5, "batch {batch}: max abs diff {err}");
    }
}

#[test]
fn random_bytes_are_refused_clearly() {
    // A fixed pseudo-random byte string (xorshift), not an ONNX protobuf.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let bytes: Vec<u8> = (0..4096)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 24) as u8
        })
        .collect();
    let err = OnnxPolicy::from_bytes(&bytes, PolicySpec::default()).expect_err("refused");
    assert!(
        matches!(err, PolicyError::Parse { len: 4096, .. }),
        "unexpected error: {err:?}"
    );
    assert!(err.to_string().contains("not an ONNX model"), "{err}");
    let empty = OnnxPolicy::from_bytes(&[], PolicySpec::default()).expect_err("refused");
    assert!(empty.to_string().contains("not an ONNX model"), "{empty}");
}

#[test]
fn wrong_input_width_is_refused_clearly() {
    let err = OnnxPolicy::from_path(data("test_policy_wrong_width.onnx"), PolicySpec::default())
        .expect_err("refused");
    match &err {
        PolicyError::InputShape {
            name,
            got,
            expected,
        } => {
            assert_eq!(name, "obs_history");
            assert_eq!(got, "[batch, 3, 50]");
            assert!(expected.contains("[batch, 3, 53]"), "{expected}");
        }
        other => panic!("unexpected error: {other:?}"),
    }
    assert!(err.to_string().contains("expected [batch, 3, 53]"), "{err}");
}

#[test]
fn wrong_action_count_is_refused_clearly() {
    // The test policy has 12 actions; a spec asking for 10 must be refused at load time.
    let spec = PolicySpec {
        num_actions: 10,
        ..PolicySpec::default()
    };
    let err = OnnxPolicy::from_path(data("test_policy.onnx"), spec).expect_err("refused");
    assert!(matches!(err, PolicyError::OutputShape { .. }), "{err:?}");
    assert!(err.to_string().contains("expected [batch, 10]"), "{err}");
}

#[test]
fn wrong_batch_length_is_an_error_not_a_panic() {
    let policy = OnnxPolicy::from_path(data("test_policy.onnx"), PolicySpec::default()).unwrap();
    let err = policy.act_vec(&[0.0; 100], 1).expect_err("refused");
    assert!(
        matches!(
            err,
            PolicyError::Batch {
                got: 100,
                expected: 159,
                ..
            }
        ),
        "{err:?}"
    );
}

#[test]
fn missing_file_is_an_io_error() {
    let err = OnnxPolicy::from_path(data("no_such_policy.onnx"), PolicySpec::default())
        .expect_err("refused");
    assert!(matches!(err, PolicyError::Io { .. }), "{err:?}");
}
