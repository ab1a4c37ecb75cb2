//! The wire-format scan that bounds what decoding an untrusted model allocates, before anything
//! is decoded (issue 36): models of empty repeated entries are refused with the count or the
//! bound, the bound is exact on hand-built inputs and above what prost really allocates
//! (measured with a counting allocator), and real policies pass.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::PathBuf;

use tract_onnx::pb;
use tract_onnx::prelude::Framework;
use unigait_policy::{ModelLimits, PolicyError, parse_checked, scan_wire};

/// Counts this thread's live heap bytes and their peak, so a test can measure one decode.
struct Counting;

thread_local! {
    static LIVE: Cell<u64> = const { Cell::new(0) };
    static PEAK: Cell<u64> = const { Cell::new(0) };
}

fn add(n: u64) {
    let _ = LIVE.try_with(|l| {
        let v = l.get() + n;
        l.set(v);
        let _ = PEAK.try_with(|p| p.set(p.get().max(v)));
    });
}

fn sub(n: u64) {
    let _ = LIVE.try_with(|l| l.set(l.get().saturating_sub(n)));
}

// SAFETY: forwards to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        add(layout.size() as u64);
        // SAFETY: the caller's layout, passed on.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        sub(layout.size() as u64);
        // SAFETY: `ptr` came from `System.alloc` with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // Both blocks are live while the data moves.
        add(new_size as u64);
        sub(layout.size() as u64);
        // SAFETY: as `alloc`/`dealloc`.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Peak heap bytes this thread allocated while decoding `bytes` with tract's decoder.
fn decode_peak(bytes: &[u8]) -> u64 {
    let start = LIVE.with(Cell::get);
    PEAK.with(|p| p.set(start));
    let decoded = tract_onnx::onnx().proto_model_for_read(&mut &bytes[..]);
    let peak = PEAK.with(Cell::get) - start;
    assert!(decoded.is_ok(), "{:?}", decoded.err());
    drop(decoded);
    peak
}

fn test_policy() -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/test_policy.onnx");
    std::fs::read(path).expect("tests/data/test_policy.onnx")
}

/// A length-delimited field: key, length, body.
fn field(tag: u64, body: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    varint(&mut out, tag << 3 | 2);
    varint(&mut out, body.len() as u64);
    out.extend_from_slice(body);
    out
}

fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// A model whose graph (ModelProto field 7) holds `graph_body`.
fn model(graph_body: &[u8]) -> Vec<u8> {
    field(7, graph_body)
}

const ATTRIBUTE: u64 = std::mem::size_of::<pb::AttributeProto>() as u64;
const NODE: u64 = std::mem::size_of::<pb::NodeProto>() as u64;
const MODEL: u64 = std::mem::size_of::<pb::ModelProto>() as u64;

#[test]
fn a_model_of_empty_nodes_is_refused_by_its_node_count() {
    // 15 MiB of empty NodeProto entries (GraphProto field 1: bytes 0x0a 0x00), the case.
    let n = (15 << 20) / 2;
    let bytes = model(&[0x0a, 0x00].repeat(n));
    assert!(bytes.len() < ModelLimits::default().max_bytes);
    match scan_wire(&bytes, &ModelLimits::default()) {
        Err(PolicyError::TooLarge { what, size, limit }) => {
            assert_eq!(what, "nodes in the graph");
            assert_eq!(size, n as u64);
            assert_eq!(limit, 1024);
        }
        other => panic!("{other:?}"),
    }
    // parse_checked (the worker's path) refuses it before decoding as well.
    assert!(matches!(
        parse_checked(&bytes, &ModelLimits::default()),
        Err(PolicyError::TooLarge { .. })
    ));
}

#[test]
fn empty_attributes_are_refused_by_the_decoded_bound() {
    // One node with a million empty attributes (NodeProto field 5): 2 MiB on the wire.
    let n: u64 = 1 << 20;
    let node = [0x2a, 0x00].repeat(n as usize);
    let bytes = model(&field(1, &node));
    // Hand-computed: the model, one node and a million attributes, each `Vec` element counted
    // three times (a doubling `Vec` moving to its next block).
    let expected = MODEL + 3 * NODE + 3 * n * ATTRIBUTE;
    let lenient = ModelLimits {
        max_decoded_bytes: u64::MAX,
        ..ModelLimits::default()
    };
    assert_eq!(scan_wire(&bytes, &lenient).expect("scan"), expected);
    match scan_wire(&bytes, &ModelLimits::default()) {
        Err(PolicyError::TooLarge { size, limit, .. }) => {
            assert_eq!(size, expected);
            assert_eq!(limit, 128 << 20);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn the_bound_is_above_what_decoding_allocates() {
    let lenient = ModelLimits {
        max_decoded_bytes: u64::MAX,
        max_nodes: usize::MAX,
        ..ModelLimits::default()
    };
    let attributes = model(&field(1, &[0x2a, 0x00].repeat(20_000)));
    let nodes = model(&[0x0a, 0x00].repeat(50_000));
    // A tensor (GraphProto field 5) with 100k packed one-byte dims (TensorProto field 1).
    let dims = model(&field(5, &field(1, &[1u8; 100_000])));
    // Node inputs (NodeProto field 1): 30k empty strings.
    let strings = model(&field(1, &[0x0a, 0x00].repeat(30_000)));
    for (name, bytes) in [
        ("attributes", attributes),
        ("nodes", nodes),
        ("dims", dims),
        ("strings", strings),
        ("test_policy", test_policy()),
    ] {
        let bound = scan_wire(&bytes, &lenient).expect(name);
        let peak = decode_peak(&bytes);
        eprintln!(
            "{name}: {} wire bytes, bound {bound}, decode peak {peak}",
            bytes.len()
        );
        // The decoder's copy of the input (tract reads it into a buffer) is not the model's.
        assert!(
            peak <= bound + bytes.len() as u64,
            "{name}: peak {peak} > bound {bound}"
        );
    }
}

#[test]
fn real_policies_pass_and_malformed_bytes_are_parse_errors() {
    let policy = test_policy();
    let bound = scan_wire(&policy, &ModelLimits::default()).expect("the test policy");
    assert!(bound >= policy.len() as u64 / 2 && bound < 4 * policy.len() as u64 + (1 << 16));
    parse_checked(&policy, &ModelLimits::default()).expect("parses");
    // Truncated inside a field.
    let cut = &policy[..policy.len() - 3];
    assert!(matches!(
        scan_wire(cut, &ModelLimits::default()),
        Err(PolicyError::Parse { .. })
    ));
    // A length that runs past the end.
    assert!(matches!(
        scan_wire(&[0x3a, 0xff, 0xff, 0x03], &ModelLimits::default()),
        Err(PolicyError::Parse { .. })
    ));
    // Field number 0 and a group.
    for bad in [&[0x02, 0x00][..], &[0x3b, 0x3c][..]] {
        assert!(matches!(
            scan_wire(bad, &ModelLimits::default()),
            Err(PolicyError::Parse { .. })
        ));
    }
}

#[test]
fn deep_nesting_is_refused_without_recursing_far() {
    // graph { node { attribute { g: graph { node { ... } } } } }, 40 levels of graphs.
    let mut body = Vec::new();
    for _ in 0..40 {
        // AttributeProto.g (6) holds the graph; NodeProto.attribute (5); GraphProto.node (1).
        body = field(1, &field(5, &field(6, &body)));
    }
    let bytes = model(&body);
    match scan_wire(&bytes, &ModelLimits::default()) {
        Err(PolicyError::Parse { message, .. }) => assert!(message.contains("nest"), "{message}"),
        other => panic!("{other:?}"),
    }
}
