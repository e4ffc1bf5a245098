//! Mutations of valid inputs for the fuzz tests: a valid file (a mesh, a dataset's JSON, a model
//! file, a configuration) with a few edits of the kinds that break readers: bytes changed,
//! inserted, deleted or duplicated, a cut, and tokens that are valid syntax with hostile values
//! (huge counts, NaN, negative ids, empty containers).

use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

/// How many inputs each fuzz target tries in the short run (the one CI runs), and in the long
/// run (`cargo test -p ppfd-tests --test fuzz -- --ignored`); `PPFD_FUZZ_CASES` overrides both.
pub const SHORT_CASES: u32 = 300;
pub const LONG_CASES: u32 = 30_000;

/// Tokens that keep a text file parseable by a lenient reader but carry values a reader must
/// refuse or bound.
pub const HOSTILE_TOKENS: &[&str] = &[
    "NaN",
    "nan",
    "inf",
    "-inf",
    "1e39",
    "-1",
    "0",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "-2147483649",
    "null",
    "[]",
    "{}",
    "\"\"",
    "[[[[[[[[[[[[[[[[",
    ",",
    ":",
    "\n",
    "\0",
    "end_header\n",
    "element vertex 4294967295\n",
    "element face 2000000000\n",
    "property list uint uint vertex_indices\n",
    "format binary_big_endian 1.0\n",
    "\"obj_id\": -1",
    "\"cam_R_m2c\": [1, 0, 0, 0, 1, 0, 0, 0]",
    "\"cam_K\": [0, 0, 0, 0, 0, 0, 0, 0, 0]",
    "\"depth_scale\": 0",
    "\"diameter\": 1e30",
    "workers = 18446744073709551615",
    "[detector]\nvoting.reference_step = 0\n",
];

/// One edit of a file, positions as fractions of its length so that they land anywhere
/// whatever the file's size.
#[derive(Clone, Debug)]
pub enum Edit {
    /// Replace the byte at the position.
    Set(u32, u8),
    /// Insert a byte.
    Insert(u32, u8),
    /// Insert one of [`HOSTILE_TOKENS`].
    Token(u32, usize),
    /// Remove up to this many bytes.
    Delete(u32, u16),
    /// Copy a span of up to this many bytes to another position.
    Duplicate(u32, u16, u32),
    /// Cut the file here.
    Truncate(u32),
}

/// 1 to 6 edits.
pub fn edits() -> impl Strategy<Value = Vec<Edit>> {
    let edit = prop_oneof![
        4 => (any::<u32>(), any::<u8>()).prop_map(|(p, b)| Edit::Set(p, b)),
        2 => (any::<u32>(), any::<u8>()).prop_map(|(p, b)| Edit::Insert(p, b)),
        4 => (any::<u32>(), 0..HOSTILE_TOKENS.len()).prop_map(|(p, t)| Edit::Token(p, t)),
        2 => (any::<u32>(), 1u16..64).prop_map(|(p, n)| Edit::Delete(p, n)),
        1 => (any::<u32>(), 1u16..256, any::<u32>()).prop_map(|(p, n, q)| Edit::Duplicate(p, n, q)),
        1 => any::<u32>().prop_map(Edit::Truncate),
    ];
    prop::collection::vec(edit, 1..=6)
}

/// `base` with `edits` applied in order.
pub fn mutate(base: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut out = base.to_vec();
    // A position in 0..=len from a fraction of u32::MAX.
    let at = |p: u32, len: usize| ((p as u64 * (len as u64 + 1)) >> 32) as usize;
    for e in edits {
        let len = out.len();
        match *e {
            Edit::Set(p, b) if len > 0 => {
                let i = at(p, len - 1);
                out[i] = b;
            }
            Edit::Set(..) => {}
            Edit::Insert(p, b) => out.insert(at(p, len), b),
            Edit::Token(p, t) => {
                let i = at(p, len);
                out.splice(i..i, HOSTILE_TOKENS[t].bytes());
            }
            Edit::Delete(p, n) => {
                let i = at(p, len);
                let end = (i + n as usize).min(len);
                out.drain(i..end);
            }
            Edit::Duplicate(p, n, q) => {
                let i = at(p, len);
                let span: Vec<u8> = out[i..(i + n as usize).min(len)].to_vec();
                let j = at(q, len);
                out.splice(j..j, span);
            }
            Edit::Truncate(p) => out.truncate(at(p, len)),
        }
    }
    out
}

/// The number of inputs to try: `PPFD_FUZZ_CASES` when set, else `default`.
pub fn cases(default: u32) -> u32 {
    std::env::var("PPFD_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Runs `check` on `cases` inputs drawn from `strategy` (deterministically seeded, so a failure
/// reproduces; nothing is written to disk) and prints how many were tried. A panic or an `Err`
/// of `check` fails the test with the (shrunk) input.
pub fn run<S: Strategy>(
    target: &str,
    cases: u32,
    strategy: S,
    check: impl Fn(S::Value) -> Result<(), TestCaseError>,
) {
    let config = Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    };
    let mut runner = TestRunner::new_with_rng(
        config,
        proptest::test_runner::TestRng::deterministic_rng(
            proptest::test_runner::RngAlgorithm::ChaCha,
        ),
    );
    let tried = std::sync::atomic::AtomicU64::new(0);
    let result = runner.run(&strategy, |v| {
        tried.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        check(v)
    });
    let tried = tried.into_inner();
    println!("fuzz {target}: {tried} inputs tried");
    if let Err(e) = result {
        panic!("fuzz {target}: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edits_land_inside_the_file_and_apply_in_order() {
        let base = b"abcdef";
        assert_eq!(mutate(base, &[Edit::Set(0, b'x')]), b"xbcdef");
        assert_eq!(mutate(base, &[Edit::Set(u32::MAX, b'x')]), b"abcdex");
        assert_eq!(mutate(base, &[Edit::Insert(u32::MAX, b'!')]), b"abcdef!");
        assert_eq!(mutate(base, &[Edit::Delete(0, 2)]), b"cdef");
        assert_eq!(mutate(base, &[Edit::Truncate(u32::MAX / 2)]), b"abc");
        assert_eq!(
            mutate(base, &[Edit::Duplicate(0, 2, u32::MAX)]),
            b"abcdefab"
        );
        assert_eq!(
            mutate(base, &[Edit::Token(0, 0), Edit::Delete(0, 1)]),
            b"aNabcdef"
        );
        assert_eq!(mutate(b"", &[Edit::Set(7, 1), Edit::Delete(3, 9)]), b"");
    }
}
