//! The embedded default planner: a deterministic HTN parser in the paper's
//! three layers.
//!
//! 1. **Lexical primitives** — the instruction is tokenised (numbers, units,
//!    honorifics and parentheses kept whole), verb forms reduced ("finding"
//!    → "find"), misspelt keywords corrected ("trun" → "turn", see
//!    [`crate::typo`]), and split into clauses at punctuation and connectives
//!    ("then", "and", "but", "after that", "finally"; not the "and" inside
//!    "one and a half"). Filler and politeness are dropped.
//! 2. **Directive resolution** — each clause resolves into an egocentric
//!    branch (turn direction and angle, distance), an allocentric branch (a
//!    landmark phrase after a FIND verb or a travel verb with a destination:
//!    "head over to", "make your way to"), FOLLOW or RETURN. A clause without
//!    a verb is read with the one before it (ellipsis: "find the chair, then
//!    the table", "move 2 m, then 3 more", "turn left, then left again").
//!    "It", "him", "there" refer to the last target: "follow it" follows a
//!    dog, and after a chair means going to it (the paper's example), which
//!    the FIND does. A relation after a target ("the chair next to the
//!    table", "the cup is on the table") is kept as a hint (`ref`) on its
//!    FIND step. Negated clauses ("don't go near the cables", "without …")
//!    and remarks plan nothing; "no, …" takes back the clause before it.
//! 3. **Grounding and composition** — numbers and units become metres and
//!    radians, landmark phrases COCO-80 ids through the [`Grounder`] (a
//!    misspelt class word is corrected when nothing grounds), person names
//!    identities. Consecutive turns and drives compose into one MOVE (a turn,
//!    then a drive; "then 2 more metres" adds up); the validator then splits
//!    drives over 10 m into ≤ 10 m subgoals. A place no class covers (a room
//!    name) is reported in the answer and skipped when a detectable target
//!    follows it directly; otherwise the steps after it depend on it, and the
//!    parser asks rather than guesses. So does an action it cannot read, a
//!    pronoun with nothing before it, or a turn without a side.
//!
//! Documented defaults for vague language:
//! - "a little / a bit / slightly ahead", or a drive with no distance: [`VAGUE_SHORT_M`] (the paper's 2.5 m);
//! - "a few metres": 3 m; "a couple of metres": 2 m; "far / a long way": [`VAGUE_FAR_M`];
//! - "a step": [`STEP_M`] per step; "a bit more" after a drive: another [`VAGUE_SHORT_M`];
//! - a plain left/right turn: ±1.57 rad; "slightly / bear / veer", "turn left a bit": ±[`SLIGHT_TURN_RAD`]; "half left": ±0.79;
//!   "around / U-turn / about-turn": 3.14; "twice" doubles a turn; a number with no unit in a drive: metres;
//! - "go back N m", "reverse N m", "back up N m": turn around (3.14) and drive N m, so the camera faces the way
//!   it drives.
//!
//! Yaw values are rounded to 0.01 rad and distances to 0.01 m.

use crate::grounding::{Grounder, Ungrounded, Via};
use crate::plan::{Action, Clarification, MAX_INSTRUCTION_BYTES, Outcome, Plan, Reference, Step};
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
    /// The word as tokenised, before verb forms and misspellings were
    /// normalised: what a plan step quotes as its source.
    raw: String,
}

impl Token {
    fn new(w: String, capital: bool) -> Token {
        Token { raw: w.clone(), w, capital }
    }
}

/// The words of `t` as the person said them (lower case).
fn spoken(t: &[Token]) -> String {
    t.iter().map(|x| x.raw.as_str()).collect::<Vec<_>>().join(" ")
}

/// Titles before a name; the spelled-out forms are what speech recognition writes.
const HONORIFICS: &[&str] = &[
    "mr.", "mrs.", "ms.", "dr.", "mr", "mrs", "ms", "dr", "miss", "sir", "madam", "prof.", "prof", "mister", "missus",
];

fn tokenize(text: &str) -> Vec<Token> {
    let text = text.replace(['\u{2019}', '\u{2018}'], "'").replace(['\u{201c}', '\u{201d}'], "\"").replace('°', " ° ");
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
    // "60°": read as degrees, quoted as said.
    if raw == "°" {
        out.push(Token { w: "degrees".into(), capital: false, raw: raw.into() });
        return;
    }
    // A capital that only starts a sentence says nothing about a name.
    let sentence_start = out.last().is_none_or(|t| matches!(t.w.as_str(), "." | "!" | "?"));
    let capital = raw.chars().next().is_some_and(char::is_uppercase) && !sentence_start;
    let mut w = raw.to_lowercase();
    if w.starts_with('(') {
        // A parenthesis stays one token and attaches to the phrase before it.
        let end = w.rfind(')').map(|i| i + 1).unwrap_or(w.len());
        let rest = w[end..].to_string();
        w.truncate(end);
        out.push(Token::new(w, capital));
        for c in rest.chars().filter(|c| matches!(c, ',' | '.' | ';' | '!' | '?' | ':')) {
            out.push(Token::new(c.to_string(), false));
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
        out.push(Token::new(t, false));
    }
}

/// "4m" → "4" "m", "2.5meters" → "2.5" "meters", "90deg" → "90" "deg";
/// "twenty-five" → "twenty" "five".
fn split_number_unit(out: &mut Vec<Token>, w: &str, capital: bool) {
    let digits = w.chars().take_while(|c| c.is_ascii_digit() || *c == '.').count();
    if digits > 0 && digits < w.len() && w[..digits].chars().any(|c| c.is_ascii_digit()) {
        let unit = &w[digits..];
        if unit.chars().all(|c| c.is_ascii_alphabetic()) {
            out.push(Token::new(w[..digits].to_string(), false));
            out.push(Token::new(unit.to_string(), false));
            return;
        }
    }
    if w.contains('-') && w.split('-').all(|p| word_number(p).is_some()) {
        for p in w.split('-') {
            out.push(Token::new(p.to_string(), capital));
        }
        return;
    }
    out.push(Token::new(w.to_string(), capital));
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
    "should",
    "you",
    "i",
    "i'd",
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
    "um",
    "umm",
    "uh",
    "uhm",
    "er",
    "erm",
    "hmm",
    "like",
    "basically",
    "let's",
    "yes",
    "yeah",
];

/// The base form of verb forms the parser reads ("finding" → "find").
fn base_verb(w: &str) -> Option<&'static str> {
    Some(match w {
        "finding" | "finds" => "find",
        "following" | "follows" => "follow",
        "going" | "goes" => "go",
        "turning" | "turns" => "turn",
        "moving" | "moves" => "move",
        "heading" => "head",
        "walking" => "walk",
        "driving" => "drive",
        "looking" => "look",
        "searching" => "search",
        "approaching" => "approach",
        "coming" => "come",
        "getting" => "get",
        "bringing" => "bring",
        "fetching" => "fetch",
        "rotating" => "rotate",
        "returning" => "return",
        "navigating" => "navigate",
        "proceeding" => "proceed",
        "locating" => "locate",
        "visiting" => "visit",
        "reaching" => "reach",
        "spinning" => "spin",
        "found" => "find",
        "reached" => "reach",
        "turned" => "turn",
        "gone" | "went" => "go",
        "seen" => "see",
        "spotted" => "spot",
        "arrived" | "arriving" | "arrives" => "arrive",
        "dont" | "do't" => "don't",
        _ => return None,
    })
}

/// Common words that are never corrected as misspellings of a keyword
/// ("let" is one letter from "left", "mind" from "find").
const NOT_TYPOS: &[&str] = &[
    "let", "me", "us", "do", "does", "did", "be", "been", "is", "are", "was", "were", "its", "this", "what", "who",
    "why", "how", "lost", "see", "saw", "like", "think", "guess", "mind", "kind", "able", "very", "much", "lot",
    "lots", "excuse", "sorry", "mean", "not", "never", "avoid", "stay", "away", "usual", "thing", "things", "yes",
    "no", "favour", "favor", "wait", "hit", "bump", "touch", "red", "blue", "green", "tall", "big", "small", "room",
    "door", "wall", "floor", "stairs", "file", "base", "lab", "bit", "more", "once", "twice", "must", "might", "may",
    "hall", "list", "fast", "slow", "sure", "help", "hold", "last", "fine", "one", "ones", "our", "all", "any", "some",
    "much", "many", "else", "told", "tell", "said", "say", "ask", "got", "put", "set", "let's",
];

/// Direction, unit and action words beyond the lists above.
const KEYWORDS: &[&str] = &[
    "left",
    "right",
    "around",
    "forward",
    "forwards",
    "backward",
    "backwards",
    "back",
    "ahead",
    "straight",
    "degrees",
    "degree",
    "radians",
    "radian",
    "meters",
    "metres",
    "meter",
    "metre",
    "centimeters",
    "centimetres",
    "feet",
    "foot",
    "inches",
    "yards",
    "seconds",
    "minutes",
    "return",
    "follow",
    "again",
    "another",
    "further",
    "until",
    "where",
    "slightly",
    "little",
    "couple",
    "half",
    "about",
    "front",
    "clockwise",
    "counterclockwise",
    "anticlockwise",
    "spot",
    "place",
    "start",
    "bring",
    "fetch",
    "deliver",
    "report",
    "stop",
    "park",
    "home",
    "hundred",
    "point",
    "yourself",
];

/// The parser's own words, the vocabulary keyword misspellings are corrected to.
fn keyword_vocabulary() -> &'static [&'static str] {
    static VOCAB: std::sync::OnceLock<Vec<&'static str>> = std::sync::OnceLock::new();
    VOCAB.get_or_init(|| {
        let mut v: Vec<&'static str> = Vec::new();
        for list in [
            FILLER,
            TURN_WORDS,
            DRIVE_WORDS,
            TRAVEL_VERBS,
            PARTICLES,
            FIND_VERBS,
            STOP_PREPS,
            PHRASE_END,
            DETERMINERS,
            NEGATIONS,
            SIDE_PHRASE_WORDS,
            KEYWORDS,
        ] {
            v.extend_from_slice(list);
        }
        v.extend(vlnav_words::all());
        v.sort_unstable();
        v.dedup();
        v
    })
}

/// Verb forms to their base, misspelt keywords corrected (not capitalised
/// words after the first: names stay as spoken; not class names).
fn normalise(tokens: Vec<Token>, notes: &mut Vec<String>) -> Vec<Token> {
    let vocab = keyword_vocabulary();
    tokens
        .into_iter()
        .enumerate()
        .map(|(i, mut t)| {
            if let Some(b) = base_verb(&t.w) {
                t.w = b.to_string();
            } else if (i == 0 || !t.capital)
                && !NOT_TYPOS.contains(&t.w.as_str())
                && crate::grounding::lexical(&t.w).is_none()
                && let Some(fixed) = crate::typo::correct(&t.w, vocab, false)
            {
                notes.push(format!("read \"{}\" as \"{fixed}\"", t.w));
                t.w = fixed.to_string();
            }
            t
        })
        .collect()
}

/// Whether "and" at `i` joins two clauses rather than parts of a number
/// ("one and a half", "a hundred and eighty").
fn and_joins_clauses(tokens: &[Token], i: usize) -> bool {
    let w = |k: usize| tokens.get(k).map(|t| t.w.as_str()).unwrap_or("");
    let next = w(i + 1);
    let prev = if i == 0 { "" } else { w(i - 1) };
    !(next == "half" || (next == "a" && w(i + 2) == "half") || (prev == "hundred" && word_number(next).is_some()))
}

/// Splits the instruction into clauses at punctuation and connectives
/// ("then", "and", "but", "after that", "finally"); "without …" starts a
/// clause of its own (a constraint, see [`NEGATIONS`]).
fn clauses(tokens: &[Token]) -> Vec<Vec<Token>> {
    let mut out: Vec<Vec<Token>> = vec![Vec::new()];
    let mut i = 0;
    while i < tokens.len() {
        let t = &tokens[i];
        let next = tokens.get(i + 1).map(|t| t.w.as_str());
        let boundary = matches!(
            t.w.as_str(),
            "," | "." | ";" | "!" | "?" | ":" | "then" | "finally" | "afterwards" | "lastly" | "but"
        ) || (t.w == "after" && next == Some("that"))
            || (t.w == "and" && and_joins_clauses(tokens, i));
        if t.w == "without" {
            out.push(vec![t.clone()]);
        } else if boundary {
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
        let only_side = clause.len() > 1
            && clause.iter().any(|t| matches!(t.w.as_str(), "left" | "right"))
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

/// Ways of saying "follow" with a person: "stay with her", "accompany Maria",
/// "go with Peter", "keep up with the child".
const FOLLOW_PHRASES: &[&[&str]] = &[
    &["keep", "up", "with"],
    &["tag", "along", "with"],
    &["stay", "close", "to"],
    &["stay", "with"],
    &["go", "with"],
    &["come", "with"],
    &["walk", "with"],
    &["stick", "with"],
    &["accompany"],
];

/// Rewrites the phrases of [`FOLLOW_PHRASES`] to "follow" (the source keeps the words said).
fn rewrite_follow(tokens: Vec<Token>) -> Vec<Token> {
    let mut out: Vec<Token> = Vec::with_capacity(tokens.len());
    let mut i = 0;
    while i < tokens.len() {
        let ws: Vec<&str> = tokens[i..].iter().take(3).map(|t| t.w.as_str()).collect();
        if let Some(p) = FOLLOW_PHRASES.iter().find(|p| ws.starts_with(p)) {
            let raw = tokens[i..i + p.len()].iter().map(|t| t.raw.as_str()).collect::<Vec<_>>().join(" ");
            out.push(Token { w: "follow".into(), capital: false, raw });
            i += p.len();
            continue;
        }
        out.push(tokens[i].clone());
        i += 1;
    }
    out
}

/// Verbs that start a new instruction in run-on speech ("go forward 5 m turn
/// left", "find the dog follow it").
const RUNON_VERBS: &[&str] =
    &["go", "turn", "move", "find", "follow", "come", "drive", "walk", "return", "rotate", "spin", "locate", "search"];

/// Words after which a verb continues the same instruction ("go find", "to turn", "you go").
fn continues_before_verb(w: &str) -> bool {
    FILLER.contains(&w)
        || DETERMINERS.contains(&w)
        || TURN_WORDS.contains(&w)
        || DRIVE_WORDS.contains(&w)
            && !matches!(w, "forward" | "forwards" | "ahead" | "straight" | "back" | "backward" | "backwards")
        || TRAVEL_VERBS.contains(&w)
        || FIND_VERBS.contains(&w)
        || NEGATIONS.contains(&w)
        || matches!(
            w,
            "me" | "us"
                | "let"
                | "we"
                | "don't"
                | "not"
                | "mind"
                | "may"
                | "might"
                | "must"
                | "please"
                | "and"
                | "or"
                | "to"
                | "look"
                | "who"
                | "which"
                | "where"
                | "when"
                | "once"
                | "before"
                | "after"
                | "if"
                | "lets"
                | "gonna"
                | "wanna"
                | "will"
                | "shall"
                | "did"
                | "do"
                | "does"
                | "be"
                | "who's"
                | "by"
                | "as"
                | "until"
        )
}

/// Splits run-on speech at a verb that follows a finished instruction.
fn split_runon(clause: Vec<Token>) -> Vec<Vec<Token>> {
    let mut out = vec![Vec::new()];
    for (i, t) in clause.iter().enumerate() {
        let starts = i > 0
            && RUNON_VERBS.contains(&t.w.as_str())
            && !continues_before_verb(&clause[i - 1].w)
            && !noun_turn(&clause, i)
            && clause.get(i + 1).is_none_or(|n| !matches!(n.w.as_str(), "sign" | "light" | "lights"));
        if starts && out.last().is_some_and(|c| !c.is_empty()) {
            out.push(Vec::new());
        }
        if let Some(last) = out.last_mut() {
            last.push(t.clone());
        }
    }
    out
}

/// "turn" as a noun: "take a right turn", "make a sharp left turn" (but
/// "… on the right turn left" starts a new instruction).
fn noun_turn(t: &[Token], i: usize) -> bool {
    t[i].w == "turn"
        && i > 0
        && matches!(
            t[i - 1].w.as_str(),
            "left"
                | "right"
                | "sharp"
                | "slight"
                | "quick"
                | "full"
                | "hard"
                | "quarter"
                | "half"
                | "u"
                | "gentle"
                | "small"
                | "little"
                | "wide"
                | "tight"
        )
        && t.get(i + 1).is_none_or(|n| !matches!(n.w.as_str(), "left" | "right" | "around" | "back" | "round"))
}

/// Words that begin a time clause: "before you …", "after turning …", "once you have …".
fn subordinator(t: &[Token], k: usize) -> Option<&'static str> {
    let w = |j: usize| t.get(j).map(|x| x.w.as_str()).unwrap_or("");
    let kind = match w(k) {
        "before" => "before",
        "after" => "after",
        "once" => "after",
        "when" | "whenever" => "after",
        "as" if w(k + 1) == "soon" && w(k + 2) == "as" => "after",
        _ => return None,
    };
    let next = if w(k) == "as" { w(k + 3) } else { w(k + 1) };
    let verb_next = |x: &str| {
        TURN_WORDS.contains(&x)
            || DRIVE_WORDS.contains(&x)
            || TRAVEL_VERBS.contains(&x)
            || FIND_VERBS.contains(&x)
            || matches!(x, "follow" | "return" | "having")
    };
    (matches!(next, "you" | "you've" | "you're" | "we" | "we've" | "i" | "i've") || verb_next(next)).then_some(kind)
}

/// Drops a time clause's opening words: "once you have found the dog" → "found the dog".
fn strip_subordinator(t: &[Token]) -> Vec<Token> {
    let mut i = 0;
    let w = |j: usize| t.get(j).map(|x| x.w.as_str()).unwrap_or("");
    if w(0) == "as" && w(1) == "soon" && w(2) == "as" {
        i = 3;
    } else if matches!(w(0), "before" | "after" | "once" | "when" | "whenever" | "first") {
        i = 1;
    }
    while matches!(
        w(i),
        "you" | "you've" | "you're" | "we" | "we've" | "i" | "i've" | "have" | "had" | "having" | "are" | "that" | "do"
    ) {
        i += 1;
    }
    t[i.min(t.len())..].to_vec()
}

/// Puts clauses in the order of the events they describe: "before you go to A,
/// find B" → B, A; "go to A but first find B" → B, A; "find A after you reach
/// B" → B, A; "after …", "once …", "when …" at the start already are. Run-on
/// speech is split at each new instruction's verb first.
fn order_events(clauses: Vec<Vec<Token>>, notes: &mut Vec<String>) -> Vec<Vec<Token>> {
    let mut pieces: Vec<Vec<Token>> = Vec::new();
    let mut priority: Vec<bool> = Vec::new();
    for clause in clauses {
        let initial_prior = matches!(clause.first().map(|t| t.w.as_str()), Some("first"))
            || matches!(words(&clause).as_slice(), ["before", "that", ..]);
        let initial_before = subordinator(&clause, 0) == Some("before");
        // A time clause inside: "find the laptop after you go to the desk".
        let mut main = clause.clone();
        let mut sub: Option<(Vec<Token>, &'static str)> = None;
        if let Some(k) = (1..clause.len()).find(|&k| subordinator(&clause, k).is_some()) {
            let kind = subordinator(&clause, k).unwrap_or("after");
            main = clause[..k].to_vec();
            sub = Some((clause[k..].to_vec(), kind));
        }
        let mut parts: Vec<(Vec<Token>, bool)> = Vec::new();
        parts.extend(split_runon(main).into_iter().map(|r| (r, false)));
        // "before you go to the chair find the bottle": the chair comes after.
        if initial_before && parts.len() > 1 {
            notes.push("\"before …\": planned in the order of events".into());
            let first = parts.remove(0);
            parts.push(first);
        }
        if let Some((sub, kind)) = sub {
            let runs = split_runon(sub);
            if kind == "after" {
                notes.push("\"after / once / when …\": planned in the order of events".into());
                for (j, r) in runs.into_iter().enumerate() {
                    parts.insert(j, (r, false));
                }
            } else {
                parts.extend(runs.into_iter().map(|r| (r, false)));
            }
        }
        if initial_prior
            && !pieces.is_empty()
            && !initial_before
            && let Some(p) = parts.first_mut()
        {
            p.1 = true;
        }
        for (p, prior) in parts {
            pieces.push(p);
            priority.push(prior);
        }
    }
    // "X but first Y", "X, but before that Y": Y moves before X.
    let mut out: Vec<Vec<Token>> = Vec::new();
    for (p, prior) in pieces.into_iter().zip(priority) {
        let p = if subordinator(&p, 0).is_some() || matches!(p.first().map(|t| t.w.as_str()), Some("first")) {
            strip_subordinator(&p)
        } else if matches!(words(&p).as_slice(), ["before", "that", ..]) {
            p[2..].to_vec()
        } else {
            p
        };
        if p.is_empty() {
            continue;
        }
        if prior && !out.is_empty() {
            notes.push("\"but first / before that …\": planned before the clause it follows".into());
            let at = out.len() - 1;
            out.insert(at, p);
        } else {
            out.push(p);
        }
    }
    out
}

/// Words of a side phrase that is not a clause by itself ("on your left").
const SIDE_PHRASE_WORDS: &[&str] =
    &["on", "in", "to", "at", "your", "the", "my", "left", "right", "hand", "side", "left-hand", "right-hand"];

/// Words that make a clause a constraint or a retraction, not a step:
/// "don't go near the cables", "without touching the plant", "never mind".
const NEGATIONS: &[&str] = &["don't", "not", "never", "avoid", "without", "shouldn't", "mustn't", "cannot"];
// ---- numbers and units ------------------------------------------------------

/// A number word's value (`vlnav_words`: 0 to 19, and tens to 90).
fn word_number(w: &str) -> Option<f64> {
    vlnav_words::value(w).map(f64::from)
}

/// Words between a number and its unit that make it an increment: "2 more metres".
const MORE: &[&str] = &["more", "further", "extra", "additional"];

/// A number starting at token `i`: digits ("2.5"), words ("two", "twenty
/// five", "one hundred", "a hundred"), "two point five", "one and a half",
/// "half a", "a couple of", "a few", "a" / "an" / "another" / "a further"
/// before a unit. Returns the value and the index after it.
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
    let unit_next = |k: usize| is_unit(w(k)) || duration_unit(w(k)).is_some();
    match first {
        "half" => return Some((0.5, if w(i + 1) == "a" || w(i + 1) == "an" { i + 2 } else { i + 1 })),
        "a" | "an" if w(i + 1) == "couple" => return Some((2.0, if w(i + 2) == "of" { i + 3 } else { i + 2 })),
        "a" | "an" if w(i + 1) == "few" => return Some((3.0, i + 2)),
        "a" | "an" if w(i + 1) == "half" => return Some((0.5, i + 2)),
        "a" | "an" if w(i + 1) == "hundred" => return number_at_hundred(t, 1.0, i + 1),
        "a" | "an" if unit_next(i + 1) => return Some(and_a_half(t, 1.0, i + 1)),
        "a" if w(i + 1) == "further" && unit_next(i + 2) => return Some(and_a_half(t, 1.0, i + 2)),
        "another" if unit_next(i + 1) => return Some(and_a_half(t, 1.0, i + 1)),
        "another" | "further" => return number_at(t, i + 1).filter(|(v, _)| *v > 0.0),
        "a" if w(i + 1) == "further" => return number_at(t, i + 2),
        "couple" => return Some((2.0, if w(i + 1) == "of" { i + 2 } else { i + 1 })),
        "few" => return Some((3.0, i + 1)),
        "hundred" => return number_at_hundred(t, 1.0, i),
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
        return number_at_hundred(t, total, k);
    }
    Some(point_and_half(t, total, k))
}

/// `factor` hundred at token `k` ("hundred"), with "and eighty" and the like after it.
fn number_at_hundred(t: &[Token], factor: f64, k: usize) -> Option<(f64, usize)> {
    let w = |j: usize| t.get(j).map(|x| x.w.as_str()).unwrap_or("");
    let mut total = factor * 100.0;
    let mut k = k + 1;
    if w(k) == "and" && word_number(w(k + 1)).is_some() {
        k += 1;
    }
    if let Some(u) = word_number(w(k)) {
        total += u;
        k += 1;
        if u >= 20.0
            && let Some(v) = word_number(w(k)).filter(|v| *v < 10.0)
        {
            total += v;
            k += 1;
        }
    }
    Some(point_and_half(t, total, k))
}

/// "… point five", "… and a half" after a number word.
fn point_and_half(t: &[Token], mut total: f64, mut k: usize) -> (f64, usize) {
    let w = |j: usize| t.get(j).map(|x| x.w.as_str()).unwrap_or("");
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
    and_a_half(t, total, k)
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
        "mile" | "miles" | "mi" => 1609.344,
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

fn duration_unit(w: &str) -> Option<f64> {
    Some(match w {
        "s" | "sec" | "secs" | "second" | "seconds" => 1.0,
        "min" | "mins" | "minute" | "minutes" => 60.0,
        "h" | "hour" | "hours" => 3600.0,
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
        if let Some((v, mut k)) = number_at(t, i) {
            // "2 more metres": the increment word sits between number and unit.
            if t.get(k).is_some_and(|x| MORE.contains(&x.w.as_str()))
                && t.get(k + 1).is_some_and(|x| is_unit(&x.w) || duration_unit(&x.w).is_some())
            {
                k += 1;
            }
            let unit = t.get(k).map(|x| x.w.as_str()).unwrap_or("");
            if let Some(f) = length_unit(unit).filter(|_| unit != "in" || k + 1 < t.len()) {
                // "a metre and a half"; "1 meter and 20 centimeters" is one length.
                let (mut total, mut end) = (v * f, k + 1);
                let (half, after) = and_a_half(t, 0.0, end);
                if half > 0.0 {
                    total += half * f;
                    end = after;
                }
                if t.get(end).is_some_and(|x| x.w == "and")
                    && let Some((v2, k2)) = number_at(t, end + 1)
                    && let Some(f2) = t.get(k2).and_then(|x| length_unit(&x.w)).filter(|f2| *f2 < f)
                {
                    total += v2 * f2;
                    end = k2 + 1;
                }
                q.lengths.push((total, i, end));
                i = end;
                continue;
            }
            if let Some(f) = angle_unit(unit) {
                q.angles.push(v * f);
                i = k + 1;
                continue;
            }
            if let Some(f) = duration_unit(unit) {
                q.durations.push(v * f);
                i = k + 1;
                continue;
            }
            if !matches!(t[i].w.as_str(), "a" | "an" | "half" | "couple" | "few" | "another" | "further") {
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

/// A target as spoken: a phrase, or a pronoun that refers back ("it", "him", "there").
#[derive(Clone, Debug, PartialEq)]
enum Spoken {
    Phrase { phrase: String, capital: bool },
    Pronoun,
}

/// A target with the relation it was described by ("the chair next to the table").
#[derive(Clone, Debug, PartialEq)]
struct TargetSpec {
    what: Spoken,
    reference: Option<(String, Spoken)>,
}

impl TargetSpec {
    fn phrase(phrase: String, capital: bool) -> TargetSpec {
        TargetSpec { what: Spoken::Phrase { phrase, capital }, reference: None }
    }

    fn pronoun() -> TargetSpec {
        TargetSpec { what: Spoken::Pronoun, reference: None }
    }
}

/// One clause's meaning before grounding.
#[derive(Clone, Debug, PartialEq)]
enum Directive {
    /// Egocentric: turn `yaw`, then drive `dist` metres.
    Move {
        yaw: f64,
        dist: f64,
        desc: String,
    },
    /// A drive whose distance is the default of a bare drive verb ("go
    /// left"): a distance said in the next clause replaces it.
    DefaultMove {
        yaw: f64,
        desc: String,
    },
    /// Allocentric: go to a landmark. `turn_after` is a turn made there
    /// ("turn right at the statue").
    Find {
        target: TargetSpec,
        d_s: Option<f64>,
        turn_after: Option<f64>,
    },
    Follow {
        target: TargetSpec,
        d_s: Option<f64>,
        duration_s: Option<f64>,
    },
    Return,
    /// A clause with an action word the parser does not understand.
    Unknown(String),
    /// A clause that needs a question (e.g. a turn without a side).
    Ask {
        question: String,
        reason: String,
    },
    /// A clause that plans nothing (a remark, "I lost my phone"); a noun
    /// phrase in it can be what a later "it" means.
    Aside {
        text: String,
        mention: Option<(String, bool)>,
    },
    /// A description of a target: "it is on the table", "the remote is next to the tv".
    Fact {
        subject: Spoken,
        relation: String,
        reference: Spoken,
    },
    /// A constraint or a refusal: "don't go near the cables".
    Negated(String),
    /// A travel verb alone: "go" in "go and find the bottle".
    BareVerb(String),
    /// A target read from a clause without a verb ("then the table"): if it
    /// names nothing detectable it was likely not a target ("thanks a lot").
    Implied(Box<Directive>),
}

impl Directive {
    fn implied(self) -> Directive {
        Directive::Implied(Box::new(self))
    }
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

const TURN_WORDS: &[&str] =
    &["turn", "rotate", "spin", "face", "bear", "veer", "u-turn", "uturn", "pivot", "hang", "about-turn", "about-face"];
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
    "run",
];
/// Verbs of going somewhere; with a destination preposition they name a FIND target.
const TRAVEL_VERBS: &[&str] = &[
    "go", "head", "walk", "drive", "move", "navigate", "proceed", "get", "come", "travel", "roll", "wander", "scoot",
    "run", "hurry", "make", "pull", "continue", "advance", "ride", "rush", "step", "return", "arrive",
];
/// Words between a travel verb and its destination: "head over to", "make your way to".
const PARTICLES: &[&str] = &["over", "up", "on", "down", "yourself", "your", "way", "straight", "directly", "right"];
/// Prepositions of a destination after a travel verb, longest first.
const DEST_PREPS: &[&[&str]] = &[
    &["in", "front", "of"],
    &["up", "to"],
    &["next", "to"],
    &["close", "to"],
    &["near", "to"],
    &["as", "far", "as"],
    &["to"],
    &["towards"],
    &["toward"],
    &["into"],
    &["near"],
    &["by"],
    &["beside"],
    &["at"],
];
/// Prepositions of a place passed on the way: "go through the corridor to the chair".
const VIA_PREPS: &[&str] = &["through", "past", "via", "along", "across"];
/// Verbs that name a FIND by themselves.
const FIND_VERBS: &[&str] = &["find", "locate", "reach", "approach", "visit", "meet", "greet", "spot", "seek", "see"];
/// FIND phrases other than a verb alone: the target starts after the matched words.
const FIND_CUES: &[&[&str]] = &[
    &["look", "for"],
    &["search", "for"],
    &["until", "you", "see"],
    &["until", "you", "reach"],
    &["until", "you", "get", "to"],
    &["there", "is"],
    &["there's"],
    &["there", "are"],
];
/// Prepositions after "stop" / "park" / "wait" that introduce the landmark.
const STOP_PREPS: &[&str] =
    &["near", "at", "by", "beside", "next", "in", "before", "behind", "close", "from", "of", "to", "nearby"];
/// Words that end a target phrase.
const PHRASE_END: &[&str] = &[
    "to",
    "and",
    "which",
    "that",
    "who",
    "so",
    "then",
    "until",
    "for",
    "from",
    "with",
    "on",
    "at",
    "near",
    "by",
    "beside",
    "behind",
    "before",
    "after",
    "in",
    "into",
    "when",
    "while",
    "if",
    "follow",
    "followed",
    "follows",
    "it",
    "there",
    "please",
    "is",
    "are",
    "was",
    "standing",
    "stands",
    "sitting",
    "sits",
    "lies",
    "lying",
    "located",
    "placed",
    "kept",
    "parked",
    "next",
    "close",
    "under",
    "underneath",
    "beneath",
    "below",
    "above",
    "opposite",
    "inside",
    "across",
    "against",
    "again",
    "now",
    "first",
    "too",
    "as",
    "once",
    "where",
    "should",
    "will",
    "might",
    "must",
    "can",
    "could",
    "would",
];
const PARTICIPLES: &[&str] = &["standing", "sitting", "lying", "placed", "kept", "located", "parked"];
const DETERMINERS: &[&str] =
    &["the", "a", "an", "some", "this", "that", "my", "your", "our", "his", "her", "their", "any", "one", "its"];
/// Words that refer back to the last target.
const PRONOUNS: &[&str] = &["it", "him", "her", "them", "there", "that", "this", "one", "they", "he", "she"];
/// Relations that describe a target by another object, longest first.
const RELATIONS: &[&[&str]] = &[
    &["to", "the", "left", "of"],
    &["to", "the", "right", "of"],
    &["in", "front", "of"],
    &["on", "top", "of"],
    &["across", "from"],
    &["left", "of"],
    &["right", "of"],
    &["next", "to"],
    &["close", "to"],
    &["near", "to"],
    &["beside"],
    &["near"],
    &["by"],
    &["on"],
    &["under"],
    &["underneath"],
    &["beneath"],
    &["below"],
    &["above"],
    &["behind"],
    &["opposite"],
    &["inside"],
    &["in"],
    &["at"],
    &["from"],
    &["against"],
];
/// Classes that move, so "follow it" means following them; "follow it" after
/// a chair means going to it (the paper's example), which FIND already does.
fn movable(class_id: i32) -> bool {
    matches!(class_id, 0..=8 | 14..=23)
}

/// The target phrase starting at `start`: determiners dropped, cut at the
/// first word that ends a noun phrase; "spot where X is" → X. Returns the
/// phrase, whether it held a capitalised word, and the index after it.
fn phrase_from(t: &[Token], start: usize) -> (String, bool, usize) {
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
    (text, capital, i)
}

/// A target at `start`: a pronoun, or a phrase with the relation after it.
fn target_at(t: &[Token], start: usize) -> Option<TargetSpec> {
    let mut i = start;
    while t.get(i).is_some_and(|x| matches!(x.w.as_str(), "close" | "to" | "near" | "up" | "next" | "by" | "beside")) {
        i += 1;
    }
    if t.get(i).is_some_and(|x| PRONOUNS.contains(&x.w.as_str()))
        && !t.get(i + 1).is_some_and(|x| !PHRASE_END.contains(&x.w.as_str()) && x.w.chars().all(char::is_alphabetic))
    {
        return Some(TargetSpec::pronoun());
    }
    let (phrase, capital, end) = phrase_from(t, start);
    if phrase.is_empty() || length_unit(&phrase).is_some() || is_side_phrase(&phrase) {
        return None;
    }
    let mut spec = TargetSpec::phrase(phrase, capital);
    spec.reference = relation_at(t, end);
    Some(spec)
}

fn is_side_phrase(p: &str) -> bool {
    p.split_whitespace().all(|w| SIDE_PHRASE_WORDS.contains(&w) || w == "side")
}

/// A relation after a target phrase: "[that is] [standing] next to the table".
fn relation_at(t: &[Token], mut i: usize) -> Option<(String, Spoken)> {
    let w = |k: usize| t.get(k).map(|x| x.w.as_str()).unwrap_or("");
    if matches!(w(i), "that" | "which" | "who") && matches!(w(i + 1), "is" | "are" | "stands" | "sits" | "lies") {
        i += 2;
    } else if matches!(w(i), "that's" | "who's" | "which's") {
        i += 1;
    }
    if PARTICIPLES.contains(&w(i)) || matches!(w(i), "stands" | "sits" | "lies" | "is" | "are") {
        i += 1;
    }
    let ws: Vec<&str> = t[i.min(t.len())..].iter().map(|x| x.w.as_str()).collect();
    let rel = RELATIONS.iter().find(|r| ws.starts_with(r))?;
    let k = i + rel.len();
    if t.get(k).is_some_and(|x| PRONOUNS.contains(&x.w.as_str())) {
        return Some((rel.join(" "), Spoken::Pronoun));
    }
    let (phrase, capital, _) = phrase_from(t, k);
    if phrase.is_empty()
        || is_side_phrase(&phrase)
        || matches!(phrase.as_str(), "me" | "you" | "us" | "distance")
        || phrase.split_whitespace().next().is_some_and(|p| word_number(p).is_some())
        || length_unit(phrase.split_whitespace().last().unwrap_or("")).is_some()
        || phrase.chars().next().is_some_and(|c| c.is_ascii_digit())
    {
        return None;
    }
    Some((rel.join(" "), Spoken::Phrase { phrase, capital }))
}

/// A stopping distance stated with the target: "stop 1 m before the chair",
/// "within 2 metres of", "keep 1.5 m behind", "at a distance of 2 m".
fn stop_distance(t: &[Token], q: &Quantities) -> Option<f64> {
    q.lengths.iter().find_map(|&(v, start, end)| {
        let after = t.get(end).map(|x| x.w.as_str()).unwrap_or("");
        let before = |k: usize| if k == 0 { "" } else { t.get(k - 1).map(|x| x.w.as_str()).unwrap_or("") };
        (matches!(after, "before" | "from" | "away" | "behind" | "short" | "of" | "in")
            || matches!(before(start), "within" | "keep" | "at" | "stay" | "distance" | "of"))
        .then_some(v)
    })
}

fn turn_magnitude(ws: &[&str], q: &Quantities) -> Option<f64> {
    let times = if has(ws, "twice") { 2.0 } else { 1.0 };
    if let Some(a) = q.angles.first() {
        return Some(*a * times);
    }
    if ws.iter().any(|w| matches!(*w, "around" | "u-turn" | "uturn" | "about-turn" | "about-face"))
        || has_seq(ws, &["turn", "back"]).is_some()
        || has_seq(ws, &["about", "face"]).is_some()
        || has_seq(ws, &["about", "turn"]).is_some()
    {
        return Some(HALF_TURN);
    }
    // "turn left a bit": a turn with no drive word, made small.
    let turn_only = ws.iter().any(|w| TURN_WORDS.contains(w)) && !ws.iter().any(|w| DRIVE_WORDS.contains(w));
    let a_bit = ["bit", "little", "tad", "touch"].iter().any(|w| has_seq(ws, &["a", w]).is_some());
    if ws.iter().any(|w| matches!(*w, "slightly" | "slight" | "bear" | "veer"))
        || has_seq(ws, &["a", "little", "to", "the"]).is_some()
        || turn_only && a_bit
    {
        return Some(SLIGHT_TURN_RAD * times);
    }
    if has(ws, "half") && side(ws) != 0 {
        return Some(0.79 * times);
    }
    if side(ws) != 0 {
        return Some(RIGHT_ANGLE * times);
    }
    None
}

/// Words that make a clause an action (as opposed to a remark).
fn has_action_word(ws: &[&str]) -> bool {
    ws.iter().any(|w| {
        TURN_WORDS.contains(w)
            || DRIVE_WORDS.contains(w)
            || TRAVEL_VERBS.contains(w)
            || FIND_VERBS.contains(w)
            || matches!(
                *w,
                "follow"
                    | "return"
                    | "bring"
                    | "fetch"
                    | "grab"
                    | "deliver"
                    | "give"
                    | "hand"
                    | "take"
                    | "carry"
                    | "stop"
                    | "park"
                    | "halt"
                    | "look"
                    | "search"
            )
    })
}

/// What the clauses before this one established, for ellipsis: the action
/// of the last target ("find the chair, then the table") and the side of
/// the last turn ("turn left, then 90 degrees more").
#[derive(Clone, Copy, Debug, Default)]
struct Ellipsis {
    target_action: Option<Action>,
    last_side: i8,
    last_was_move: bool,
}

/// A first clause that is only a cue word ("right, now turn left", "so,").
fn discourse_marker(ws: &[&str]) -> bool {
    matches!(ws, ["right"] | ["all", "right"] | ["now"] | ["so"] | ["well"] | ["okay"] | ["ok"])
}

/// Cuts "when you reach it", "once there", "there" off a clause about a turn:
/// the turn happens where the robot is after the step before it.
fn strip_here_and_now(t: &[Token]) -> Vec<Token> {
    let ws = words(t);
    let turnish = ws.iter().any(|w| TURN_WORDS.contains(w)) || side(&ws) != 0;
    if !turnish {
        return t.to_vec();
    }
    let mut out = t.to_vec();
    if let Some(k) = ws.iter().position(|w| matches!(*w, "when" | "once" | "as")) {
        let rest = &ws[k..];
        if rest.iter().any(|w| PRONOUNS.contains(w)) {
            out.truncate(k);
        }
    }
    let keep: Vec<bool> = (0..out.len())
        .map(|i| out[i].w != "there" || out.get(i + 1).is_some_and(|n| matches!(n.w.as_str(), "is" | "are")))
        .collect();
    let mut k = 0;
    out.retain(|_| {
        k += 1;
        keep[k - 1]
    });
    out
}

fn resolve(t: &[Token], ctx: Ellipsis) -> Vec<Directive> {
    let t = strip_here_and_now(t);
    let t = t.as_slice();
    let ws = words(t);
    let q = quantities(t);
    let text = ws.join(" ");

    // Constraints: "don't go near the cables", "avoid the stairs", "never mind the chair";
    // but "don't stop until you reach the car" is a FIND of the car.
    // "if you don't mind", "would you not mind": politeness, not a constraint.
    let negation_at = |i: usize| NEGATIONS.contains(&ws[i]) && ws.get(i + 1) != Some(&"mind");
    if (0..ws.len()).any(negation_at)
        || has_seq(&ws, &["do", "not"]).is_some_and(|i| ws.get(i + 2) != Some(&"mind"))
        || has_seq(&ws, &["stay", "away"]).is_some()
        || has_seq(&ws, &["keep", "away"]).is_some()
    {
        // The part from an "until" after the clause's first word: shorter, so this ends
        // (a clause that begins with "until" is itself the constraint).
        if let Some(u) = ws.iter().skip(1).position(|w| *w == "until") {
            return resolve(&t[u + 1..], ctx);
        }
        return vec![Directive::Negated(text)];
    }

    // "… and stop", "then stop there": every plan ends where its last step does.
    if ws.iter().any(|w| matches!(*w, "stop" | "halt"))
        && ws.iter().all(|w| {
            matches!(*w, "stop" | "halt" | "there" | "here" | "now" | "just" | "right" | "please") || FILLER.contains(w)
        })
    {
        return Vec::new();
    }

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
            return match target_at(t, s) {
                Some(target) => vec![Directive::Find { target, d_s: None, turn_after: None }, Directive::Return],
                None => vec![Directive::Unknown(text)],
            };
        }
    }
    if let Some(i) = ws.iter().position(|w| matches!(*w, "deliver" | "give" | "hand" | "take" | "carry"))
        && !ws.iter().any(|w| matches!(*w, "turn" | "left" | "right" | "u-turn"))
        && let Some(to) = ws[i..].iter().position(|w| *w == "to").map(|k| k + i)
        && let Some(target) = target_at(t, to + 1).filter(|x| x.what != Spoken::Pronoun)
        && !matches!(&target.what, Spoken::Phrase { phrase, .. } if phrase == "me")
    {
        return vec![Directive::Find { target, d_s: None, turn_after: None }];
    }

    // FOLLOW: "follow the person for 30 seconds"; "you may see X … follow it" is a FIND of X
    // and, when X moves, a FOLLOW of it.
    if let Some(i) = ws.iter().position(|w| *w == "follow") {
        let d_s = stop_distance(t, &q);
        let duration_s = q.durations.first().copied();
        let target = target_at(t, i + 1).unwrap_or_else(TargetSpec::pronoun);
        if target.what != Spoken::Pronoun {
            return vec![Directive::Follow { target, d_s, duration_s }];
        }
        if let Some(find) = find_cue(t, &ws).filter(|x| x.0 < i)
            && let Some(seen) = target_at(t, find.1).filter(|x| x.what != Spoken::Pronoun)
        {
            return vec![
                Directive::Find { target: seen, d_s: None, turn_after: None },
                Directive::Follow { target, d_s, duration_s },
            ];
        }
        return vec![Directive::Follow { target, d_s, duration_s }];
    }

    // "stop / park / wait near the statue"
    if let Some(i) = ws.iter().position(|w| matches!(*w, "stop" | "park" | "halt" | "wait"))
        && let Some(p) = ws[i + 1..].iter().position(|w| STOP_PREPS.contains(w)).map(|k| k + i + 1)
    {
        let mut s = p + 1;
        while matches!(ws.get(s), Some(&"to") | Some(&"of") | Some(&"front")) {
            s += 1;
        }
        if let Some(target) = target_at(t, s) {
            return vec![Directive::Find { target, d_s: stop_distance(t, &q), turn_after: None }];
        }
    }

    // "turn right at the statue": go to the landmark, then turn there.
    let turning = ws.iter().any(|w| TURN_WORDS.contains(w)) || has_seq(&ws, &["take", "a"]).is_some() && side(&ws) != 0;
    if turning && let Some(at) = ws.iter().position(|w| *w == "at") {
        let (phrase, capital, end) = phrase_from(t, at + 1);
        if !phrase.is_empty() && !is_side_phrase(&phrase) {
            let mag = turn_magnitude(&ws, &q).unwrap_or(RIGHT_ANGLE);
            let s = side(&ws);
            let yaw = if mag >= HALF_TURN { HALF_TURN } else { mag * s as f64 };
            let mut target = TargetSpec::phrase(phrase, capital);
            target.reference = relation_at(t, end);
            return vec![Directive::Find { target, d_s: None, turn_after: (yaw != 0.0).then_some(yaw) }];
        }
    }

    // Allocentric cues: "find X", "go to X", "head over to X", "you may see X".
    if let Some((_, start)) = find_cue(t, &ws) {
        // "go through the corridor to the chair": the place passed, then the destination.
        if let Some(via) = t.get(start.wrapping_sub(1)).filter(|x| VIA_PREPS.contains(&x.w.as_str())).map(|_| start) {
            let (phrase, capital, end) = phrase_from(t, via);
            let mut out = Vec::new();
            if !phrase.is_empty() {
                out.push(Directive::Find { target: TargetSpec::phrase(phrase, capital), d_s: None, turn_after: None });
            }
            if let Some(k) = (end..t.len()).find(|&k| matches!(t[k].w.as_str(), "to" | "towards" | "toward"))
                && let Some(target) = target_at(t, k + 1)
            {
                out.push(Directive::Find { target, d_s: stop_distance(t, &q), turn_after: None });
            }
            if !out.is_empty() {
                return out;
            }
        }
        return match target_at(t, start) {
            Some(target) => vec![Directive::Find { target, d_s: stop_distance(t, &q), turn_after: None }],
            None => vec![Directive::Unknown(text)],
        };
    }

    // A travel verb alone: "go" in "go and find the bottle", "move".
    let content: Vec<&str> = ws.iter().copied().filter(|w| !FILLER.contains(w)).collect();
    if !content.is_empty() && content.iter().all(|w| TRAVEL_VERBS.contains(w) || matches!(*w, "keep" | "on")) {
        return vec![Directive::BareVerb(text)];
    }

    // Egocentric: turns and drives.
    let drives = ws.iter().any(|w| DRIVE_WORDS.contains(w));
    let turn_cue = ws.iter().any(|w| TURN_WORDS.contains(w))
        || (has(&ws, "take") || has(&ws, "make") || has(&ws, "do")) && (side(&ws) != 0 || has(&ws, "about-turn"));
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
        // Motion only from words the parser knows: a phrase it does not
        // understand ("the far lamp", "move the chair") is asked about, never driven.
        if let Some(unknown) = not_motion_words(t) {
            return vec![Directive::Ask {
                question: format!(
                    "I did not understand \"{unknown}\" in \"{}\". How far and which way should I move, or what should I find?",
                    spoken(t)
                ),
                reason: format!(
                    "\"{unknown}\" is not a direction, distance or angle I know; no motion is planned from it"
                ),
            }];
        }
        // "go right 45 degrees": an angle and no forward word is a turn.
        let forward_word = ws.iter().any(|w| {
            matches!(*w, "ahead" | "forward" | "forwards" | "straight" | "advance" | "proceed" | "continue" | "keep")
        });
        let angle_only = !q.angles.is_empty() && q.lengths.is_empty() && q.bare.is_empty() && !forward_word;
        let vague_words =
            vague_far || ws.iter().any(|w| matches!(*w, "little" | "bit" | "slightly" | "some" | "further"));
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
        let mut defaulted = false;
        if dist == 0.0 && !pure_turn && !angle_only {
            // "a little", an unqualified drive and "turn left and go" take the short default.
            dist = if vague_far { VAGUE_FAR_M } else { VAGUE_SHORT_M };
            defaulted = !vague_words;
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
        if defaulted {
            return vec![Directive::DefaultMove { yaw, desc: text }];
        }
        return vec![Directive::Move { yaw, dist, desc: text }];
    }

    ellipsis_or_aside(t, &ws, &q, text, ctx)
}

/// Words a clause that becomes a MOVE may hold besides numbers: directions,
/// units, vague distances, verbs of turning and driving, fillers. Anything
/// else (an object, a place, a word the parser does not know) means the
/// clause was not understood as motion.
const MOTION_EXTRA: &[&str] = &[
    "for",
    "by",
    "of",
    "about",
    "around",
    "approximately",
    "roughly",
    "some",
    "or",
    "so",
    "more",
    "bit",
    "little",
    "far",
    "long",
    "way",
    "slightly",
    "slight",
    "twice",
    "again",
    "take",
    "make",
    "do",
    "hand",
    "side",
    "your",
    "me",
    "us",
    "distance",
    "direction",
    "degrees",
    "full",
    "quarter",
    "turn",
    "just",
    "over",
    "along",
    "on",
    "up",
    "in",
    "off",
    "go",
    "going",
    "keep",
    "it",
    "yourself",
    "till",
    "all",
    "small",
    "tiny",
    "short",
    "tad",
    "touch",
    "smidge",
    "while",
    "right",
    "left",
    "into",
    "towards",
    "toward",
    "forth",
    "is",
    "be",
    "we",
    "let's",
    "other",
    "opposite",
    "face",
    "facing",
    "one",
    "half",
    "once",
    "mind",
    "if",
    "possible",
    "meters",
    "few",
    "couple",
    "please",
    "not",
    "how",
    "wondering",
    "was",
    "think",
    "maybe",
    "kind",
    "as",
    "very",
    "much",
    "really",
    "same",
    "exactly",
    "only",
    "about-face",
    "clock",
    "counter",
    "anti",
    "position",
    "heading",
    "backwards",
    "backward",
    "reverse",
    "reversing",
    "back",
    "round",
    "roll",
    "spin",
    "bear",
    "veer",
    "pivot",
    "hang",
    "sharp",
    "gentle",
    "gently",
    "fully",
    "completely",
    "whole",
    "entire",
    "steps",
];

/// The first word of a motion clause that is not motion vocabulary, if any.
fn not_motion_words(t: &[Token]) -> Option<String> {
    let known = |w: &str| {
        w.chars().all(|c| !c.is_alphabetic())
            || FILLER.contains(&w)
            || TURN_WORDS.contains(&w)
            || DRIVE_WORDS.contains(&w)
            || TRAVEL_VERBS.contains(&w)
            || PARTICLES.contains(&w)
            || KEYWORDS.contains(&w)
            || DETERMINERS.contains(&w)
            || SIDE_PHRASE_WORDS.contains(&w)
            || MORE.contains(&w)
            || MOTION_EXTRA.contains(&w)
            || vlnav_words::value(w).is_some()
            || length_unit(w).is_some()
            || angle_unit(w).is_some()
            || duration_unit(w).is_some()
            || HONORIFICS.contains(&w)
            || matches!(w, "hundred" | "thousand" | "and" | "a" | "counterclockwise" | "anticlockwise" | "clockwise")
            || w.starts_with("counter-")
            || w.starts_with("anti-")
    };
    t.iter().find(|x| !known(&x.w)).map(|x| x.raw.clone())
}

/// The earliest FIND cue in the clause: (its position, where the target starts).
fn find_cue(t: &[Token], ws: &[&str]) -> Option<(usize, usize)> {
    let mut best: Option<(usize, usize)> = None;
    let mut offer = |p: usize, start: usize| {
        if best.is_none_or(|(bp, _)| p < bp) {
            best = Some((p, start));
        }
    };
    for cue in FIND_CUES {
        if let Some(p) = has_seq(ws, cue) {
            offer(p, p + cue.len());
        }
    }
    for (p, w) in ws.iter().enumerate() {
        if FIND_VERBS.contains(w) {
            offer(p, p + 1);
        }
        if TRAVEL_VERBS.contains(w) {
            // verb, particles ("over", "your way"), then a destination or a place passed.
            let mut k = p + 1;
            while k < ws.len()
                && (PARTICLES.contains(&ws[k]) || FILLER.contains(&ws[k]) && !matches!(ws[k], "to" | "at"))
            {
                if ws[k] == "right" && ws.get(k + 1).is_none_or(|n| !matches!(*n, "to" | "up" | "over")) {
                    break;
                }
                k += 1;
            }
            if let Some(prep) = DEST_PREPS.iter().find(|d| ws[k.min(ws.len())..].starts_with(d)) {
                let start = k + prep.len();
                let directional = ws
                    .get(start..)
                    .map(|rest| {
                        let rest: Vec<&str> =
                            rest.iter().copied().filter(|w| !matches!(*w, "the" | "your" | "my")).collect();
                        rest.first().is_some_and(|w| matches!(*w, "left" | "right"))
                    })
                    .unwrap_or(false);
                if !directional {
                    offer(p, start);
                }
            } else if ws.get(k).is_some_and(|w| VIA_PREPS.contains(w)) {
                offer(p, k + 1);
            }
        }
    }
    let _ = t;
    best
}

/// A clause with no verb of its own: read with the clause before it ("then
/// the table", "then 2 more", "left again"), or a remark.
fn ellipsis_or_aside(t: &[Token], ws: &[&str], q: &Quantities, text: String, ctx: Ellipsis) -> Vec<Directive> {
    let action_word = has_action_word(ws);
    let content: Vec<&str> =
        ws.iter().copied().filter(|w| !FILLER.contains(w) && w.chars().any(char::is_alphanumeric)).collect();
    if content.is_empty() {
        return Vec::new();
    }
    // A description: "it is on the table", "the remote should be next to it".
    if !action_word && let Some(fact) = fact(t, ws) {
        return vec![fact];
    }
    // A distance: "then 2 more", "a bit more", "another 3".
    let vague = content.iter().any(|w| matches!(*w, "bit" | "little" | "more" | "further"));
    if !action_word
        && (ctx.last_was_move || !q.bare.is_empty())
        && side(ws) == 0
        && q.angles.is_empty()
        && not_motion_words(t).is_none()
    {
        if let Some(&(v, _, _)) = q.bare.first() {
            return vec![Directive::Move { yaw: 0.0, dist: v, desc: text }];
        }
        if vague && ctx.last_was_move {
            return vec![Directive::Move { yaw: 0.0, dist: VAGUE_SHORT_M, desc: text }];
        }
    }
    // A turn: "left again", "then right", "90 degrees more".
    let s = side(ws);
    // Only motion words: "the left chair" is a target, never a turn.
    if !action_word
        && (s != 0 || !q.angles.is_empty())
        && content.iter().all(|w| !DETERMINERS.contains(w))
        && not_motion_words(t).is_none()
    {
        let s = if s != 0 { s } else { ctx.last_side };
        if s == 0 {
            return vec![Directive::Ask {
                question: "Which way should I turn, left or right?".into(),
                reason: format!("\"{text}\" does not say which way to turn"),
            }];
        }
        let m = turn_magnitude(ws, q).unwrap_or(RIGHT_ANGLE);
        return vec![Directive::Move { yaw: wrap(m * s as f64), dist: 0.0, desc: text }];
    }
    // A noun phrase: "then the table", "then to the bicycle", "first the chair"; read as
    // the last target's action, or as a FIND when it starts with an article.
    if !action_word {
        let mut start = 0;
        while t.get(start).is_some_and(|x| {
            (FILLER.contains(&x.w.as_str()) && !DETERMINERS.contains(&x.w.as_str()) && x.w != "to")
                || matches!(x.w.as_str(), "towards")
        }) {
            start += 1;
        }
        let opens_phrase = t.get(start).is_some_and(|x| DETERMINERS.contains(&x.w.as_str()) || x.w == "to");
        if (ctx.target_action.is_some() || opens_phrase)
            && let Some(target) = target_at(t, start).filter(|x| x.what != Spoken::Pronoun)
        {
            return match ctx.target_action {
                Some(Action::Follow) => vec![Directive::Follow { target, d_s: None, duration_s: None }],
                _ => vec![Directive::Find { target, d_s: None, turn_after: None }],
            }
            .into_iter()
            .map(Directive::implied)
            .collect();
        }
    }
    if action_word {
        return vec![Directive::Unknown(text)];
    }
    // A remark; its last noun phrase may be what a later "it" means.
    let mention = (0..t.len())
        .filter(|&i| DETERMINERS.contains(&t[i].w.as_str()))
        .filter_map(|i| {
            let (p, c, _) = phrase_from(t, i);
            (!p.is_empty()).then_some((p, c))
        })
        .next_back();
    vec![Directive::Aside { text, mention }]
}

/// "it is on the table", "the remote should be next to it".
fn fact(t: &[Token], ws: &[&str]) -> Option<Directive> {
    let copula = ws.iter().position(|w| matches!(*w, "is" | "are" | "it's" | "be" | "sits" | "stands" | "lies"))?;
    let subject_words: Vec<&str> = ws[..copula]
        .iter()
        .copied()
        .filter(|w| !FILLER.contains(w) && !matches!(*w, "should" | "might" | "must" | "may" | "probably"))
        .collect();
    let subject = if ws[copula] == "it's" || matches!(subject_words.as_slice(), ["it"] | ["they"]) {
        Spoken::Pronoun
    } else if subject_words.is_empty() || subject_words.iter().any(|w| matches!(*w, "there" | "where" | "what")) {
        return None;
    } else {
        let (phrase, capital, _) = phrase_from(&t[..copula], 0);
        if phrase.is_empty() {
            return None;
        }
        Spoken::Phrase { phrase, capital }
    };
    let (relation, reference) = relation_at(t, copula + 1)?;
    Some(Directive::Fact { subject, relation, reference })
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

/// Head nouns of places no detector class covers: a phrase about one of
/// them names a place, not an object ("the kitchen", "the meeting room"),
/// however close an embedding puts it to a class ("office" ~ desk).
const PLACES: &[&str] = &[
    "kitchen",
    "office",
    "lobby",
    "corridor",
    "hallway",
    "hall",
    "room",
    "reception",
    "cafeteria",
    "canteen",
    "garage",
    "garden",
    "yard",
    "lab",
    "laboratory",
    "pantry",
    "elevator",
    "lift",
    "stairs",
    "staircase",
    "stairway",
    "entrance",
    "exit",
    "door",
    "doorway",
    "corner",
    "pharmacy",
    "shop",
    "store",
    "bathroom",
    "bedroom",
    "basement",
    "attic",
    "balcony",
    "terrace",
    "patio",
    "street",
    "building",
    "floor",
    "wall",
    "window",
    "gate",
    "station",
    "area",
    "zone",
    "library",
    "classroom",
    "ward",
    "warehouse",
    "restroom",
    "washroom",
    "toilets",
    "base",
];

/// A phrase with its misspelt class words corrected ("chiar" → "chair"), if any were;
/// `Err` with the classes when a word is equally near two of them ("cas": car, cat).
fn corrected_phrase(phrase: &str) -> Result<Option<String>, Vec<String>> {
    let vocab = crate::grounding::class_words();
    let mut changed = false;
    let mut fixed: Vec<String> = Vec::new();
    for w in phrase.split_whitespace() {
        if crate::grounding::lexical(w).is_none() && !NOT_TYPOS.contains(&w) {
            let found = crate::typo::candidates(w, vocab, true);
            let mut classes: Vec<i32> =
                found.iter().filter_map(|c| crate::grounding::lexical(c).map(|g| g.class_id)).collect();
            classes.sort_unstable();
            classes.dedup();
            if classes.len() > 1 {
                return Err(classes.iter().map(|&c| vlnav_proto::coco::CLASSES[c as usize].to_string()).collect());
            }
            if let Some(c) = found.first() {
                changed = true;
                fixed.push(c.to_string());
                continue;
            }
        }
        fixed.push(w.to_string());
    }
    Ok(changed.then(|| fixed.join(" ")))
}

fn ground_target(g: &Grounder, phrase: &str, capital: bool) -> Ground {
    if let Some(name) = person_identity(phrase, capital) {
        return Ground::Class { class_id: 0, person: Some(name), note: None };
    }
    if phrase.split_whitespace().last().is_some_and(|head| PLACES.contains(&head)) {
        return Ground::Unknown(Ungrounded { phrase: phrase.to_string(), suggestions: Vec::new() });
    }
    let describe = |found: crate::grounding::Grounding, said: &str| {
        let note = match found.via {
            Via::Lexical(_) if said == phrase => None,
            Via::Lexical(_) => Some(format!(
                "read \"{phrase}\" as \"{said}\": {} (id {})",
                vlnav_proto::coco::CLASSES[found.class_id as usize],
                found.class_id
            )),
            Via::Semantic { matched, score } => Some(format!(
                "grounded \"{said}\" to {} (id {}) by similarity to \"{matched}\" ({score:.2})",
                vlnav_proto::coco::CLASSES[found.class_id as usize],
                found.class_id
            )),
        };
        Ground::Class { class_id: found.class_id, person: None, note }
    };
    match g.ground(phrase) {
        Ok(found) => describe(found, phrase),
        Err(u) => match corrected_phrase(phrase) {
            Ok(Some(fixed)) => match crate::grounding::lexical(&fixed) {
                Some(found) => describe(found, &fixed),
                None => Ground::Unknown(u),
            },
            Ok(None) => Ground::Unknown(u),
            // Equally near two classes: ask which, offering both.
            Err(options) => Ground::Unknown(Ungrounded { phrase: phrase.to_string(), suggestions: options }),
        },
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

/// What "it", "him", "there" refer to: the last target named.
#[derive(Clone, Debug)]
struct Antecedent {
    phrase: String,
    class_id: i32,
    person: Option<String>,
}

/// A plan step in the making, or a target that names no detectable class.
#[derive(Clone, Debug)]
enum Item {
    Step(Step),
    Unplaced { phrase: String, suggestions: Vec<String> },
}

/// Builds the plan clause by clause, with what earlier clauses said.
struct Builder<'g> {
    grounder: &'g Grounder,
    items: Vec<Item>,
    notes: Vec<String>,
    ungrounded: Vec<String>,
    antecedent: Option<Antecedent>,
    /// Descriptions of a class: "the remote is next to the tv".
    facts: Vec<(i32, Reference)>,
    bare_verbs: Vec<String>,
    ellipsis: Ellipsis,
    /// The words of the clause being read, as spoken: each step's source.
    source: String,
    /// The last step is a drive whose distance is a bare drive verb's default.
    last_move_defaulted: bool,
}

impl<'g> Builder<'g> {
    fn new(grounder: &'g Grounder) -> Self {
        Builder {
            grounder,
            items: Vec::new(),
            notes: Vec::new(),
            ungrounded: Vec::new(),
            antecedent: None,
            facts: Vec::new(),
            bare_verbs: Vec::new(),
            ellipsis: Ellipsis::default(),
            source: String::new(),
            last_move_defaulted: false,
        }
    }

    fn ask(&mut self, question: impl Into<String>, reason: impl Into<String>, options: Vec<String>) -> Parsed {
        Parsed::ask(question, reason, options, std::mem::take(&mut self.notes))
    }

    fn last_step(&mut self) -> Option<&mut Step> {
        match self.items.last_mut() {
            Some(Item::Step(s)) => Some(s),
            _ => None,
        }
    }

    fn push_move(&mut self, yaw: f64, dist: f64, desc: String) {
        self.push_move_from(yaw, dist, desc, false);
    }

    fn push_move_from(&mut self, yaw: f64, dist: f64, desc: String, defaulted: bool) {
        self.ellipsis.last_was_move = true;
        if yaw != 0.0 {
            self.ellipsis.last_side = if yaw > 0.0 { 1 } else { -1 };
        }
        let was_defaulted = std::mem::replace(&mut self.last_move_defaulted, defaulted);
        let source = self.source.clone();
        if let Some(prev) = self.last_step()
            && prev.action == Action::Move
        {
            let merged = if prev.source.split(" + ").any(|s| s == source) {
                prev.source.clone()
            } else {
                format!("{} + {source}", prev.source)
            };
            if was_defaulted && yaw == 0.0 && dist > 0.0 && !defaulted {
                // "go left, then forward 1 m": the distance said replaces the bare verb's default.
                prev.f_dist = dist;
                prev.desc = format!("{}, {desc}", prev.desc);
                prev.source = merged;
                return;
            }
            if prev.f_dist == 0.0 {
                // A pure turn, then a drive or another turn: one MOVE turns, then drives.
                prev.yaw = wrap(prev.yaw + yaw);
                prev.f_dist = dist;
                prev.desc = format!("{}, {desc}", prev.desc);
                prev.source = merged;
                if prev.yaw.abs() < 0.005 && prev.f_dist < 0.1 {
                    self.items.pop();
                }
                return;
            }
            if yaw == 0.0 && dist > 0.0 {
                // "then 2 more metres": the drives add up.
                prev.f_dist += dist;
                prev.desc = format!("{}, {desc}", prev.desc);
                prev.source = merged;
                return;
            }
        }
        self.items.push(Item::Step(Step::moving(desc, dist, yaw).with_source(source)));
    }

    /// A spoken reference object → a plan reference, or a place reported as not grounded.
    fn reference(&mut self, relation: String, spoken: Spoken) -> Option<Reference> {
        match spoken {
            Spoken::Pronoun => {
                self.antecedent.as_ref().map(|a| Reference { relation, target: a.phrase.clone(), class_id: a.class_id })
            }
            Spoken::Phrase { phrase, capital } => match ground_target(self.grounder, &phrase, capital) {
                Ground::Class { class_id, note, .. } => {
                    self.notes.extend(note);
                    Some(Reference { relation, target: phrase, class_id })
                }
                Ground::Unknown(u) => {
                    self.notes.push(format!(
                        "\"{}\" ({relation} it) is not something I can detect; looking for the target without it",
                        u.phrase
                    ));
                    self.ungrounded.push(u.phrase);
                    None
                }
            },
        }
    }

    /// A FIND or FOLLOW; `Err` is the question to ask instead of a plan.
    fn target(
        &mut self,
        action: Action,
        target: TargetSpec,
        d_s: Option<f64>,
        duration_s: Option<f64>,
        implied: bool,
    ) -> Result<(), Parsed> {
        self.ellipsis.last_was_move = false;
        self.ellipsis.target_action = Some(action);
        if let Some(d) = d_s
            && !(0.0..=5.0).contains(&d)
        {
            return Err(self.ask(
                "How close should I stop? I can stop between 0 and 5 m from a target.",
                format!("stopping distance {d} m is out of range"),
                vec![],
            ));
        }
        if let Some(t) = duration_s
            && !(0.0..=3600.0).contains(&t)
        {
            return Err(self.ask(
                "For how long should I follow? At most one hour.",
                format!("follow duration {t} s is out of range"),
                vec![],
            ));
        }
        let verb = if action == Action::Follow { "follow" } else { "go to" };
        let (phrase, class_id, person) = match target.what {
            Spoken::Pronoun => {
                let Some(a) = self.antecedent.clone() else {
                    return Err(self.ask(
                        format!("What should I {verb}?"),
                        format!("\"{verb} it\" with nothing named before it"),
                        vec![],
                    ));
                };
                let same = |s: &Step| {
                    matches!(s.action, Action::Find | Action::Follow)
                        && s.class_id == a.class_id
                        && s.person == a.person
                };
                if action == Action::Follow && !movable(a.class_id) {
                    self.notes.push(format!("\"follow\" a {} that does not move: going to it", a.phrase));
                    if self.last_step().is_some_and(|s| same(s)) {
                        return Ok(());
                    }
                    return self.push_target(Action::Find, a.phrase, a.class_id, a.person, d_s, None, None);
                }
                if action == Action::Find
                    && let Some(prev) = self.last_step().filter(|s| same(s))
                {
                    // "find the bench and stop 1 m before it": the same visit.
                    if d_s.is_some() {
                        prev.d_s = d_s.map(round2);
                    }
                    return Ok(());
                }
                (a.phrase, a.class_id, a.person)
            }
            Spoken::Phrase { phrase, capital } => match ground_target(self.grounder, &phrase, capital) {
                Ground::Class { class_id, person, note } => {
                    self.notes.extend(note);
                    (phrase, class_id, person)
                }
                Ground::Unknown(u)
                    if implied
                        && u.phrase.split_whitespace().all(|w| {
                            FILLER.contains(&w)
                                || NOT_TYPOS.contains(&w)
                                || matches!(w, "lot" | "bunch" | "ton" | "million")
                        }) =>
                {
                    self.notes.push(format!("ignored \"{}\": not an action, a place or an object I know", u.phrase));
                    return Ok(());
                }
                Ground::Unknown(u) => {
                    self.items.push(Item::Unplaced { phrase: u.phrase, suggestions: u.suggestions });
                    return Ok(());
                }
            },
        };
        let reference = match target.reference {
            Some((relation, spoken)) => self.reference(relation, spoken),
            None => None,
        };
        self.push_target(action, phrase, class_id, person, d_s, duration_s, reference)
    }

    #[allow(clippy::too_many_arguments)]
    fn push_target(
        &mut self,
        action: Action,
        phrase: String,
        class_id: i32,
        person: Option<String>,
        d_s: Option<f64>,
        duration_s: Option<f64>,
        reference: Option<Reference>,
    ) -> Result<(), Parsed> {
        self.antecedent = Some(Antecedent { phrase: phrase.clone(), class_id, person: person.clone() });
        self.last_move_defaulted = false;
        let mut step = Step { target: phrase, class_id, person, reference, ..Step::blank(action) };
        step.source = self.source.clone();
        step.d_s = d_s.map(round2);
        if action == Action::Follow {
            step.duration_s = duration_s;
        }
        self.items.push(Item::Step(step));
        Ok(())
    }

    fn fact(&mut self, subject: Spoken, relation: String, reference: Spoken) {
        let class_id = match subject {
            Spoken::Pronoun => self.antecedent.as_ref().map(|a| a.class_id),
            Spoken::Phrase { phrase, capital } => match ground_target(self.grounder, &phrase, capital) {
                Ground::Class { class_id, .. } => Some(class_id),
                Ground::Unknown(_) => None,
            },
        };
        if let (Some(class_id), Some(r)) = (class_id, self.reference(relation, reference)) {
            self.facts.push((class_id, r));
        }
    }

    /// One clause's directives; `Err` is the question to ask instead of a plan.
    fn directive(&mut self, d: Directive, implied: bool) -> Result<(), Parsed> {
        match d {
            Directive::Unknown(clause) => Err(self.ask(
                format!(
                    "I did not understand \"{clause}\". Could you rephrase it as a move, a place to find, a person to follow, or \"go back\"?"
                ),
                format!("no action recognised in \"{clause}\""),
                vec![],
            )),
            Directive::Ask { question, reason } => Err(self.ask(question, reason, vec![])),
            Directive::Return => {
                self.ellipsis.last_was_move = false;
                self.last_move_defaulted = false;
                self.items.push(Item::Step(Step::go_back("return to the start").with_source(self.source.clone())));
                Ok(())
            }
            Directive::Move { yaw, dist, desc } => {
                self.push_move(yaw, dist, desc);
                Ok(())
            }
            Directive::DefaultMove { yaw, desc } => {
                self.push_move_from(yaw, VAGUE_SHORT_M, desc, true);
                Ok(())
            }
            Directive::Find { target, d_s, turn_after } => {
                self.target(Action::Find, target, d_s, None, implied)?;
                if let Some(yaw) = turn_after {
                    let side = if yaw > 0.0 { "left" } else { "right" };
                    self.push_move(yaw, 0.0, format!("turn {side} at the landmark"));
                }
                Ok(())
            }
            Directive::Follow { target, d_s, duration_s } => {
                self.target(Action::Follow, target, d_s, duration_s, implied)
            }
            Directive::Aside { text, mention } => {
                if let Some((phrase, capital)) = mention
                    && let Ground::Class { class_id, person, .. } = ground_target(self.grounder, &phrase, capital)
                {
                    self.antecedent = Some(Antecedent { phrase, class_id, person });
                }
                self.notes.push(format!("no action in \"{text}\"; nothing planned for it"));
                Ok(())
            }
            Directive::Fact { subject, relation, reference } => {
                self.fact(subject, relation, reference);
                Ok(())
            }
            Directive::Negated(text) => {
                self.notes.push(format!(
                    "not planned: \"{text}\" (a constraint; obstacles are avoided on the way in any case)"
                ));
                Ok(())
            }
            Directive::BareVerb(text) => {
                self.bare_verbs.push(text);
                Ok(())
            }
            Directive::Implied(inner) => self.directive(*inner, true),
        }
    }

    /// The plan, or the question a person would also ask.
    fn finish(mut self) -> Parsed {
        // Descriptions ("the remote is next to the tv") ride on the FIND of that class.
        for (class_id, r) in std::mem::take(&mut self.facts) {
            for item in self.items.iter_mut() {
                if let Item::Step(s) = item
                    && matches!(s.action, Action::Find | Action::Follow)
                    && s.class_id == class_id
                    && s.reference.is_none()
                {
                    s.reference = Some(r.clone());
                }
            }
        }
        // A place no class covers is passed over when a detectable target comes
        // right after it ("go to the kitchen and find the cup"); otherwise the
        // steps after it depend on it, and the plan would guess.
        let mut steps = Vec::new();
        let items = std::mem::take(&mut self.items);
        for (i, item) in items.iter().enumerate() {
            match item {
                Item::Step(s) if s.action == Action::Move => {
                    // Turns and drives add up unrounded; the plan carries 0.01 rad and 1 cm.
                    steps.push(Step { yaw: round2(wrap(s.yaw)), f_dist: round2(s.f_dist), ..s.clone() })
                }
                Item::Step(s) => steps.push(s.clone()),
                Item::Unplaced { phrase, suggestions } => {
                    let next_is_target = matches!(items.get(i + 1), Some(Item::Step(s)) if matches!(s.action, Action::Find | Action::Follow));
                    if !next_is_target {
                        return self.ask(
                            format!("I don't know what \"{phrase}\" looks like. Which object should I look for?"),
                            format!("cannot ground \"{phrase}\" to a COCO-80 class"),
                            suggestions.clone(),
                        );
                    }
                    self.notes.push(format!(
                        "\"{phrase}\" is not something I can detect; planning the next target without it"
                    ));
                    self.ungrounded.push(phrase.clone());
                }
            }
        }
        if steps.is_empty() {
            if !self.bare_verbs.is_empty() {
                return self.ask(
                    "Where should I go, or how far?",
                    format!("\"{}\" names no direction, distance or target", self.bare_verbs.join(", ")),
                    vec!["move 2 m ahead".into(), "go to the chair".into()],
                );
            }
            return self.ask(
                "What should I do? I can move, find an object or a person, follow someone, or go back.",
                "the instruction holds no action",
                vec![],
            );
        }
        for s in &steps {
            if s.action != Action::Move {
                continue;
            }
            if s.f_dist > MAX_SPLIT_M {
                return self.ask(
                    format!(
                        "That is {} m. I can drive at most {MAX_SPLIT_M} m in one instruction; how far should I go?",
                        s.f_dist
                    ),
                    format!("distance {} m in \"{}\" is too far", s.f_dist, s.desc),
                    vec![],
                );
            }
            if s.f_dist.abs() < 0.1 && s.yaw.abs() < 0.01 {
                // Under 10 cm and no turn: nothing the robot can execute.
                return self.ask(
                    format!("\"{}\" is less than 10 cm. How far should I move?", s.desc),
                    format!("\"{}\" neither turns nor drives", s.desc),
                    vec![],
                );
            }
        }
        // Count moves as the validator will split them (≤ 10 m each).
        let expanded: usize = steps
            .iter()
            .map(|s| {
                if s.action == Action::Move { ((s.f_dist / crate::plan::MAX_STEP_M).ceil() as usize).max(1) } else { 1 }
            })
            .sum();
        if expanded > crate::plan::MAX_STEPS {
            return self.ask(
                format!(
                    "That is {expanded} steps; I can plan at most {} at once. Could you split the instruction?",
                    crate::plan::MAX_STEPS
                ),
                "too many steps",
                vec![],
            );
        }
        Parsed { outcome: Outcome::Plan(Plan::new(steps)), notes: self.notes, ungrounded: self.ungrounded }
    }
}

fn parse_unchecked(text: &str, grounder: &Grounder) -> Parsed {
    if non_latin_share(text) > 0.3 {
        return Parsed::ask(
            "I only understand instructions in English. Could you say it in English?",
            "the instruction is not in English",
            vec![],
            Vec::new(),
        );
    }
    if !text.chars().any(|c| c.is_ascii_alphabetic()) {
        return Parsed::ask(
            "I did not understand that. What should I do?",
            "the instruction has no words",
            vec!["move 2 m ahead".into(), "find the chair".into(), "go back".into()],
            Vec::new(),
        );
    }
    let mut b = Builder::new(grounder);
    let tokens = rewrite_follow(normalise(tokenize(text), &mut b.notes));
    let clauses = order_events(clauses(&tokens), &mut b.notes);
    // The plan so far before each clause, so that a correction can take one back.
    let mut before: Vec<Vec<Item>> = Vec::with_capacity(clauses.len());
    for (ci, clause) in clauses.iter().enumerate() {
        before.push(b.items.clone());
        let mut clause = clause.as_slice();
        // A correction: "go back 2 m? No, go forward 2 m" takes the clause before back.
        if clause.first().is_some_and(|t| matches!(t.w.as_str(), "no" | "sorry")) {
            if ci > 0 {
                b.items = before[ci - 1].clone();
                b.notes.push("a correction (\"no, …\") replaced the clause before it".into());
            }
            clause = &clause[1..];
        }
        let ws = words(clause);
        if ws.is_empty() || (ci == 0 && clauses.len() > 1 && discourse_marker(&ws)) {
            continue;
        }
        b.source = spoken(clause);
        for d in resolve(clause, b.ellipsis) {
            if let Err(ask) = b.directive(d, false) {
                return ask;
            }
        }
    }
    b.finish()
}

// ---- What the words state ---------------------------------------------------

/// The motion an instruction's words state, read with the parser's own
/// lexicon: what a plan proposed by another backend may drive and turn
/// ([`crate::provenance`]). Every value carries the words it was read from.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Stated {
    /// Distances in metres, in the order said: a number with a length unit,
    /// a bare number in a clause with a drive word, or the documented default
    /// of a vague phrase ("a little ahead", "far", a drive with no distance).
    pub lengths: Vec<(f64, String)>,
    /// Turns in radians, counter-clockwise positive, in the order said: an
    /// angle with its unit, or the default of a side word, "slightly", "half
    /// left", "around"; a turn with no side of its own takes the side said
    /// before it ("left 45 degrees, then another 45"); an about-turn is
    /// the same either way round.
    pub angles: Vec<(f64, String)>,
    /// Durations in seconds ("for 20 seconds", "for a minute").
    pub durations: Vec<f64>,
    /// The words that ask to go back to the start ("go back", "return").
    pub back: Option<String>,
    /// Every word, lower case, as tokenised and as normalised (verb forms,
    /// misspellings of keywords).
    pub words: Vec<String>,
}

/// Reads what `text` states about motion (see [`Stated`]).
pub fn stated(text: &str) -> Stated {
    let mut notes = Vec::new();
    let tokens = normalise(tokenize(text), &mut notes);
    let mut out = Stated::default();
    for t in &tokens {
        out.words.push(t.raw.clone());
        if t.w != t.raw {
            out.words.push(t.w.clone());
        }
    }
    let mut last_side = 0i8;
    for clause in clauses(&tokens).into_iter().flat_map(split_runon) {
        let ws = words(&clause);
        let q = quantities(&clause);
        let drives = ws.iter().any(|w| DRIVE_WORDS.contains(w));
        let turns = ws.iter().any(|w| TURN_WORDS.contains(w));
        for &(v, a, b) in &q.lengths {
            out.lengths.push((v, spoken(&clause[a..b.min(clause.len())])));
        }
        let more = ws.iter().any(|w| MORE.contains(w) || *w == "another" || *w == "again");
        if drives || turns || more {
            for &(v, a, b) in &q.bare {
                out.lengths.push((v, spoken(&clause[a..b.min(clause.len()).max(a + 1)])));
            }
        }
        // A vague drive ("go left", "a little ahead", "far"), not a destination ("go to the chair").
        if (drives || more && !turns && q.angles.is_empty())
            && q.lengths.is_empty()
            && q.bare.is_empty()
            && not_motion_words(&clause).is_none()
        {
            let far = has(&ws, "far") || has_seq(&ws, &["long", "way"]).is_some();
            let value = if far { VAGUE_FAR_M } else { VAGUE_SHORT_M };
            out.lengths.push((value, spoken(&clause)));
        }
        let sd = side(&ws);
        let side_here = if sd != 0 { sd } else { last_side };
        last_side = side_here;
        let mut turn = |a: f64, words: String| {
            let about = a >= HALF_TURN - 0.01;
            if about || side_here != 0 {
                out.angles.push((if about { a } else { a * f64::from(side_here) }, words));
            }
        };
        for a in &q.angles {
            turn(*a, spoken(&clause));
        }
        out.durations.extend(&q.durations);
        // "the left chair" describes a thing; "left", "take a left" and
        // "go left" turn.
        let described = !turns
            && !drives
            && (has_seq(&ws, &["the", "left"]).is_some() || has_seq(&ws, &["the", "right"]).is_some());
        if q.angles.is_empty()
            && !described
            && let Some(a) = turn_magnitude(&ws, &q)
        {
            turn(a, spoken(&clause));
        }
        // "go back 2 m", "reverse 2 m" turn around before driving.
        let backwards = ws.iter().any(|w| matches!(*w, "backward" | "backwards" | "reverse"));
        if (has(&ws, "back") || backwards) && (!q.lengths.is_empty() || !q.bare.is_empty()) {
            turn(HALF_TURN, spoken(&clause));
        }
        let back = (has(&ws, "back") && q.lengths.is_empty() && q.bare.is_empty())
            || ws.iter().any(|w| matches!(*w, "return" | "home" | "start" | "started" | "beginning"))
            // "bring me a cup": fetching ends where it began.
            || ws.iter().any(|w| matches!(*w, "bring" | "fetch"));
        if back && out.back.is_none() {
            out.back = Some(spoken(&clause));
        }
    }
    out
}

/// The COCO class id `phrase` names, as the parser grounds a target: a named
/// person (class 0), the synonyms, MiniLM similarity, then a misspelling of
/// a class word ("chiar"). `None` for places, unknowns and ties.
pub fn class_of(grounder: &Grounder, phrase: &str) -> Option<i32> {
    let capital = phrase.chars().next().is_some_and(char::is_uppercase);
    match ground_target(grounder, phrase, capital) {
        Ground::Class { class_id, .. } => Some(class_id),
        _ => None,
    }
}
