//! A small deterministic mutation fuzzer for the tests of every reader of a file a user hands in
//! (issue 28): seeded mutations of valid files (bytes, numbers, JSON structure), each read back under
//! `catch_unwind`. Dev-only: no crate of the product depends on it.
//!
//! Environment (tests only): `DEEPVIEW_FUZZ_SEED`, `DEEPVIEW_FUZZ_ITERS`, `DEEPVIEW_FUZZ_SECS`.

use serde_json::Value;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// splitmix64.
pub struct Rng(u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `0..n` (0 when `n == 0`).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }
    pub fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// What kind of file: which mutations apply besides the byte-level ones.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kind {
    /// Bytes; numbers in text headers are replaced too.
    Binary,
    /// Text with numbers.
    Text,
    /// JSON: also structural mutations (drop a key or element, wrong types, duplicates).
    Json,
}

/// Numbers that break parsers: zero, signs, type limits and their neighbours, sizes whose products
/// wrap, overflow to infinity, subnormals, and the non-numbers some parsers accept.
const NUMBERS: &[&str] = &[
    "0",
    "-0",
    "1",
    "-1",
    "2",
    "3",
    "7",
    "0.5",
    "-0.5",
    "1.5",
    "180",
    "255",
    "256",
    "65535",
    "65536",
    "2147483647",
    "2147483648",
    "-2147483649",
    "4294967295",
    "4294967296",
    "9007199254740993",
    "2305843009213693952",
    "4611686018427387904",
    "9223372036854775807",
    "9223372036854775808",
    "9223372036854775809",
    "18446744073709551615",
    "18446744073709551616",
    "99999999999999999999999",
    "1e6",
    "1e9",
    "1e18",
    "1e308",
    "-1e308",
    "1e999",
    "-1e999",
    "1e-9",
    "1e-320",
    "5e-324",
    "NaN",
    "nan",
    "inf",
    "-inf",
    "Infinity",
    "1e",
    "--1",
    "0x10",
];
/// Integers written over binary fields (little-endian, 1, 2, 4 or 8 bytes).
const INTEGERS: &[u64] = &[
    0,
    1,
    2,
    3,
    7,
    8,
    16,
    17,
    127,
    128,
    255,
    256,
    0x7fff,
    0xffff,
    0x1_0000,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    0x1_0000_0000,
    1 << 61,
    1 << 62,
    i64::MAX as u64,
    1 << 63,
    u64::MAX,
];
const BYTES: &[u8] = &[
    0, 0xff, 0x7f, 0x80, b'0', b'9', b'-', b'.', b'e', b' ', b'\n', b'#', b'"', b',', b':', b'{',
    b'}', b'[', b']', b'/', 0x93,
];

fn mutate_bytes(rng: &mut Rng, b: &mut Vec<u8>) {
    let len = b.len();
    match rng.below(8) {
        0 if len > 0 => {
            let i = rng.below(len);
            b[i] ^= 1 << rng.below(8);
        }
        1 if len > 0 => {
            let i = rng.below(len);
            b[i] = *rng.pick(BYTES);
        }
        2 => b.truncate(rng.below(len + 1)),
        3 => {
            let at = rng.below(len + 1);
            let n = 1 + rng.below(16);
            let new: Vec<u8> = (0..n)
                .map(|_| {
                    if rng.below(2) == 0 {
                        *rng.pick(BYTES)
                    } else {
                        rng.next_u64() as u8
                    }
                })
                .collect();
            b.splice(at..at, new);
        }
        4 if len > 0 => {
            let s = rng.below(len);
            let n = 1 + rng.below((len - s).min(64));
            b.drain(s..s + n);
        }
        5 if len > 0 => {
            // Duplicate a chunk somewhere.
            let s = rng.below(len);
            let n = 1 + rng.below((len - s).min(256));
            let chunk = b[s..s + n].to_vec();
            let at = rng.below(len + 1);
            b.splice(at..at, chunk);
        }
        6 => {
            let width = *rng.pick(&[1usize, 2, 4, 8]);
            if len >= width {
                let at = rng.below(len - width + 1);
                let v = rng.pick(INTEGERS).to_le_bytes();
                b[at..at + width].copy_from_slice(&v[..width]);
            }
        }
        _ if len > 0 => {
            // Copy a chunk over another place.
            let (s, d) = (rng.below(len), rng.below(len));
            let n = 1 + rng.below((len - s.max(d)).min(32));
            let chunk = b[s..s + n].to_vec();
            b[d..d + n].copy_from_slice(&chunk);
        }
        _ => b.push(rng.next_u64() as u8),
    }
}

/// Spans of number-like tokens (`-1.5e3`), not parts of names (`layer_000`).
fn number_spans(b: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let digit_at = |k: usize| b.get(k).is_some_and(u8::is_ascii_digit);
        let starts = b[i].is_ascii_digit() || (matches!(b[i], b'-' | b'.') && digit_at(i + 1));
        let in_name = i > 0 && (b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_');
        if starts && !in_name {
            let s = i;
            i += 1;
            while i < b.len()
                && (b[i].is_ascii_digit() || matches!(b[i], b'.' | b'e' | b'E' | b'+' | b'-'))
            {
                i += 1;
            }
            out.push((s, i));
        } else {
            i += 1;
        }
    }
    out
}

pub fn mutate_number(rng: &mut Rng, b: &mut Vec<u8>) -> bool {
    let spans = number_spans(b);
    if spans.is_empty() {
        return false;
    }
    let (s, e) = *rng.pick(&spans);
    b.splice(s..e, rng.pick(NUMBERS).bytes());
    true
}

fn pointers(v: &Value, at: String, out: &mut Vec<String>) {
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                pointers(
                    x,
                    format!("{at}/{}", k.replace('~', "~0").replace('/', "~1")),
                    out,
                );
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                pointers(x, format!("{at}/{i}"), out);
            }
        }
        _ => {}
    }
    out.push(at);
}

fn wrong_value(rng: &mut Rng) -> Value {
    let choices = [
        Value::Null,
        Value::Bool(true),
        Value::from("x"),
        Value::from(""),
        Value::Array(Vec::new()),
        Value::Object(Default::default()),
        Value::from(0),
        Value::from(-1),
        Value::from(0.5),
        Value::from(1e300),
        Value::from(u64::MAX),
        Value::from(i64::MIN),
        Value::from(u32::MAX),
        Value::from("1.0"),
    ];
    rng.pick(&choices).clone()
}

/// A structural mutation of JSON; `false` when `b` is not JSON.
pub fn mutate_json(rng: &mut Rng, b: &mut Vec<u8>) -> bool {
    let Ok(mut v) = serde_json::from_slice::<Value>(b) else {
        return false;
    };
    let mut ptrs = Vec::new();
    pointers(&v, String::new(), &mut ptrs);
    let ptr = rng.pick(&ptrs).clone();
    let op = rng.below(5);
    let Some(node) = v.pointer_mut(&ptr) else {
        return false;
    };
    match (op, node) {
        (1, Value::Object(m)) if !m.is_empty() => {
            let k = m.keys().nth(rng.below(m.len())).unwrap().clone();
            m.remove(&k);
        }
        (1, Value::Array(a)) if !a.is_empty() => {
            a.remove(rng.below(a.len()));
        }
        (2, Value::Array(a)) if !a.is_empty() => {
            let x = a[rng.below(a.len())].clone();
            a.insert(rng.below(a.len() + 1), x);
        }
        (2, Value::Object(m)) => {
            m.insert("unexpected".into(), wrong_value(rng));
        }
        (3, Value::Array(a)) => a.clear(),
        (3, Value::Object(m)) => m.clear(),
        (4, node) => *node = Value::Array(vec![node.clone()]),
        (_, node) => *node = wrong_value(rng),
    }
    *b = if rng.below(2) == 0 {
        serde_json::to_vec(&v).unwrap()
    } else {
        serde_json::to_vec_pretty(&v).unwrap()
    };
    true
}

/// One to three stacked mutations of `base`.
pub fn mutate(rng: &mut Rng, kind: Kind, base: &[u8]) -> Vec<u8> {
    let mut b = base.to_vec();
    for _ in 0..1 + rng.below(3) {
        let done = match (kind, rng.below(4)) {
            (Kind::Json, 0 | 1) => mutate_json(rng, &mut b),
            (Kind::Json | Kind::Text, 2) | (Kind::Binary, 0) => mutate_number(rng, &mut b),
            _ => false,
        };
        if !done {
            mutate_bytes(rng, &mut b);
        }
    }
    b
}

fn env<T: std::str::FromStr>(name: &str) -> Option<T> {
    std::env::var(name).ok().and_then(|v| v.trim().parse().ok())
}

fn panic_text(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<String>()
        .cloned()
        .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_else(|| "(non-text panic payload)".into())
}

/// A format-aware mutation (`None`: not applicable to this input).
pub type Special = dyn Fn(&mut Rng, &[u8]) -> Option<Vec<u8>>;

/// One fuzz target: mutations of `seeds` written to `file`, then `parse` called.
pub struct Fuzz<'a> {
    /// The parser(s) under test, for messages and the names of saved failures.
    pub name: &'a str,
    /// Where every input is written before `parse` runs.
    pub file: &'a Path,
    pub kind: Kind,
    /// Valid inputs (each must parse).
    pub seeds: Vec<Vec<u8>>,
    /// Inputs to try (stopped earlier by the time limit).
    pub iters: usize,
    /// Every error message must contain one of these (the file's name or path).
    pub needles: Vec<String>,
    /// A format-aware mutation tried for half of the inputs (e.g. on an embedded header).
    pub special: Option<&'a Special>,
}

impl Fuzz<'_> {
    /// Run the target: `parse` reads `self.file` and returns its error message; invariants of what
    /// it accepts are asserted inside it (a failed assertion is reported like any panic).
    pub fn run(self, mut parse: impl FnMut() -> Result<(), String>) {
        let default_seed = self.name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, c| {
            (h ^ c as u64).wrapping_mul(0x100_0000_01b3)
        });
        let seed = env::<u64>("DEEPVIEW_FUZZ_SEED").unwrap_or(default_seed);
        let iters = env::<usize>("DEEPVIEW_FUZZ_ITERS").unwrap_or(self.iters);
        let secs = env::<f64>("DEEPVIEW_FUZZ_SECS").unwrap_or(5.0);
        eprintln!(
            "fuzz {}: seed {seed} (reproduce with DEEPVIEW_FUZZ_SEED={seed}), up to {iters} inputs or {secs} s",
            self.name
        );
        for (i, s) in self.seeds.iter().enumerate() {
            std::fs::write(self.file, s).unwrap();
            if let Err(e) = parse() {
                panic!("fuzz {}: valid input {i} is refused: {e}", self.name);
            }
        }
        let mut rng = Rng(seed);
        let mut corpus = self.seeds.clone();
        let (start, mut failures) = (Instant::now(), Vec::new());
        let (mut refused, mut accepted) = (0usize, 0usize);
        let deadline = start + Duration::from_secs_f64(secs);
        let mut done = 0;
        while done < iters && Instant::now() < deadline && failures.len() < 5 {
            let base = &corpus[rng.below(corpus.len())];
            let input = match self.special {
                Some(f) if rng.below(2) == 0 => {
                    f(&mut rng, base).unwrap_or_else(|| mutate(&mut rng, self.kind, base))
                }
                _ => mutate(&mut rng, self.kind, base),
            };
            std::fs::write(self.file, &input).unwrap();
            let problem = match catch_unwind(AssertUnwindSafe(&mut parse)) {
                Ok(Ok(())) => {
                    accepted += 1;
                    // Accepted inputs seed further mutations (a small corpus reaching deeper).
                    if corpus.len() < 32 {
                        corpus.push(input.clone());
                    } else {
                        let k = rng.below(corpus.len());
                        corpus[k] = input.clone();
                    }
                    None
                }
                Ok(Err(msg)) => {
                    refused += 1;
                    if msg.trim().is_empty() {
                        Some("empty error message".to_string())
                    } else if !self.needles.iter().any(|n| msg.contains(n.as_str())) {
                        Some(format!(
                            "error does not name the file ({:?}): {msg}",
                            self.needles
                        ))
                    } else {
                        None
                    }
                }
                Err(p) => Some(format!("panicked: {}", panic_text(&*p))),
            };
            if let Some(problem) = problem {
                let dir =
                    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../target/fuzz-failures");
                let saved = dir.join(format!(
                    "{}-seed{seed}-iter{done}",
                    self.name.replace(['/', ' '], "_")
                ));
                let _ = std::fs::create_dir_all(&dir).and_then(|_| std::fs::write(&saved, &input));
                failures.push(format!(
                    "iteration {done}: {problem} (input saved as {})",
                    saved.display()
                ));
            }
            done += 1;
        }
        std::fs::write(self.file, &self.seeds[0]).unwrap();
        eprintln!(
            "fuzz {}: {done} inputs in {:.2} s: {accepted} accepted, {refused} refused, {} failed",
            self.name,
            start.elapsed().as_secs_f64(),
            failures.len(),
        );
        assert!(
            failures.is_empty(),
            "fuzz {} with DEEPVIEW_FUZZ_SEED={seed}:\n{}",
            self.name,
            failures.join("\n")
        );
    }
}
