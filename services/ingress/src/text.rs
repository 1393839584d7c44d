//! Text normalisation for instructions, typed or transcribed: Unicode
//! compatibility forms folded (NFKC: full-width digits, ligatures, …),
//! typographic quotes and dashes made ASCII, invisible and control
//! characters dropped, whitespace collapsed and punctuation spacing made
//! regular. Wording is left alone: number words ("four") and units stay as
//! written, because the planner grounds them itself.

use unicode_normalization::UnicodeNormalization;

/// Longest instruction accepted, in characters after normalisation.
pub const MAX_INSTRUCTION_CHARS: usize = 4_000;

fn fold_char(c: char) -> Option<&'static str> {
    Some(match c {
        '\u{2018}' | '\u{2019}' | '\u{201A}' | '\u{201B}' | '\u{2032}' | '`' | '\u{00B4}' => "'",
        '\u{201C}' | '\u{201D}' | '\u{201E}' | '\u{201F}' | '\u{2033}' | '\u{00AB}' | '\u{00BB}' => "\"",
        '\u{2010}' | '\u{2011}' | '\u{2012}' | '\u{2013}' | '\u{2014}' | '\u{2015}' | '\u{2212}' => "-",
        '\u{2026}' => "...",
        // Zero-width characters and the byte-order mark.
        '\u{200B}' | '\u{200C}' | '\u{200D}' | '\u{2060}' | '\u{FEFF}' => "",
        _ => return None,
    })
}

fn is_closing_punct(c: char) -> bool {
    matches!(c, ',' | '.' | ';' | ':' | '!' | '?' | ')' | ']' | '}')
}

/// Normalises one instruction. The result may be empty.
pub fn normalize_instruction(text: &str) -> String {
    // 1. Compatibility folding, typographic punctuation, invisible characters.
    let mut folded = String::with_capacity(text.len());
    for c in text.nfkc() {
        if let Some(s) = fold_char(c) {
            folded.push_str(s);
        } else if c.is_whitespace() {
            folded.push(' ');
        } else if !c.is_control() {
            folded.push(c);
        }
    }

    // 2. Collapse whitespace, drop spaces before closing punctuation and
    //    after opening brackets, squeeze repeated punctuation ("!!!", "..").
    let chars: Vec<char> = folded.chars().collect();
    let mut out = String::with_capacity(chars.len());
    for (i, &c) in chars.iter().enumerate() {
        if c == ' ' {
            let next = chars[i + 1..].iter().find(|&&n| n != ' ');
            let prev = out.chars().last();
            let before_closing = next.is_some_and(|&n| is_closing_punct(n));
            let after_opening = matches!(prev, Some('(' | '[' | '{'));
            if prev.is_none() || prev == Some(' ') || next.is_none() || before_closing || after_opening {
                continue;
            }
            out.push(' ');
            continue;
        }
        if matches!(c, ',' | '.' | ';' | ':' | '!' | '?') && out.ends_with(c) {
            continue;
        }
        // 3. A space after , ; : ! ? and sentence dots when a letter follows
        //    directly ("left,then" → "left, then"); "3.5", "1,000", "10:30" and
        //    "e.g." keep their form.
        if let Some(prev) = out.chars().last() {
            let prev2 = out.chars().rev().nth(1);
            if c.is_alphabetic() && matches!(prev, ',' | ';' | ':' | '!' | '?') {
                out.push(' ');
            } else if c.is_alphabetic() && prev == '.' && prev2.is_some_and(|p| p.is_alphabetic()) {
                // "ahead.Then" → "ahead. Then", but keep "e.g" / "a.m" abbreviations.
                let word_len = out[..out.len() - 1].chars().rev().take_while(|p| p.is_alphabetic()).count();
                if word_len > 1 && c.is_uppercase() {
                    out.push(' ');
                }
            }
        }
        out.push(c);
    }
    out.trim().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn whitespace_is_collapsed_and_trimmed() {
        assert_eq!(normalize_instruction("  go\t to \n\n the  chair  "), "go to the chair");
        assert_eq!(normalize_instruction("go\u{00A0}to\u{2003}the chair"), "go to the chair");
        assert_eq!(normalize_instruction("   \n\t "), "");
    }

    #[test]
    fn typographic_characters_become_ascii() {
        assert_eq!(normalize_instruction("the robot\u{2019}s \u{201C}left\u{201D} side"), "the robot's \"left\" side");
        assert_eq!(normalize_instruction("turn \u{2014} then stop\u{2026}"), "turn - then stop.");
        assert_eq!(normalize_instruction("move \u{FF14} m"), "move 4 m");
        assert_eq!(normalize_instruction("go\u{200B} to the \u{FB01}re exit"), "go to the fire exit");
        assert_eq!(normalize_instruction("stop\u{0007} here"), "stop here");
    }

    #[test]
    fn punctuation_spacing_is_regular() {
        assert_eq!(normalize_instruction("take left turn ,move 4 m ahead !"), "take left turn, move 4 m ahead!");
        assert_eq!(normalize_instruction("left,then right;stop"), "left, then right; stop");
        assert_eq!(normalize_instruction("ahead.Then find it"), "ahead. Then find it");
        assert_eq!(normalize_instruction("really?!!  go ,, now"), "really?! go, now");
        assert_eq!(normalize_instruction("the statue ( human )"), "the statue (human)");
    }

    #[test]
    fn numbers_and_number_words_are_kept_as_written() {
        assert_eq!(normalize_instruction("move 3.5 m, then 1,000 mm at 10:30"), "move 3.5 m, then 1,000 mm at 10:30");
        assert_eq!(normalize_instruction("Move five meters forward"), "Move five meters forward");
        assert_eq!(normalize_instruction("e.g. the chair"), "e.g. the chair");
    }
}
