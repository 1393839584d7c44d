//! Seeded, deterministic fuzzing for the workspace's fuzz tests: the case
//! runner ([`run`]), value generators with the edge cases that break parsers
//! (NaN, infinities, `-0`, sizes at and beyond every limit), byte-level
//! mutations of valid encodings ([`mutate_bytes`]), protobuf-shaped hostile
//! payloads ([`hostile_protobuf`]), word-level mutations of real
//! instructions ([`mutate_text`]) and a per-thread allocation meter
//! ([`PeakAlloc`]).
//!
//! Every case draws from its own ChaCha8 stream (seed, case index), so a
//! failing case is replayed alone with `VLNAV_FUZZ_CASE=<index>`.
//!
//! Environment:
//! - `VLNAV_FUZZ_CASES`: cases per target (default: the test's own short count);
//! - `VLNAV_FUZZ_SEED`: the seed (default [`DEFAULT_SEED`]);
//! - `VLNAV_FUZZ_CASE`: run only this case index (replaying a failure);
//! - `VLNAV_FUZZ_TRACE`: print each case's index before it runs (to find a
//!   case that aborts the process, e.g. by overflowing the stack).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::collections::BTreeMap;
use std::fmt::Debug;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::time::{Duration, Instant};

use rand::{Rng as _, RngCore, SeedableRng};
pub use rand_chacha::rand_core;

pub mod frames;
pub use rand_chacha::ChaCha8Rng as Rng;

/// The seed every target uses unless `VLNAV_FUZZ_SEED` says otherwise.
pub const DEFAULT_SEED: u64 = 0x766c_6e61_7600;

fn env_u64(name: &str) -> Option<u64> {
    let v = std::env::var(name).ok()?;
    let v = v.trim().replace('_', "");
    v.parse().ok().or_else(|| v.parse::<f64>().ok().map(|f| f as u64))
}

/// Cases to run: `VLNAV_FUZZ_CASES`, else `default`.
pub fn cases(default: u64) -> u64 {
    env_u64("VLNAV_FUZZ_CASES").unwrap_or(default)
}

/// The seed: `VLNAV_FUZZ_SEED`, else [`DEFAULT_SEED`].
pub fn seed() -> u64 {
    env_u64("VLNAV_FUZZ_SEED").unwrap_or(DEFAULT_SEED)
}

/// The random stream of case `index`.
pub fn case_rng(seed: u64, index: u64) -> Rng {
    let mut rng = Rng::seed_from_u64(seed);
    rng.set_stream(index);
    rng
}

/// What a fuzz run saw.
#[derive(Debug, Default)]
pub struct Report {
    pub target: String,
    pub cases: u64,
    pub elapsed: Duration,
    /// Outcome name → how many cases ended so.
    pub outcomes: BTreeMap<String, u64>,
    /// Case index and input (debug form, shortened) of every panic.
    pub panics: Vec<(u64, String, String)>,
    /// The slowest case: its time and index.
    pub slowest: (Duration, u64),
}

impl Report {
    /// Fails the test when any case panicked, naming the first few inputs.
    pub fn assert_no_panics(&self) {
        if self.panics.is_empty() {
            return;
        }
        let shown: Vec<String> = self
            .panics
            .iter()
            .take(5)
            .map(|(i, msg, input)| format!("case {i} (VLNAV_FUZZ_CASE={i}): {msg}\n  input: {input}"))
            .collect();
        panic!("{}: {} of {} cases panicked:\n{}", self.target, self.panics.len(), self.cases, shown.join("\n"));
    }

    /// Cases that ended with `outcome`.
    pub fn count(&self, outcome: &str) -> u64 {
        self.outcomes.get(outcome).copied().unwrap_or(0)
    }
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "fuzz {}: {} cases in {:.2?} ({:.1} µs/case), {} panics, slowest case {} ({:.2?}); outcomes {:?}",
            self.target,
            self.cases,
            self.elapsed,
            self.elapsed.as_secs_f64() * 1e6 / self.cases.max(1) as f64,
            self.panics.len(),
            self.slowest.1,
            self.slowest.0,
            self.outcomes
        )
    }
}

fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

fn shorten(mut s: String, max: usize) -> String {
    if s.len() > max {
        let mut cut = max;
        while !s.is_char_boundary(cut) {
            cut -= 1;
        }
        let len = s.len();
        s.truncate(cut);
        s.push_str(&format!("… ({len} characters)"));
    }
    s
}

/// Runs `cases(default_cases)` cases of a target: `generate` draws an input
/// from the case's stream, `check` examines it (asserting its property) and
/// names the outcome. A panic in either is caught, counted and reported with
/// the case index; the run goes on. Prints the [`Report`] to stderr.
pub fn run<T: Debug>(
    target: &str,
    default_cases: u64,
    generate: impl FnMut(&mut Rng) -> T,
    check: impl FnMut(&T) -> String,
) -> Report {
    run_exact(target, cases(default_cases), generate, check)
}

/// [`run`] with exactly `n` cases, whatever `VLNAV_FUZZ_CASES` says (for a
/// target that runs a fraction of the others' count).
pub fn run_exact<T: Debug>(
    target: &str,
    n: u64,
    mut generate: impl FnMut(&mut Rng) -> T,
    mut check: impl FnMut(&T) -> String,
) -> Report {
    let seed = seed();
    let only = env_u64("VLNAV_FUZZ_CASE");
    let indices: Box<dyn Iterator<Item = u64>> = match only {
        Some(i) => Box::new(std::iter::once(i)),
        None => Box::new(0..n),
    };
    let trace = std::env::var_os("VLNAV_FUZZ_TRACE").is_some();
    let mut report = Report { target: target.to_string(), ..Report::default() };
    let start = Instant::now();
    for i in indices {
        if trace {
            eprintln!("{target}: case {i}");
        }
        let t0 = Instant::now();
        let mut rng = case_rng(seed, i);
        let input = match catch_unwind(AssertUnwindSafe(|| generate(&mut rng))) {
            Ok(input) => input,
            Err(p) => {
                report.panics.push((i, format!("the generator panicked: {}", panic_message(&*p)), String::new()));
                continue;
            }
        };
        match catch_unwind(AssertUnwindSafe(|| check(&input))) {
            Ok(outcome) => *report.outcomes.entry(outcome).or_default() += 1,
            Err(p) => report.panics.push((i, panic_message(&*p), shorten(format!("{input:?}"), 1500))),
        }
        let took = t0.elapsed();
        if took > report.slowest.0 {
            report.slowest = (took, i);
        }
        report.cases += 1;
    }
    report.elapsed = start.elapsed();
    eprintln!("{report}");
    report
}

// ---- Values -----------------------------------------------------------------

/// A float that breaks naive code more often than a uniform one.
pub fn interesting_f64(rng: &mut Rng) -> f64 {
    const SPECIAL: &[f64] = &[
        f64::NAN,
        -f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        0.0,
        -0.0,
        f64::MIN_POSITIVE,
        5e-324,
        f64::MAX,
        f64::MIN,
        1e308,
        -1e308,
        1e-300,
        1.0,
        -1.0,
        0.5,
        1e9,
        -1e9,
        f64::EPSILON,
        std::f64::consts::PI,
    ];
    match rng.random_range(0..4) {
        0 => SPECIAL[rng.random_range(0..SPECIAL.len())],
        1 => f64::from_bits(rng.random()),
        2 => rng.random_range(-10.0..10.0),
        _ => rng.random_range(-1e6..1e6),
    }
}

/// A plausible value for a field that is usually small (a size, a count, a
/// distance) but sometimes anything.
pub fn plausible_f64(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    if rng.random_bool(0.85) { rng.random_range(lo..hi) } else { interesting_f64(rng) }
}

/// An image side or count: 0, the limits and one past them, or random.
pub fn interesting_u32(rng: &mut Rng) -> u32 {
    const SPECIAL: &[u32] = &[
        0,
        1,
        2,
        3,
        255,
        256,
        4095,
        4096,
        4097,
        8191,
        8192,
        8193,
        65535,
        65536,
        1 << 24,
        i32::MAX as u32,
        1 << 31,
        u32::MAX - 1,
        u32::MAX,
    ];
    match rng.random_range(0..3) {
        0 => SPECIAL[rng.random_range(0..SPECIAL.len())],
        1 => rng.random_range(0..64),
        _ => rng.random(),
    }
}

/// An enum's wire value: the known range, one beyond, negative, extremes.
pub fn interesting_i32(rng: &mut Rng, known: i32) -> i32 {
    match rng.random_range(0..6) {
        0..=2 => rng.random_range(0..=known),
        3 => known + 1,
        4 => [-1, i32::MIN, i32::MAX, 1000][rng.random_range(0..4)],
        _ => rng.random(),
    }
}

/// `len` random bytes.
pub fn random_bytes(rng: &mut Rng, len: usize) -> Vec<u8> {
    let mut v = vec![0; len];
    rng.fill_bytes(&mut v);
    v
}

/// A length near `exact`: exact most of the time, else off by a little, 0,
/// or far off.
pub fn near_len(rng: &mut Rng, exact: usize) -> usize {
    match rng.random_range(0..10) {
        0..=5 => exact,
        6 => exact.saturating_sub(rng.random_range(1..4)),
        7 => exact + rng.random_range(1..4),
        8 => 0,
        _ => rng.random_range(0..64),
    }
}

// ---- Byte mutations -----------------------------------------------------------

/// Applies one to four random mutations to `data`: bit flips, interesting
/// bytes and numbers, random insertions and deletions, duplicated ranges,
/// truncation, injected varints (lengths that lie), and chunks spliced from
/// `donors`. The result is at most `max_len` bytes.
pub fn mutate_bytes(rng: &mut Rng, data: &mut Vec<u8>, donors: &[&[u8]], max_len: usize) {
    for _ in 0..rng.random_range(1..=4) {
        let len = data.len();
        let at = if len == 0 { 0 } else { rng.random_range(0..len) };
        match rng.random_range(0..11) {
            0 if len > 0 => data[at] ^= 1 << rng.random_range(0..8),
            1 if len > 0 => data[at] = [0, 1, 0x7f, 0x80, 0xff, 0x08, 0x0a, 0x12][rng.random_range(0..8)],
            2 if len > 0 => data[at] = rng.random(),
            3 => {
                let n = rng.random_range(1..16);
                let bytes = random_bytes(rng, n);
                data.splice(at..at, bytes);
            }
            4 if len > 0 => {
                let end = (at + rng.random_range(1..32)).min(len);
                data.drain(at..end);
            }
            5 if len > 0 => {
                let end = (at + rng.random_range(1..64)).min(len);
                let chunk = data[at..end].to_vec();
                let to = rng.random_range(0..=len);
                data.splice(to..to, chunk);
            }
            6 => data.truncate(at),
            7 => {
                let mut v = Vec::new();
                let value = match rng.random_range(0..4) {
                    0 => rng.random_range(0..300),
                    1 => u64::MAX,
                    2 => 1 << rng.random_range(7..63),
                    _ => rng.random(),
                };
                prost::encoding::encode_varint(value, &mut v);
                data.splice(at..at, v);
            }
            8 if len >= 8 => {
                let at = rng.random_range(0..=len - 8);
                data[at..at + 8].copy_from_slice(&interesting_f64(rng).to_le_bytes());
            }
            9 if len >= 4 => {
                let at = rng.random_range(0..=len - 4);
                let v = interesting_u32(rng);
                let bytes = if rng.random_bool(0.5) { v.to_le_bytes() } else { v.to_be_bytes() };
                data[at..at + 4].copy_from_slice(&bytes);
            }
            10 if !donors.is_empty() => {
                let donor = donors[rng.random_range(0..donors.len())];
                if !donor.is_empty() {
                    let from = rng.random_range(0..donor.len());
                    let end = (from + rng.random_range(1..=64)).min(donor.len());
                    if rng.random_bool(0.5) {
                        data.splice(at..at, donor[from..end].iter().copied());
                    } else {
                        data.truncate(at);
                        data.extend_from_slice(&donor[from..]);
                    }
                }
            }
            _ => {
                let n = rng.random_range(0..4);
                let bytes = random_bytes(rng, n);
                data.extend(bytes);
            }
        }
    }
    data.truncate(max_len);
}

/// A protobuf-looking payload: fields with random numbers and wire types,
/// lengths that lie, varints that never end, nested messages of NaNs.
pub fn hostile_protobuf<R: rand::Rng>(rng: &mut R) -> Vec<u8> {
    let mut out = Vec::new();
    match rng.random_range(0..4) {
        0 => out.extend((0..rng.random_range(0..64)).map(|_| rng.random::<u8>())),
        1 => {
            for _ in 0..rng.random_range(1..12) {
                let field: u32 = rng.random_range(1..20);
                let wire: u32 = rng.random_range(0..6);
                prost::encoding::encode_varint(((field << 3) | wire) as u64, &mut out);
                match wire {
                    0 => prost::encoding::encode_varint(rng.random(), &mut out),
                    1 => out.extend(rng.random::<u64>().to_le_bytes()),
                    2 => {
                        let len: usize = rng.random_range(0..40);
                        // Sometimes the length claims more than follows.
                        let claimed =
                            if rng.random_bool(0.2) { len as u64 + rng.random_range(1..1 << 30) } else { len as u64 };
                        prost::encoding::encode_varint(claimed, &mut out);
                        out.extend((0..len).map(|_| rng.random::<u8>()));
                    }
                    5 => out.extend(rng.random::<u32>().to_le_bytes()),
                    _ => {}
                }
            }
        }
        2 => out.extend(std::iter::repeat_n(0xFF, rng.random_range(1..16))),
        _ => {
            // A frame-like message: nested messages with huge sizes and NaNs.
            let mut inner = Vec::new();
            for field in 1..=9u32 {
                prost::encoding::encode_varint(((field << 3) | 1) as u64, &mut inner);
                let v = [f64::NAN, f64::INFINITY, -1.0, 1e300, 0.0][rng.random_range(0..5)];
                inner.extend(v.to_le_bytes());
            }
            prost::encoding::encode_varint(((rng.random_range(1..8u32) << 3) | 2) as u64, &mut out);
            prost::encoding::encode_varint(inner.len() as u64, &mut out);
            out.extend(inner);
        }
    }
    out
}

/// Bytes for a decoder: hostile protobuf, a mutation of one of `valid`
/// (encodings of real messages), or both spliced together.
pub fn wire_bytes(rng: &mut Rng, valid: &[&[u8]], max_len: usize) -> Vec<u8> {
    if valid.is_empty() || rng.random_bool(0.25) {
        return hostile_protobuf(rng);
    }
    let mut data = valid[rng.random_range(0..valid.len())].to_vec();
    if rng.random_bool(0.3) {
        return data;
    }
    mutate_bytes(rng, &mut data, valid, max_len);
    data
}

// ---- Text -----------------------------------------------------------------------

/// Numbers written the ways that break number parsing.
pub const NUMBERS: &[&str] = &[
    "1e308",
    "1e309",
    "-1e308",
    "NaN",
    "nan",
    "inf",
    "-inf",
    "infinity",
    "-0",
    "-0.0",
    "0",
    "0.0000001",
    "1e-400",
    "99999999999999999999999999999999999999",
    "18446744073709551616",
    "-9223372036854775809",
    "4294967296",
    "0x10",
    "1_000",
    "1,000,000",
    "3.",
    ".5",
    "1..2",
    "2.5.3",
    "--3",
    "+4",
    "1/2",
    "½",
    "٣",
    "１０",
    "Ⅻ",
    "10⁹",
    "1e",
    "e5",
    "5e5e5",
    "thousand",
    "a million",
    "one hundred and a half",
    "nine nine nine nine nine",
    "zero point zero",
    "minus five",
];

/// Words and characters that change length under case mapping, have no
/// width, reverse the text, or are control characters.
pub const ODD_TEXT: &[&str] = &[
    "İ",
    "ß",
    "ﬃ",
    "ǅ",
    "Σ",
    "ΐ",
    "\u{0307}",
    "e\u{0301}",
    "\u{200b}",
    "\u{200d}",
    "\u{202e}",
    "\u{feff}",
    "\u{2028}",
    "\u{85}",
    "\u{0}",
    "\u{7}",
    "\u{1b}[31m",
    "\t",
    "\r\n",
    "\n\n",
    "🤖",
    "👩‍👩‍👧",
    "\u{10ffff}",
    "\u{fffd}",
    "ｍ",
    "Ｍ",
    "中文",
    "مرحبا",
    "'",
    "\"",
    "(",
    ")",
    "((",
    "))",
    ",",
    ".",
    "...",
    ";",
    ":",
    "-",
    "—",
    "!",
    "?",
    "\\",
    "{}",
    "[]",
    "%s",
    "m",
    "cm",
    "mm",
    "km",
    "ft",
    "feet",
    "inches",
    "yards",
    "degrees",
    "°",
    "rad",
    "radians",
    "seconds",
    "minutes",
    "steps",
    "then",
    "and",
    "and then",
    "after that",
    "finally",
    "but",
    "no,",
    "don't",
    "not",
    "it",
    "there",
    "him",
    "twice",
    "again",
    "more",
    "a little",
    "far",
    "around",
    "left",
    "right",
    "Mr.",
    "Dr.",
];

fn words(s: &str) -> Vec<&str> {
    s.split_whitespace().collect()
}

/// An instruction-like string: real `seeds` spliced, duplicated and
/// mutated at the word level (numbers from [`NUMBERS`], words from
/// [`ODD_TEXT`]), sometimes at the byte level (then read as lossy UTF-8), and
/// sometimes grown past `max_bytes` by repetition.
pub fn mutate_text(rng: &mut Rng, seeds: &[&str], max_bytes: usize) -> String {
    let pick = |rng: &mut Rng| seeds[rng.random_range(0..seeds.len())];
    let mut w: Vec<String> = words(pick(rng)).into_iter().map(String::from).collect();
    for _ in 0..rng.random_range(1..=6) {
        let len = w.len();
        let at = if len == 0 { 0 } else { rng.random_range(0..=len) };
        match rng.random_range(0..12) {
            0 => {
                // Splice: this instruction's head, another's tail.
                let other = words(pick(rng));
                let from = rng.random_range(0..=other.len());
                w.truncate(at);
                w.extend(other[from..].iter().map(|s| s.to_string()));
            }
            1 => {
                let other = words(pick(rng));
                let join = ["then", "and", ",", "after that", "finally", ""][rng.random_range(0..6)];
                if !join.is_empty() {
                    w.push(join.into());
                }
                w.extend(other.iter().map(|s| s.to_string()));
            }
            2 | 3 => w.insert(at, NUMBERS[rng.random_range(0..NUMBERS.len())].into()),
            4 => w.insert(at, ODD_TEXT[rng.random_range(0..ODD_TEXT.len())].into()),
            5 if len > 0 => {
                let end = (at + rng.random_range(1..6)).min(len);
                if at < end {
                    let chunk: Vec<String> = w[at..end].to_vec();
                    for _ in 0..rng.random_range(1..4) {
                        w.splice(at..at, chunk.iter().cloned());
                    }
                }
            }
            6 if len > 0 => {
                let end = (at + rng.random_range(1..4)).min(len);
                if at < end {
                    w.drain(at..end);
                }
            }
            7 if len > 1 => {
                let (a, b) = (rng.random_range(0..len), rng.random_range(0..len));
                w.swap(a, b);
            }
            8 if len > 0 => {
                // Glue a number to a word or a unit ("2.5m", "1e308meters").
                let i = rng.random_range(0..len);
                let n = NUMBERS[rng.random_range(0..NUMBERS.len())];
                w[i] = if rng.random_bool(0.5) { format!("{n}{}", w[i]) } else { format!("{}{n}", w[i]) };
            }
            9 if len > 0 => {
                let i = rng.random_range(0..len);
                w[i] = match rng.random_range(0..3) {
                    0 => w[i].to_uppercase(),
                    1 => w[i].chars().rev().collect(),
                    _ => {
                        let digits = rng.random_range(20..400);
                        (0..digits).map(|_| char::from(b'0' + rng.random_range(0..10u8))).collect()
                    }
                };
            }
            10 => {
                // Random characters anywhere in the Unicode range.
                let s: String = (0..rng.random_range(1..8)).map(|_| rng.random::<char>()).collect();
                w.insert(at, s);
            }
            _ => {}
        }
    }
    let sep = if rng.random_bool(0.9) { " " } else { ["", "  ", "\t", ",", "\n"][rng.random_range(0..5)] };
    let mut text = w.join(sep);
    if rng.random_bool(0.1) {
        let mut bytes = text.into_bytes();
        mutate_bytes(rng, &mut bytes, &[], max_bytes + 64);
        text = String::from_utf8_lossy(&bytes).into_owned();
    }
    if rng.random_bool(0.02) && !text.is_empty() {
        // Long inputs: just under, at and over the limit.
        let target = match rng.random_range(0..3) {
            0 => max_bytes.saturating_sub(rng.random_range(0..32)),
            1 => max_bytes,
            _ => max_bytes + rng.random_range(1..4 * max_bytes),
        };
        let unit = format!("{text} ");
        while text.len() + unit.len() <= target {
            text.push_str(&unit);
        }
    }
    text
}

/// Arbitrary text: random characters, random bytes read as lossy UTF-8, or
/// runs of one character.
pub fn arbitrary_text(rng: &mut Rng, max_chars: usize) -> String {
    let n = rng.random_range(0..=max_chars);
    match rng.random_range(0..4) {
        0 => (0..n).map(|_| rng.random::<char>()).collect(),
        1 => String::from_utf8_lossy(&random_bytes(rng, n)).into_owned(),
        2 => (0..n).map(|_| char::from(rng.random_range(0x20..0x7f_u8))).collect(),
        _ => {
            let c = ODD_TEXT[rng.random_range(0..ODD_TEXT.len())];
            c.repeat(n.min(2000) / c.len().max(1) + 1)
        }
    }
}

// ---- Allocation meter --------------------------------------------------------

thread_local! {
    static METERING: Cell<bool> = const { Cell::new(false) };
    static LARGEST: Cell<usize> = const { Cell::new(0) };
    static TOTAL: Cell<usize> = const { Cell::new(0) };
}

/// The system allocator, noting on the current thread the largest single
/// allocation and the bytes allocated while [`metered`] runs. A test binary
/// installs it with `#[global_allocator] static A: PeakAlloc = PeakAlloc;`.
pub struct PeakAlloc;

fn note(size: usize) {
    // `try_with`: the thread-locals may be gone while a thread exits.
    let _ = METERING.try_with(|m| {
        if m.get() {
            let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
            let _ = TOTAL.try_with(|t| t.set(t.get().saturating_add(size)));
        }
    });
}

// SAFETY: every call is forwarded unchanged to the system allocator; the
// bookkeeping touches only `const`-initialised thread-locals, which never allocate.
unsafe impl GlobalAlloc for PeakAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// What [`metered`] measured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Allocated {
    /// The largest single allocation, bytes.
    pub largest: usize,
    /// All allocations together, bytes.
    pub total: usize,
}

/// Runs `f` and returns what it allocated on this thread (zero unless
/// [`PeakAlloc`] is the global allocator).
pub fn metered<R>(f: impl FnOnce() -> R) -> (R, Allocated) {
    LARGEST.with(|l| l.set(0));
    TOTAL.with(|t| t.set(0));
    METERING.with(|m| m.set(true));
    let r = catch_unwind(AssertUnwindSafe(f));
    METERING.with(|m| m.set(false));
    let a = Allocated { largest: LARGEST.with(Cell::get), total: TOTAL.with(Cell::get) };
    match r {
        Ok(r) => (r, a),
        Err(p) => std::panic::resume_unwind(p),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_case_is_replayed_from_its_index() {
        let a: Vec<u8> = random_bytes(&mut case_rng(5, 17), 32);
        let b: Vec<u8> = random_bytes(&mut case_rng(5, 17), 32);
        let c: Vec<u8> = random_bytes(&mut case_rng(5, 18), 32);
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    #[test]
    fn the_runner_counts_outcomes_and_catches_panics() {
        let r = run(
            "self-test",
            200,
            |rng| rng.random_range(0..10u32),
            |&x| {
                assert!(x != 3, "three");
                if x % 2 == 0 { "even".into() } else { "odd".into() }
            },
        );
        assert_eq!(r.cases, 200);
        assert!(!r.panics.is_empty() && r.panics[0].1.contains("three"));
        assert_eq!(r.count("even") + r.count("odd") + r.panics.len() as u64, 200);
    }

    #[test]
    fn mutations_stay_within_the_length_limit() {
        for i in 0..2000 {
            let mut rng = case_rng(1, i);
            let mut data = random_bytes(&mut rng, 100);
            mutate_bytes(&mut rng, &mut data, &[b"donor bytes"], 120);
            assert!(data.len() <= 120);
            let text = mutate_text(&mut rng, &["move 2 m ahead, then find the chair", "turn left"], 4096);
            assert!(text.len() <= 6 * 4096, "{}", text.len());
        }
    }
}
