//! The embedded default planner: a deterministic HTN parser in the paper's
//! three layers.
//!
//! 1. **Lexical primitives** — the instruction is tokenised (numbers, units,
//!    honorifics and parentheses kept whole), split into clauses at
//!    punctuation and connectives ("then", "finally", "and" + verb), filler
//!    is dropped, and each clause is tagged with the primitive its verb
//!    names: MOVE, FIND, FOLLOW, RETURN.
//! 2. **Directive resolution** — each clause resolves into an egocentric
//!    geometric branch (turn direction and angle, distance) or an
//!    allocentric semantic branch (a landmark phrase); a pure turn followed
//!    by a pure drive becomes one MOVE, as MOVE turns first, then drives.
//! 3. **Grounding** — numbers and units become metres and radians, landmark
//!    phrases become COCO-80 ids through the [`Grounder`], person names
//!    become identities. Anything that cannot be grounded turns the whole
//!    answer into a clarification question; the parser never guesses.
//!
//! Documented defaults for vague language:
//! - "a little / a bit / slightly ahead", or a drive with no distance: [`VAGUE_SHORT_M`] (the paper's 2.5 m);
//! - "a few metres": 3 m; "a couple of metres": 2 m; "far / a long way": [`VAGUE_FAR_M`];
//! - "a step": [`STEP_M`] per step;
//! - a plain left/right turn: ±1.57 rad; "slightly / bear / veer": ±[`SLIGHT_TURN_RAD`]; "half left": ±0.79;
//!   "around / U-turn": 3.14; a number with no unit in a drive: metres;
//! - "go back N m", "reverse N m": turn around (3.14) and drive N m, so the camera faces the way it drives.
//!
//! Yaw values are rounded to 0.01 rad and distances to 0.01 m.

use crate::grounding::{Grounder, Ungrounded, Via};
use crate::plan::{Action, Clarification, MAX_INSTRUCTION_BYTES, Outcome, Plan, Step};
use crate::validate::MAX_SPLIT_M;

/// "A little ahead" and any drive without a distance, metres (the paper's value).
pub const VAGUE_SHORT_M: f64 = 2.5;
/// "Far", "a long way", metres.
pub const VAGUE_FAR_M: f64 = 8.0;
/// One "step", metres.
pub const STEP_M: f64 = 0.75;
/// A right-angle turn as the paper writes it, radians.
pub const RIGHT_ANGLE: f64 = 1.57;
/// Half a turn, radians, as the paper writes it (3.14, not π).
#[allow(clippy::approx_constant)]
pub const HALF_TURN: f64 = 3.14;
/// "Turn slightly", "bear left", radians (30°).
pub const SLIGHT_TURN_RAD: f64 = 0.52;

/// Why an instruction is refused outright (mapped to INVALID_ARGUMENT).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InputError {
    #[error("instruction is empty: say what the robot should do, e.g. \"move 2 m ahead, then find the chair\"")]
    Empty,
    #[error("instruction is {0} bytes; at most {MAX_INSTRUCTION_BYTES} bytes are accepted")]
    TooLong(usize),
    #[error("instruction contains control or binary characters (first at byte {0}); send plain text")]
    Binary(usize),
}

/// Checks that apply to every backend before any parsing.
pub fn check_input(text: &str) -> Result<(), InputError> {
    if text.len() > MAX_INSTRUCTION_BYTES {
        return Err(InputError::TooLong(text.len()));
    }
    if let Some((i, _)) = text.char_indices().find(|(_, c)| c.is_control() && !matches!(c, '\n' | '\r' | '\t')) {
        return Err(InputError::Binary(i));
    }
    if text.trim().is_empty() {
        return Err(InputError::Empty);
    }
    Ok(())
}

/// The result of parsing: a plan or a question, plus notes (grounding
/// choices, defaults applied).
#[derive(Clone, Debug, PartialEq)]
pub struct Parsed {
    pub outcome: Outcome,
    pub notes: Vec<String>,
    /// Places named that no detectable class covers; the plan goes without them.
    pub ungrounded: Vec<String>,
}

impl Parsed {
    fn with_notes(mut self, notes: Vec<String>) -> Parsed {
        self.notes = notes;
        self
    }

    fn ask(question: impl Into<String>, reason: impl Into<String>, options: Vec<String>, notes: Vec<String>) -> Parsed {
        Parsed {
            outcome: Outcome::Clarify(Clarification { question: question.into(), reason: reason.into(), options }),
            notes,
            ungrounded: Vec::new(),
        }
    }
}

// ---- Layer 1: lexical primitives ------------------------------------------

#[derive(Clone, Debug, PartialEq)]
struct Token {
    /// Lower case, punctuation trimmed.
    w: String,
    /// Starts with an upper-case letter in the original text.
    capital: bool,
}

/// Titles before a name; the spelled-out forms are what speech recognition writes.
const HONORIFICS: &[&str] = &[
    "mr.", "mrs.", "ms.", "dr.", "mr", "mrs", "ms", "dr", "miss", "sir", "madam", "prof.", "prof", "mister", "missus",
];

fn tokenize(text: &str) -> Vec<Token> {
    let text =
        text.replace(['\u{2019}', '\u{2018}'], "'").replace(['\u{201c}', '\u{201d}'], "\"").replace('°', " degrees ");
    let mut out = Vec::new();
    let mut paren: Option<String> = None;
    for raw in text.split_whitespace() {
        if let Some(p) = paren.as_mut() {
            p.push(' ');
            p.push_str(raw);
            if raw.contains(')') {
                let whole = paren.take().unwrap_or_default();
                push_word(&mut out, &whole);
            }
            continue;
        }
        if raw.starts_with('(') && !raw.contains(')') {
            paren = Some(raw.to_string());
            continue;
        }
        push_word(&mut out, raw);
    }
    if let Some(p) = paren {
        push_word(&mut out, &p);
    }
    out
}

fn push_word(out: &mut Vec<Token>, raw: &str) {
    let capital = raw.chars().next().is_some_and(char::is_uppercase);
    let mut w = raw.to_lowercase();
    if w.starts_with('(') {
        // A parenthesis stays one token and attaches to the phrase before it.
        let end = w.rfind(')').map(|i| i + 1).unwrap_or(w.len());
        let rest = w[end..].to_string();
        w.truncate(end);
        out.push(Token { w, capital });
        for c in rest.chars().filter(|c| matches!(c, ',' | '.' | ';' | '!' | '?' | ':')) {
            out.push(Token { w: c.to_string(), capital: false });
        }
        return;
    }
    let mut trailing = Vec::new();
    while let Some(c) = w.chars().last() {
        if matches!(c, ',' | ';' | '!' | '?' | ':' | '"' | '\'' | ')')
            || (c == '.' && !HONORIFICS.contains(&w.as_str()))
        {
            w.pop();
            if matches!(c, ',' | ';' | '!' | '?' | ':' | '.') {
                trailing.push(c.to_string());
            }
        } else {
            break;
        }
    }
    let w = w.trim_start_matches(['"', '\'', '(']).to_string();
    if !w.is_empty() {
        split_number_unit(out, &w, capital);
    }
    for t in trailing.into_iter().rev().take(1) {
        out.push(Token { w: t, capital: false });
    }
}

/// "4m" → "4" "m", "2.5meters" → "2.5" "meters", "90deg" → "90" "deg";
/// "twenty-five" → "twenty" "five".
fn split_number_unit(out: &mut Vec<Token>, w: &str, capital: bool) {
    let digits = w.chars().take_while(|c| c.is_ascii_digit() || *c == '.').count();
    if digits > 0 && digits < w.len() && w[..digits].chars().any(|c| c.is_ascii_digit()) {
        let unit = &w[digits..];
        if unit.chars().all(|c| c.is_ascii_alphabetic()) {
            out.push(Token { w: w[..digits].to_string(), capital: false });
            out.push(Token { w: unit.to_string(), capital: false });
            return;
        }
    }
    if w.contains('-') && w.split('-').all(|p| word_number(p).is_some()) {
        for p in w.split('-') {
            out.push(Token { w: p.to_string(), capital });
        }
        return;
    }
    out.push(Token { w: w.to_string(), capital });
}

/// Words that carry no meaning for the plan.
const FILLER: &[&str] = &[
    "buddy",
    "please",
    "hi",
    "hello",
    "hey",
    "ok",
    "okay",
    "now",
    "kindly",
    "robot",
    "husky",
    "thanks",
    "thank",
    "then",
    "finally",
    "and",
    "so",
    "also",
    "first",
    "firstly",
    "next",
    "afterwards",
    "after",
    "that",
    "well",
    "alright",
    "just",
    "could",
    "can",
    "would",
    "will",
    "you",
    "i",
    "want",
    "need",
    "to",
    "lastly",
    "at",
    "last",
    "the",
    "a",
    "an",
    "there",
    "dear",
    "good",
    "great",
    "immediately",
    "quickly",
    "slowly",
    "carefully",
    "fine",
];

/// Verbs that start a new clause after "and".
const CLAUSE_VERBS: &[&str] = &[
    "move", "go", "turn", "take", "find", "follow", "report", "come", "return", "stop", "look", "search", "head",
    "walk", "drive", "proceed", "reach", "approach", "bring", "deliver", "rotate", "locate", "visit", "get",
    "continue", "keep", "make", "face", "advance", "back", "reverse", "fetch", "navigate", "spin", "meet", "then",
    "finally", "on", "in", "you", "there",
];

fn clauses(tokens: &[Token]) -> Vec<Vec<Token>> {
    let mut out: Vec<Vec<Token>> = vec![Vec::new()];
    let mut i = 0;
    while i < tokens.len() {
        let t = &tokens[i];
        let next = tokens.get(i + 1).map(|t| t.w.as_str());
        let boundary =
            matches!(t.w.as_str(), "," | "." | ";" | "!" | "?" | ":" | "then" | "finally" | "afterwards" | "lastly")
                || (t.w == "after" && next == Some("that"))
                || (t.w == "and" && next.is_some_and(|n| CLAUSE_VERBS.contains(&n)));
        if boundary {
            if t.w == "after" {
                i += 1;
            }
            out.push(Vec::new());
        } else if let Some(last) = out.last_mut() {
            last.push(t.clone());
        }
        i += 1;
    }
    // A side said on its own ("in your right, you may see …", a comma a
    // transcriber put in) belongs to the clause after it.
    let mut merged: Vec<Vec<Token>> = Vec::new();
    let mut pending: Vec<Token> = Vec::new();
    for clause in out.into_iter().filter(|c| !c.is_empty()) {
        let only_side = clause.iter().any(|t| matches!(t.w.as_str(), "left" | "right"))
            && clause.iter().all(|t| SIDE_PHRASE_WORDS.contains(&t.w.as_str()));
        pending.extend(clause);
        if !only_side {
            merged.push(std::mem::take(&mut pending));
        }
    }
    if !pending.is_empty() {
        merged.push(pending);
    }
    merged
}

/// Words of a side phrase that is not a clause by itself ("on your left").
const SIDE_PHRASE_WORDS: &[&str] =
    &["on", "in", "to", "at", "your", "the", "my", "left", "right", "hand", "side", "left-hand", "right-hand"];

// ---- numbers and units ------------------------------------------------------

fn word_number(w: &str) -> Option<f64> {
    const SMALL: [&str; 20] = [
        "zero",
        "one",
        "two",
        "three",
        "four",
        "five",
        "six",
        "seven",
        "eight",
        "nine",
        "ten",
        "eleven",
        "twelve",
        "thirteen",
        "fourteen",
        "fifteen",
        "sixteen",
        "seventeen",
        "eighteen",
        "nineteen",
    ];
    const TENS: [&str; 8] = ["twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety"];
    if let Some(i) = SMALL.iter().position(|s| *s == w) {
        return Some(i as f64);
    }
    TENS.iter().position(|s| *s == w).map(|i| (i as f64 + 2.0) * 10.0)
}

/// A number starting at token `i`: digits ("2.5"), words ("two", "twenty
/// five", "one hundred"), "two point five", "one and a half", "half a",
/// "a couple of", "a few", "a" / "an" before a unit. Returns the value and
/// the index after it.
fn number_at(t: &[Token], i: usize) -> Option<(f64, usize)> {
    let w = |k: usize| t.get(k).map(|x| x.w.as_str()).unwrap_or("");
    let first = w(i);
    if first.is_empty() {
        return None;
    }
    if first.chars().next().is_some_and(|c| c.is_ascii_digit()) {
        // Plain decimals only: no exponents, "inf" or "NaN".
        if !first.chars().all(|c| c.is_ascii_digit() || c == '.') {
            return None;
        }
        let v: f64 = first.parse().ok()?;
        return Some(and_a_half(t, v, i + 1));
    }
    match first {
        "half" => return Some((0.5, if w(i + 1) == "a" || w(i + 1) == "an" { i + 2 } else { i + 1 })),
        "a" | "an" if w(i + 1) == "couple" => return Some((2.0, if w(i + 2) == "of" { i + 3 } else { i + 2 })),
        "a" | "an" if w(i + 1) == "few" => return Some((3.0, i + 2)),
        "a" | "an" if w(i + 1) == "half" => return Some((0.5, i + 2)),
        "a" | "an" if is_unit(w(i + 1)) => return Some((1.0, i + 1)),
        "couple" => return Some((2.0, if w(i + 1) == "of" { i + 2 } else { i + 1 })),
        "few" => return Some((3.0, i + 1)),
        _ => {}
    }
    let mut total = word_number(first)?;
    let mut k = i + 1;
    if total >= 20.0
        && let Some(u) = word_number(w(k)).filter(|u| *u < 10.0)
    {
        total += u;
        k += 1;
    }
    if w(k) == "hundred" {
        total *= 100.0;
        k += 1;
        if w(k) == "and" && word_number(w(k + 1)).is_some() {
            k += 1;
        }
        if let Some(u) = word_number(w(k)) {
            total += u;
            k += 1;
        }
    }
    if w(k) == "point" {
        let mut frac = String::new();
        let mut j = k + 1;
        while let Some(d) = word_number(w(j)).filter(|d| *d < 10.0) {
            frac.push_str(&(d as u32).to_string());
            j += 1;
        }
        if !frac.is_empty() {
            total += format!("0.{frac}").parse::<f64>().unwrap_or(0.0);
            k = j;
        }
    }
    Some(and_a_half(t, total, k))
}

fn and_a_half(t: &[Token], v: f64, k: usize) -> (f64, usize) {
    let w = |j: usize| t.get(j).map(|x| x.w.as_str()).unwrap_or("");
    if w(k) == "and" && w(k + 1) == "a" && w(k + 2) == "half" {
        (v + 0.5, k + 3)
    } else if w(k) == "and" && w(k + 1) == "half" {
        (v + 0.5, k + 2)
    } else {
        (v, k)
    }
}

fn length_unit(w: &str) -> Option<f64> {
    Some(match w {
        "m" | "meter" | "meters" | "metre" | "metres" | "mtr" | "mtrs" => 1.0,
        "cm" | "centimeter" | "centimeters" | "centimetre" | "centimetres" => 0.01,
        "mm" | "millimeter" | "millimeters" | "millimetre" | "millimetres" => 0.001,
        "ft" | "foot" | "feet" => 0.3048,
        "yd" | "yard" | "yards" => 0.9144,
        "in" | "inch" | "inches" => 0.0254,
        "km" | "kilometer" | "kilometers" | "kilometre" | "kilometres" => 1000.0,
        "step" | "steps" | "pace" | "paces" => STEP_M,
        _ => return None,
    })
}

fn angle_unit(w: &str) -> Option<f64> {
    Some(match w {
        "degree" | "degrees" | "deg" | "degs" => std::f64::consts::PI / 180.0,
        "radian" | "radians" | "rad" | "rads" => 1.0,
        _ => return None,
    })
}

fn is_unit(w: &str) -> bool {
    (length_unit(w).is_some() && w != "in") || angle_unit(w).is_some()
}

/// Quantities found in a clause.
#[derive(Debug, Default, Clone, PartialEq)]
struct Quantities {
    /// Distances in metres, with the token range they span.
    lengths: Vec<(f64, usize, usize)>,
    /// Angles in radians (unsigned).
    angles: Vec<f64>,
    /// Durations in seconds.
    durations: Vec<f64>,
    /// A number with no unit (taken as metres in a drive).
    bare: Vec<(f64, usize, usize)>,
}

fn quantities(t: &[Token]) -> Quantities {
    let mut q = Quantities::default();
    let mut i = 0;
    while i < t.len() {
        // "a" / "an" alone is an article unless a unit follows.
        if let Some((v, k)) = number_at(t, i) {
            let unit = t.get(k).map(|x| x.w.as_str()).unwrap_or("");
            if let Some(f) = length_unit(unit).filter(|_| unit != "in" || k + 1 < t.len()) {
                q.lengths.push((v * f, i, k + 1));
                i = k + 1;
                continue;
            }
            if let Some(f) = angle_unit(unit) {
                q.angles.push(v * f);
                i = k + 1;
                continue;
            }
            if let Some(f) = match unit {
                "s" | "sec" | "secs" | "second" | "seconds" => Some(1.0),
                "min" | "mins" | "minute" | "minutes" => Some(60.0),
                "h" | "hour" | "hours" => Some(3600.0),
                _ => None,
            } {
                q.durations.push(v * f);
                i = k + 1;
                continue;
            }
            if !matches!(t[i].w.as_str(), "a" | "an" | "half" | "couple" | "few") {
                q.bare.push((v, i, k));
            }
            i = k.max(i + 1);
            continue;
        }
        i += 1;
    }
    q
}

// ---- Layer 2: directive resolution ------------------------------------------

/// One clause's meaning before grounding.
#[derive(Clone, Debug, PartialEq)]
enum Directive {
    /// Egocentric: turn `yaw`, then drive `dist` metres.
    Move {
        yaw: f64,
        dist: f64,
        desc: String,
    },
    /// Allocentric: go to a landmark. `turn_after` is a turn made there
    /// ("turn right at the statue").
    Find {
        phrase: String,
        capital: bool,
        d_s: Option<f64>,
        turn_after: Option<f64>,
    },
    Follow {
        phrase: String,
        capital: bool,
        d_s: Option<f64>,
        duration_s: Option<f64>,
    },
    Return,
    /// A clause the parser does not understand.
    Unknown(String),
    /// A clause that needs a question (e.g. a turn without a side).
    Ask {
        question: String,
        reason: String,
    },
}

fn words(t: &[Token]) -> Vec<&str> {
    t.iter().map(|x| x.w.as_str()).collect()
}

fn has(ws: &[&str], w: &str) -> bool {
    ws.contains(&w)
}

fn has_seq(ws: &[&str], seq: &[&str]) -> Option<usize> {
    ws.windows(seq.len()).position(|win| win == seq)
}

/// Turn side from the clause: +1 left, -1 right, 0 none.
fn side(ws: &[&str]) -> i8 {
    let l = ws.iter().position(|w| {
        matches!(*w, "left" | "counterclockwise" | "anticlockwise" | "counter-clockwise" | "anti-clockwise")
    });
    let r = ws.iter().position(|w| matches!(*w, "right" | "clockwise"));
    match (l, r) {
        (Some(a), Some(b)) => {
            if a < b {
                1
            } else {
                -1
            }
        }
        (Some(_), None) => 1,
        (None, Some(_)) => -1,
        _ => 0,
    }
}

const TURN_WORDS: &[&str] = &["turn", "rotate", "spin", "face", "bear", "veer", "u-turn", "uturn", "pivot"];
const DRIVE_WORDS: &[&str] = &[
    "move",
    "go",
    "drive",
    "walk",
    "head",
    "proceed",
    "advance",
    "continue",
    "keep",
    "travel",
    "roll",
    "forward",
    "forwards",
    "ahead",
    "straight",
    "back",
    "backward",
    "backwards",
    "reverse",
    "come",
];

/// FIND phrases: the target starts after the matched words.
const FIND_CUES: &[&[&str]] = &[
    &["look", "for"],
    &["search", "for"],
    &["find"],
    &["locate"],
    &["go", "to"],
    &["go", "towards"],
    &["go", "toward"],
    &["go", "at"],
    &["go", "near"],
    &["go", "by"],
    &["head", "to"],
    &["head", "towards"],
    &["head", "toward"],
    &["walk", "to"],
    &["walk", "towards"],
    &["drive", "to"],
    &["drive", "towards"],
    &["move", "to"],
    &["move", "towards"],
    &["move", "toward"],
    &["navigate", "to"],
    &["navigate", "towards"],
    &["proceed", "to"],
    &["proceed", "towards"],
    &["get", "to"],
    &["come", "to"],
    &["reach"],
    &["approach"],
    &["visit"],
    &["meet"],
    &["greet"],
    &["go", "up", "to"],
    &["go", "over", "to"],
    &["until", "you", "see"],
    &["until", "you", "reach"],
    &["may", "see"],
    &["will", "see"],
    &["can", "see"],
    &["might", "see"],
    &["should", "see"],
    &["you", "see"],
    &["there", "is"],
    &["there's"],
    &["you'll", "see"],
    &["you'll", "find"],
    &["will", "find"],
    &["spot"],
];
/// Prepositions after "stop" / "park" / "wait" that introduce the landmark.
const STOP_PREPS: &[&str] =
    &["near", "at", "by", "beside", "next", "in", "before", "behind", "close", "from", "of", "to", "nearby"];
/// Words that end a target phrase.
const PHRASE_END: &[&str] = &[
    "to", "and", "which", "that", "who", "so", "then", "until", "for", "from", "with", "on", "at", "near", "by",
    "beside", "behind", "before", "after", "in", "into", "when", "while", "if", "follow", "followed", "follows", "it",
    "there", "please", "is", "are", "was", "standing", "stands", "sitting", "sits", "lies", "lying", "located",
    "placed", "kept",
];
const PARTICIPLES: &[&str] = &["standing", "sitting", "lying", "placed", "kept", "located"];
const DETERMINERS: &[&str] =
    &["the", "a", "an", "some", "this", "that", "my", "your", "our", "his", "her", "their", "any", "one", "its"];

/// The target phrase starting at `start`: determiners dropped, cut at the
/// first word that ends a noun phrase; "spot where X is" → X.
fn phrase_from(t: &[Token], start: usize) -> (String, bool) {
    let mut i = start;
    while i < t.len() && (DETERMINERS.contains(&t[i].w.as_str()) || matches!(t[i].w.as_str(), "to" | "the" | "of")) {
        i += 1;
    }
    // "the spot / place where the bicycle is standing" → "bicycle"
    if i + 1 < t.len()
        && matches!(t[i].w.as_str(), "spot" | "place" | "location" | "point" | "area" | "position" | "part" | "corner")
        && t[i + 1].w == "where"
    {
        i += 2;
        while i < t.len() && DETERMINERS.contains(&t[i].w.as_str()) {
            i += 1;
        }
    }
    // Honorific + name keeps its period: "mr. david".
    let mut out: Vec<&Token> = Vec::new();
    while i < t.len() {
        let w = t[i].w.as_str();
        let is_paren = w.starts_with('(');
        if !is_paren && (PHRASE_END.contains(&w) || matches!(w, "," | "." | ";" | "!" | "?" | ":")) && !out.is_empty() {
            break;
        }
        // Participles open a phrase as adjectives ("the standing person").
        if !is_paren && PHRASE_END.contains(&w) && !PARTICIPLES.contains(&w) {
            break;
        }
        out.push(&t[i]);
        i += 1;
        if out.len() >= 8 {
            break;
        }
    }
    let capital = out.iter().any(|x| x.capital && !HONORIFICS.contains(&x.w.as_str()));
    let text = out.iter().map(|x| x.w.as_str()).collect::<Vec<_>>().join(" ");
    (text, capital)
}

/// A stopping distance stated with the target: "stop 1 m before the chair",
/// "within 2 metres of", "keep 1.5 m behind".
fn stop_distance(t: &[Token], q: &Quantities) -> Option<f64> {
    q.lengths.iter().find_map(|&(v, _, end)| {
        let after = t.get(end).map(|x| x.w.as_str()).unwrap_or("");
        let before = |k: usize| if k == 0 { "" } else { t.get(k - 1).map(|x| x.w.as_str()).unwrap_or("") };
        let (_, start, _) = q.lengths.iter().find(|(_, _, e)| *e == end).copied().unwrap_or((0.0, 0, 0));
        (matches!(after, "before" | "from" | "away" | "behind" | "short" | "of" | "in")
            || matches!(before(start), "within" | "keep" | "at" | "stay" | "distance"))
        .then_some(v)
    })
}

fn turn_magnitude(ws: &[&str], q: &Quantities) -> Option<f64> {
    if let Some(a) = q.angles.first() {
        return Some(*a);
    }
    if ws.iter().any(|w| matches!(*w, "around" | "u-turn" | "uturn")) || has_seq(ws, &["turn", "back"]).is_some() {
        return Some(HALF_TURN);
    }
    if ws.iter().any(|w| matches!(*w, "slightly" | "slight" | "bear" | "veer"))
        || has_seq(ws, &["a", "little", "to", "the"]).is_some()
    {
        return Some(SLIGHT_TURN_RAD);
    }
    if has(ws, "half") && side(ws) != 0 {
        return Some(0.79);
    }
    if side(ws) != 0 {
        return Some(RIGHT_ANGLE);
    }
    None
}

fn resolve(t: &[Token]) -> Vec<Directive> {
    let ws = words(t);
    let q = quantities(t);
    let text = ws.join(" ");

    // RETURN: "go back", "come back", "return", "report back to me", "head home".
    let back_cue = has_seq(&ws, &["go", "back"]).is_some()
        || has_seq(&ws, &["come", "back"]).is_some()
        || has_seq(&ws, &["head", "back"]).is_some()
        || has_seq(&ws, &["get", "back"]).is_some()
        || has_seq(&ws, &["report", "back"]).is_some()
        || has_seq(&ws, &["back", "to", "me"]).is_some()
        || has_seq(&ws, &["back", "to", "start"]).is_some()
        || has_seq(&ws, &["back", "home"]).is_some()
        || has(&ws, "return")
        || has_seq(&ws, &["come", "to", "me"]).is_some()
        || has_seq(&ws, &["report", "to", "me"]).is_some();
    let distance_given = !q.lengths.is_empty() || !q.bare.is_empty();
    if back_cue && !distance_given && !ws.iter().any(|w| matches!(*w, "turn" | "rotate")) {
        return vec![Directive::Return];
    }

    // Object retrieval and delivery: "bring a water bottle (from the kitchen)" → FIND, RETURN.
    for cue in ["bring", "fetch", "grab"] {
        if let Some(i) = ws.iter().position(|w| *w == cue) {
            let mut s = i + 1;
            if matches!(ws.get(s), Some(&"me") | Some(&"us")) {
                s += 1;
            }
            let (phrase, capital) = phrase_from(t, s);
            if phrase.is_empty() {
                return vec![Directive::Unknown(text)];
            }
            return vec![Directive::Find { phrase, capital, d_s: None, turn_after: None }, Directive::Return];
        }
    }
    if let Some(i) = ws.iter().position(|w| matches!(*w, "deliver" | "give" | "hand" | "take" | "carry"))
        && !ws.iter().any(|w| matches!(*w, "turn" | "left" | "right" | "u-turn"))
        && let Some(to) = ws[i..].iter().position(|w| *w == "to").map(|k| k + i)
    {
        let (phrase, capital) = phrase_from(t, to + 1);
        if !phrase.is_empty() && phrase != "me" {
            return vec![Directive::Find { phrase, capital, d_s: None, turn_after: None }];
        }
    }

    // FOLLOW: "follow the person for 30 seconds"; "you may see X … follow it" is a FIND of X.
    if let Some(i) = ws.iter().position(|w| *w == "follow") {
        let (phrase, capital) = phrase_from(t, i + 1);
        let pronoun = phrase.is_empty()
            || matches!(ws.get(i + 1), Some(&"it") | Some(&"that") | Some(&"them") | Some(&"him") | Some(&"her"));
        if !pronoun {
            return vec![Directive::Follow {
                phrase,
                capital,
                d_s: stop_distance(t, &q),
                duration_s: q.durations.first().copied(),
            }];
        }
        if !FIND_CUES.iter().any(|c| has_seq(&ws, c).is_some()) {
            return vec![Directive::Ask {
                question: "What should I follow?".into(),
                reason: format!("\"{text}\" does not say what to follow"),
            }];
        }
    }

    // "stop / park / wait near the statue"
    if let Some(i) = ws.iter().position(|w| matches!(*w, "stop" | "park" | "halt" | "wait"))
        && let Some(p) = ws[i + 1..].iter().position(|w| STOP_PREPS.contains(w)).map(|k| k + i + 1)
    {
        let mut s = p + 1;
        while matches!(ws.get(s), Some(&"to") | Some(&"of") | Some(&"front")) {
            s += 1;
        }
        let (phrase, capital) = phrase_from(t, s);
        if !phrase.is_empty() {
            return vec![Directive::Find { phrase, capital, d_s: stop_distance(t, &q), turn_after: None }];
        }
    }

    // "turn right at the statue": go to the landmark, then turn there.
    let turning = ws.iter().any(|w| TURN_WORDS.contains(w)) || has_seq(&ws, &["take", "a"]).is_some() && side(&ws) != 0;
    if turning && let Some(at) = ws.iter().position(|w| *w == "at") {
        let (phrase, capital) = phrase_from(t, at + 1);
        if !phrase.is_empty() && !matches!(phrase.as_str(), "left" | "right") {
            let mag = turn_magnitude(&ws, &q).unwrap_or(RIGHT_ANGLE);
            let s = side(&ws);
            let yaw = if mag >= HALF_TURN { HALF_TURN } else { mag * s as f64 };
            return vec![Directive::Find { phrase, capital, d_s: None, turn_after: (yaw != 0.0).then_some(yaw) }];
        }
    }

    // Allocentric cues: "find X", "go to X", "you may see X".
    let mut best: Option<(usize, usize)> = None;
    for cue in FIND_CUES {
        if let Some(p) = has_seq(&ws, cue)
            && best.is_none_or(|(bp, _)| p < bp)
        {
            best = Some((p, p + cue.len()));
        }
    }
    if let Some((_, start)) = best {
        let next = ws.get(start).copied().unwrap_or("");
        let directional = matches!(next, "left" | "right" | "the")
            && matches!(ws.get(start + 1).copied().unwrap_or(next), "left" | "right");
        if !directional && !matches!(next, "left" | "right") {
            let (phrase, capital) = phrase_from(t, start);
            if !phrase.is_empty() && length_unit(&phrase).is_none() {
                return vec![Directive::Find { phrase, capital, d_s: stop_distance(t, &q), turn_after: None }];
            }
        }
    }

    // Egocentric: turns and drives.
    let drives = ws.iter().any(|w| DRIVE_WORDS.contains(w));
    let turn_cue =
        ws.iter().any(|w| TURN_WORDS.contains(w)) || (has(&ws, "take") || has(&ws, "make")) && side(&ws) != 0;
    if turn_cue || drives || !q.lengths.is_empty() {
        let s = side(&ws);
        let backwards = ws.iter().any(|w| matches!(*w, "back" | "backward" | "backwards" | "reverse")) && !turn_cue;
        let mut dist = q.lengths.iter().map(|x| x.0).sum::<f64>();
        if dist == 0.0
            && let Some(&(v, _, _)) = q.bare.first()
            && q.angles.is_empty()
        {
            dist = v;
        }
        let vague_far = ws.iter().any(|w| matches!(*w, "far")) || has_seq(&ws, &["long", "way"]).is_some();
        // A drive word without a distance: "move a little ahead", "go straight".
        let pure_turn = turn_cue
            && !ws.iter().any(|w| {
                matches!(
                    *w,
                    "move"
                        | "go"
                        | "drive"
                        | "walk"
                        | "proceed"
                        | "advance"
                        | "ahead"
                        | "forward"
                        | "forwards"
                        | "straight"
                        | "continue"
                        | "keep"
                )
            });
        if dist == 0.0 && !pure_turn && !turn_cue {
            // "a little" and an unqualified drive both take the short default.
            dist = if vague_far { VAGUE_FAR_M } else { VAGUE_SHORT_M };
        }
        if dist == 0.0 && turn_cue && !pure_turn {
            // "turn left and go" in one clause with no distance.
            dist = if vague_far { VAGUE_FAR_M } else { VAGUE_SHORT_M };
        }
        let yaw = if backwards {
            HALF_TURN
        } else if turn_cue || s != 0 {
            match turn_magnitude(&ws, &q) {
                Some(m) if m >= HALF_TURN - 0.005 && s == 0 => HALF_TURN,
                Some(m) if s != 0 => wrap(m * s as f64),
                Some(_) => {
                    return vec![Directive::Ask {
                        question: "Which way should I turn, left or right?".into(),
                        reason: format!("\"{text}\" gives an angle but no side"),
                    }];
                }
                None if turn_cue && ws.iter().any(|w| matches!(*w, "turn" | "rotate")) && dist == 0.0 => {
                    return vec![Directive::Ask {
                        question: "Which way should I turn, left or right?".into(),
                        reason: format!("\"{text}\" does not say which way to turn"),
                    }];
                }
                None => 0.0,
            }
        } else {
            0.0
        };
        if dist == 0.0 && yaw == 0.0 {
            return vec![Directive::Unknown(text)];
        }
        return vec![Directive::Move { yaw: round2(yaw), dist: round2(dist), desc: text }];
    }

    // Nothing recognised: only filler is allowed to be ignored.
    if ws.iter().all(|w| FILLER.contains(w) || w.chars().all(|c| !c.is_alphanumeric())) {
        return Vec::new();
    }
    vec![Directive::Unknown(text)]
}

fn wrap(a: f64) -> f64 {
    let mut a = a % (2.0 * std::f64::consts::PI);
    if a > std::f64::consts::PI + 1e-9 {
        a -= 2.0 * std::f64::consts::PI;
    } else if a < -std::f64::consts::PI - 1e-9 {
        a += 2.0 * std::f64::consts::PI;
    }
    // π stays π as the paper writes it.
    if (a.abs() - std::f64::consts::PI).abs() < 0.005 { HALF_TURN } else { a }
}

fn round2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

// ---- Layer 3: grounding ------------------------------------------------------

/// Splits "mr. david" into an identity; a single capitalised word that is
/// not a class ("find David") is a name too.
fn person_identity(phrase: &str, capital: bool) -> Option<String> {
    let ws: Vec<&str> = phrase.split_whitespace().collect();
    if ws.len() >= 2 && HONORIFICS.contains(&ws[0]) {
        let name = ws[1..].join(" ");
        let name: String =
            name.chars().filter(|c| c.is_ascii_alphabetic() || matches!(c, ' ' | '\'' | '-' | '.')).collect();
        let name = name.trim_matches(['.', ' ']).to_string();
        return (!name.is_empty()).then_some(name);
    }
    if capital
        && ws.len() == 1
        && crate::grounding::lexical(ws[0]).is_none()
        && ws[0].chars().all(|c| c.is_ascii_alphabetic())
    {
        return Some(ws[0].to_string());
    }
    None
}

enum Ground {
    Class { class_id: i32, person: Option<String>, note: Option<String> },
    Unknown(Ungrounded),
}

fn ground_target(g: &Grounder, phrase: &str, capital: bool) -> Ground {
    if let Some(name) = person_identity(phrase, capital) {
        return Ground::Class { class_id: 0, person: Some(name), note: None };
    }
    match g.ground(phrase) {
        Ok(found) => {
            let note = match found.via {
                Via::Lexical(_) => None,
                Via::Semantic { matched, score } => Some(format!(
                    "grounded \"{phrase}\" to {} (id {}) by similarity to \"{matched}\" ({score:.2})",
                    vlnav_proto::coco::CLASSES[found.class_id as usize],
                    found.class_id
                )),
            };
            Ground::Class { class_id: found.class_id, person: None, note }
        }
        Err(u) => Ground::Unknown(u),
    }
}

/// A FIND or FOLLOW step for a grounded target, or the question to ask.
fn target_step(
    grounder: &Grounder,
    action: Action,
    phrase: String,
    capital: bool,
    d_s: Option<f64>,
    notes: &mut Vec<String>,
) -> Result<Step, Parsed> {
    match ground_target(grounder, &phrase, capital) {
        Ground::Unknown(u) => Err(Parsed::ask(
            format!("I don't know what \"{}\" looks like. Which object should I look for?", u.phrase),
            format!("cannot ground \"{}\" to a COCO-80 class", u.phrase),
            u.suggestions,
            Vec::new(),
        )),
        Ground::Class { class_id, person, note } => {
            notes.extend(note);
            let mut step = Step { target: phrase, class_id, person, ..Step::blank(action) };
            if let Some(d) = d_s {
                if !(0.0..=5.0).contains(&d) {
                    return Err(Parsed::ask(
                        "How close should I stop? I can stop between 0 and 5 m from a target.",
                        format!("stopping distance {d} m is out of range"),
                        vec![],
                        Vec::new(),
                    ));
                }
                step.d_s = Some(round2(d));
            }
            Ok(step)
        }
    }
}

/// Share of letters outside ASCII: a rough "is this English" test.
fn non_latin_share(text: &str) -> f64 {
    let letters: Vec<char> = text.chars().filter(|c| c.is_alphabetic()).collect();
    if letters.is_empty() {
        return 0.0;
    }
    letters.iter().filter(|c| !c.is_ascii()).count() as f64 / letters.len() as f64
}

/// The rule-based planner.
pub fn parse(text: &str, grounder: &Grounder) -> Parsed {
    let parsed = parse_unchecked(text, grounder);
    // The parser never hands on a plan the validator would refuse: whatever
    // slipped through the layers (a name made of junk, a step of nothing)
    // becomes a question.
    static VALIDATOR: std::sync::OnceLock<crate::validate::Validator> = std::sync::OnceLock::new();
    if let Outcome::Plan(plan) = &parsed.outcome
        && let Err(errors) = VALIDATOR.get_or_init(crate::validate::Validator::new).validate_plan(plan)
    {
        return Parsed::ask(
            "I could not make a safe plan from that. Could you say it more simply?",
            errors.join("; "),
            vec![],
            parsed.notes,
        );
    }
    parsed
}

fn parse_unchecked(text: &str, grounder: &Grounder) -> Parsed {
    let mut notes = Vec::new();
    if non_latin_share(text) > 0.3 {
        return Parsed::ask(
            "I only understand instructions in English. Could you say it in English?",
            "the instruction is not in English",
            vec![],
            notes,
        );
    }
    if !text.chars().any(|c| c.is_ascii_alphabetic()) {
        return Parsed::ask(
            "I did not understand that. What should I do?",
            "the instruction has no words",
            vec!["move 2 m ahead".into(), "find the chair".into(), "go back".into()],
            notes,
        );
    }
    let tokens = tokenize(text);
    let mut directives = Vec::new();
    for clause in clauses(&tokens) {
        directives.extend(resolve(&clause));
    }
    let mut steps: Vec<Step> = Vec::new();
    for d in directives {
        match d {
            Directive::Unknown(clause) => {
                return Parsed::ask(
                    format!(
                        "I did not understand \"{clause}\". Could you rephrase it as a move, a place to find, a person to follow, or \"go back\"?"
                    ),
                    format!("no action recognised in \"{clause}\""),
                    vec![],
                    notes,
                );
            }
            Directive::Ask { question, reason } => return Parsed::ask(question, reason, vec![], notes),
            Directive::Return => steps.push(Step::go_back("return to the start")),
            Directive::Move { yaw, dist, desc } => {
                if dist > MAX_SPLIT_M {
                    return Parsed::ask(
                        format!(
                            "That is {dist} m. I can drive at most {MAX_SPLIT_M} m in one instruction; how far should I go?"
                        ),
                        format!("distance {dist} m in \"{desc}\" is too far"),
                        vec![],
                        notes,
                    );
                }
                if dist.abs() < 0.1 && yaw.abs() < 0.01 {
                    // Under 10 cm and no turn: nothing the robot can execute.
                    return Parsed::ask(
                        format!("\"{desc}\" is less than 10 cm. How far should I move?"),
                        format!("\"{desc}\" neither turns nor drives"),
                        vec![],
                        notes,
                    );
                }
                if dist > 0.0
                    && yaw == 0.0
                    && let Some(prev) = steps.last_mut()
                    && prev.action == Action::Move
                    && prev.f_dist == 0.0
                {
                    // A pure turn then a pure drive: one MOVE turns, then drives.
                    prev.f_dist = dist;
                    prev.desc = format!("{}, {}", prev.desc, desc);
                    continue;
                }
                steps.push(Step::moving(desc, dist, yaw));
            }
            Directive::Find { phrase, capital, d_s, turn_after } => {
                match target_step(grounder, Action::Find, phrase, capital, d_s, &mut notes) {
                    Ok(step) => steps.push(step),
                    Err(ask) => return ask.with_notes(notes),
                }
                if let Some(yaw) = turn_after {
                    steps.push(Step::moving(
                        format!("turn {} at the landmark", if yaw > 0.0 { "left" } else { "right" }),
                        0.0,
                        round2(yaw),
                    ));
                }
            }
            Directive::Follow { phrase, capital, d_s, duration_s } => {
                match target_step(grounder, Action::Follow, phrase, capital, d_s, &mut notes) {
                    Ok(mut step) => {
                        if let Some(t) = duration_s {
                            if !(0.0..=3600.0).contains(&t) {
                                return Parsed::ask(
                                    "For how long should I follow? At most one hour.",
                                    format!("follow duration {t} s is out of range"),
                                    vec![],
                                    notes,
                                );
                            }
                            step.duration_s = Some(t);
                        }
                        steps.push(step);
                    }
                    Err(ask) => return ask.with_notes(notes),
                }
            }
        }
    }
    if steps.is_empty() {
        return Parsed::ask(
            "What should I do? I can move, find an object or a person, follow someone, or go back.",
            "the instruction holds no action",
            vec![],
            notes,
        );
    }
    // Count moves as the validator will split them (≤ 10 m each).
    let expanded: usize =
        steps
            .iter()
            .map(|s| {
                if s.action == Action::Move { ((s.f_dist / crate::plan::MAX_STEP_M).ceil() as usize).max(1) } else { 1 }
            })
            .sum();
    if expanded > crate::plan::MAX_STEPS {
        return Parsed::ask(
            format!(
                "That is {expanded} steps; I can plan at most {} at once. Could you split the instruction?",
                crate::plan::MAX_STEPS
            ),
            "too many steps",
            vec![],
            notes,
        );
    }
    Parsed { outcome: Outcome::Plan(Plan::new(steps)), notes, ungrounded: Vec::new() }
}
